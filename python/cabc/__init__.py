"""cabc's racing task in Python: the simulator as a Gymnasium environment and its experts as callables.

    import cabc
    env = cabc.make("BarcTrack-v0", observation="state")      # or "camera"
    obs, info = env.reset(seed=0)
    pid = cabc.expert("pid")                                   # or "mpcc"
    obs, reward, terminated, truncated, info = env.step(pid(obs))

    oval = cabc.make("BarcTrack-v0", track="oval")             # or "chicane", "long", "path/to/centre-line.csv"
    mpcc = cabc.expert("mpcc", track="oval")                   # the MPCC on the same track

    envs = cabc.make_vec(64)                                   # 64 cars stepped in one call
    obs, info = envs.reset(seed=0)
    obs, rewards, terminated, truncated, info = envs.step(pid(obs))

``gymnasium.make("BarcTrack-v0")`` and ``gymnasium.make_vec("BarcTrack-v0", num_envs=n,
vectorization_mode="vector_entry_point")`` work too once ``cabc`` is imported.
"""

from __future__ import annotations

import gymnasium as gym

from . import _core
from .env import BarcTrackEnv
from .vector import BarcTrackVectorEnv

__all__ = ["BarcTrackEnv", "BarcTrackVectorEnv", "Expert", "ENV_IDS", "make", "make_vec", "expert"]
__version__ = _core.VERSION

Expert = _core.Expert
ENV_IDS = ("BarcTrack-v0",)
EXPERTS = ("pid", "mpcc")

if ENV_IDS[0] not in gym.registry:
    gym.register(
        id=ENV_IDS[0],
        entry_point="cabc.env:BarcTrackEnv",
        vector_entry_point="cabc.vector:BarcTrackVectorEnv",
    )


def _check_id(env_id: str) -> None:
    if env_id not in ENV_IDS:
        raise ValueError(f"unknown environment {env_id!r}: cabc has {', '.join(ENV_IDS)}")


def make(env_id: str = ENV_IDS[0], **kwargs) -> gym.Env:
    """``gymnasium.make`` of a cabc environment (with Gymnasium's usual wrappers; ``.unwrapped`` is the bare one).

    Keyword arguments: ``observation`` ("state" or "camera"), ``spawn`` ("random" or "fixed"), ``render_mode``,
    ``width``, ``height``, ``fov``, ``max_laps``, ``max_episode_steps``, ``track`` ("l-track-barc", the default;
    "oval", "chicane", "long", or a .csv or .toml file), ``track_scale``, ``track_half_width`` (see
    ``cabc.BarcTrackEnv``).
    """
    _check_id(env_id)
    return gym.make(env_id, **kwargs)


def make_vec(num_envs: int, env_id: str = ENV_IDS[0], **kwargs) -> BarcTrackVectorEnv:
    """``num_envs`` environments stepped in one call into Rust (see ``cabc.BarcTrackVectorEnv``); keyword arguments
    as ``make``'s, without ``render_mode``."""
    _check_id(env_id)
    return BarcTrackVectorEnv(num_envs, **kwargs)


def expert(name: str, **kwargs) -> _core.Expert:
    """The PID lane follower (``"pid"``, ``target_speed=`` in m/s) or MPCC-conv (``"mpcc"``), as a callable
    ``expert(state) -> action`` that keeps its memory (the PID's errors, the MPCC's warm start) between calls, per
    row of a batch; ``expert.reset()`` at a new episode (``expert.reset(i)`` for row i of a vector env).

    ``track=``, ``track_scale=``, ``track_half_width=``: the track the MPCC drives, as the environment's (the
    L-track when not given); give the same as the environment's."""
    if name not in EXPERTS:
        raise ValueError(f"unknown expert {name!r}: expected one of {', '.join(EXPERTS)}")
    return _core.Expert(name, **kwargs)
