"""BarcTrack-v0: the racing task as a Gymnasium environment, a thin shell over the Rust simulator (``cabc._core.Sim``).

The car is the dynamic bicycle of cabc-sim on the L-shaped BARC track, or on the track ``track=`` names (a shipped
one, "oval", "chicane", "long", or a ``.csv``/``.toml`` file; ``track_scale=``, ``track_half_width=``); one step holds
the action for 0.1 s.

* Observation ``"state"``: ``Box(6)`` float64, [v_long, v_tran, omega, s, x_tran, e_psi] (m/s, m/s, rad/s, m, m, rad).
  ``"camera"``: ``Dict(image=Box(H, W, 3) uint8, velocity=Box(3) float64)``, the first-person image and
  [v_long, v_tran, omega].
* Action: ``Box(2)`` float64, [a (m/s^2), delta (rad)] within the simulator's box; values outside are clipped,
  non-finite ones raise ``ValueError``.
* Reward: the progress along the centreline in metres during the step (the simulator's own, the reference's).
* ``terminated``: the car left the track (|x_tran| > the half-width, 0.55 on the L-track; or the Frenet band).
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


def observation_space(observation: str, image_shape: tuple[int, int], state_bounds) -> spaces.Space:
    """The observation space of one environment; ``state_bounds``: the (low, high) of the state on its track (s
    within [0, its length], x_tran within its band)."""
    low, high = state_bounds
    state = spaces.Box(low=np.array(low), high=np.array(high), dtype=np.float64)
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
        track: the track, as a run's ``sim.track``: ``"l-track-barc"`` (the default), a shipped one (``"oval"``,
            ``"chicane"``, ``"long"``) or a file, ``*.csv`` (an F1TENTH centre line) or ``*.toml`` (pieces); a bad
            one raises ``ValueError`` naming the file and line. Tracks are built once per process and name.
        track_scale: the track's lengths and widths multiplied by this (1).
        track_half_width: the constraint's half-width (m, after the scale) instead of the track's own.

    Attributes (of this environment's track): ``track`` (in words), ``track_length`` (m), ``half_width`` (m);
    ``cabc._core.TRACK_LENGTH`` and ``HALF_WIDTH`` are the default L-track's.
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
        track: str | None = None,
        track_scale: float | None = None,
        track_half_width: float | None = None,
    ):
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"unknown render_mode {render_mode!r}: expected None or 'rgb_array'")
        self._sim = _core.Sim(
            observation, spawn, width, height, fov, max_laps, max_episode_steps, track, track_scale, track_half_width
        )
        self.render_mode = render_mode
        self.track = self._sim.track
        self.track_length = self._sim.track_length
        self.half_width = self._sim.half_width
        self.action_space = action_space()
        self.observation_space = observation_space(observation, self._sim.image_shape, self._sim.state_bounds)
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
