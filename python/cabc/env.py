"""BarcTrack-v0: the racing task as a Gymnasium environment, a thin shell over the Rust simulator (``cabc._core.Sim``).

The car is the dynamic bicycle of cabc-sim on the L-shaped BARC track; one step holds the action for 0.1 s.

* Observation ``"state"``: ``Box(6)`` float64, [v_long, v_tran, omega, s, x_tran, e_psi] (m/s, m/s, rad/s, m, m, rad).
  ``"camera"``: ``Dict(image=Box(H, W, 3) uint8, velocity=Box(3) float64)``, the first-person image and
  [v_long, v_tran, omega].
* Action: ``Box(2)`` float64, [a (m/s^2), delta (rad)] within the simulator's box; values outside are clipped,
  non-finite ones raise ``ValueError``.
* Reward: the progress along the centreline in metres during the step (the simulator's own, the reference's).
* ``terminated``: the car left the track (|x_tran| > 0.55, the constraint; or the Frenet band).
  ``truncated``: the simulator's limits (stall, spin, ``max_laps`` laps) or a step limit.
* ``info``: ``laps``, ``lap_times``, ``lap_completed``, ``lap_time``, ``end_reason``, ``state`` (the 6-d state,
  what the experts take), ``vehicle_state`` ([v_x, v_y, omega, X, Y, psi]) and ``time``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from . import _core

# One seed a reset draws from the environment's own generator when none is given (the simulator's streams are u64).
_SEED_BOUND = 2**63


def action_space() -> spaces.Box:
    """The simulator's action box."""
    return spaces.Box(low=np.array(_core.ACTION_LOW), high=np.array(_core.ACTION_HIGH), dtype=np.float64)


def observation_space(observation: str, image_shape: tuple[int, int]) -> spaces.Space:
    """The observation space of one environment."""
    state = spaces.Box(low=np.array(_core.STATE_LOW), high=np.array(_core.STATE_HIGH), dtype=np.float64)
    if observation == "state":
        return state
    h, w = image_shape
    velocity = spaces.Box(low=state.low[:3], high=state.high[:3], dtype=np.float64)
    return spaces.Dict({"image": spaces.Box(0, 255, (h, w, 3), dtype=np.uint8), "velocity": velocity})


def spawn_option(options: dict[str, Any] | None) -> str | None:
    """The ``spawn`` of ``reset(options=...)``, if any."""
    if not options:
        return None
    unknown = set(options) - {"spawn"}
    if unknown:
        raise ValueError(f"unknown reset options {sorted(unknown)}: the only one is 'spawn' ('fixed' or 'random')")
    return options.get("spawn")


class BarcTrackEnv(gym.Env):
    """One car on the BARC track (see the module's documentation).

    Args:
        observation: ``"state"`` or ``"camera"``.
        spawn: where every reset starts, ``"random"`` (the training spawn: anywhere along the track, up to the band
            sideways, +-30 degrees, 0.5-2 m/s) or ``"fixed"`` (the evaluation spawn, s = 0.1 m at 0.5 m/s);
            ``reset(options={"spawn": ...})`` overrides it for one episode.
        render_mode: ``None`` or ``"rgb_array"`` (the first-person camera).
        width, height, fov: the camera's pixels and horizontal field of view (degrees); 224 x 224 and 110 by default.
        max_laps: laps after which the simulator truncates (50).
        max_episode_steps: an optional step limit (truncation, end reason ``"budget"``); ``cabc.make`` and
            ``gymnasium.make`` take this argument themselves and wrap the environment in Gymnasium's ``TimeLimit``
            (the same truncation, without an end reason).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": round(1 / _core.DT)}

    def __init__(
        self,
        observation: str = "state",
        spawn: str = "random",
        render_mode: str | None = None,
        width: int | None = None,
        height: int | None = None,
        fov: float | None = None,
        max_laps: int | None = None,
        max_episode_steps: int | None = None,
    ):
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"unknown render_mode {render_mode!r}: expected None or 'rgb_array'")
        self._sim = _core.Sim(observation, spawn, width, height, fov, max_laps, max_episode_steps)
        self.render_mode = render_mode
        self.action_space = action_space()
        self.observation_space = observation_space(observation, self._sim.image_shape)
        self._seeded = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if seed is None and not self._seeded:
            # A first reset without a seed: one from Gymnasium's generator (itself seeded from the OS).
            seed = int(self.np_random.integers(_SEED_BOUND))
        self._seeded = True
        return self._sim.reset(seed, spawn_option(options))

    def step(self, action):
        return self._sim.step(action)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() without render_mode: make the environment with render_mode='rgb_array'")
            return None
        return self._sim.render()
