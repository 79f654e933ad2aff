"""n BarcTrack environments stepped by one call into Rust (``cabc._core.VecSim``): a Gymnasium ``VectorEnv``.

Actions come in as an (n, 2) array and observations go out as (n, 6) arrays (or a dict of (n, H, W, 3) images and
(n, 3) velocities); rewards, ``terminated`` and ``truncated`` as (n,) arrays, with the single environment's meaning
(``cabc.env``). An environment whose episode ends is reset within the same call (``AutoresetMode.SAME_STEP``): its
returned observation starts the next episode, and ``info["final_obs"][i]`` holds the last one. ``info`` carries
``laps`` (each episode's laps, for an ended one its final count), ``lap_time`` (where a lap ended on this step) and,
where an episode ended, ``end_reason``; each with Gymnasium's mask ``info["_key"]``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from . import _core
from .env import _SEED_BOUND, action_space, observation_space, spawn_option


class BarcTrackVectorEnv(VectorEnv):
    """``num_envs`` cars, env i drawing its spawns from stream i of the seed; arguments and the track's attributes
    (``track``, ``track_length``, ``half_width``) as ``BarcTrackEnv``'s."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int,
        observation: str = "state",
        spawn: str = "random",
        width: int | None = None,
        height: int | None = None,
        fov: float | None = None,
        max_laps: int | None = None,
        max_episode_steps: int | None = None,
        track: str | None = None,
        track_scale: float | None = None,
        track_half_width: float | None = None,
    ):
        self._sim = _core.VecSim(
            num_envs,
            observation,
            spawn,
            width,
            height,
            fov,
            max_laps,
            max_episode_steps,
            track,
            track_scale,
            track_half_width,
        )
        self.num_envs = num_envs
        self.track = self._sim.track
        self.track_length = self._sim.track_length
        self.half_width = self._sim.half_width
        self.single_action_space = action_space()
        self.single_observation_space = observation_space(observation, self._sim.image_shape, self._sim.state_bounds)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.render_mode = None
        self._seeded = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if isinstance(seed, (list, tuple)):
            raise ValueError("seed must be one int (env i draws from stream i of it) or None")
        super().reset(seed=seed)
        if seed is None and not self._seeded:
            seed = int(self.np_random.integers(_SEED_BOUND))
        self._seeded = True
        return self._sim.reset(seed, spawn_option(options)), {}

    def step(self, actions):
        return self._sim.step(actions)
