"""BarcTrack-v0 against Gymnasium's API: the environment checker on both observations, the spaces from the
simulator, seeding, spawns, the ends of episodes and bad input."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import cabc

# What the checker recommends and we decline: the simulator's action box as it is ([-2, 2] m/s^2, [-0.45, 0.45] rad,
# not [-1, 1]) and unbounded velocities.
KNOWN_WARNINGS = ("symmetric and normalized space", "minimum value is -infinity", "maximum value is infinity")


@pytest.mark.parametrize(
    "kwargs",
    [
        {"observation": "state"},
        {"observation": "camera", "width": 32, "height": 24},
        {"observation": "state", "track": "oval"},
        {"observation": "camera", "width": 32, "height": 24, "track": "chicane"},
    ],
)
def test_gymnasium_env_checker_passes(kwargs):
    env = gym.make("BarcTrack-v0", render_mode="rgb_array", **kwargs).unwrapped
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    unexpected = [str(w.message) for w in caught if not any(k in str(w.message) for k in KNOWN_WARNINGS)]
    assert not unexpected, unexpected


def test_spaces_are_the_simulators():
    env = cabc.make("BarcTrack-v0").unwrapped
    assert env.action_space.shape == (2,)
    np.testing.assert_array_equal(env.action_space.low, [-2.0, -0.45])
    np.testing.assert_array_equal(env.action_space.high, [2.0, 0.45])
    low, high = env.observation_space.low, env.observation_space.high
    assert env.observation_space.shape == (6,)
    assert high[3] == pytest.approx(cabc._core.TRACK_LENGTH) and low[3] == 0.0
    assert high[4] > 0.55 and low[4] == -high[4]
    camera = cabc.make("BarcTrack-v0", observation="camera", width=40, height=30).unwrapped
    assert camera.observation_space["image"].shape == (30, 40, 3)
    assert camera.observation_space["image"].dtype == np.uint8
    assert camera.observation_space["velocity"].shape == (3,)


def test_fixed_spawn_and_seeded_random_spawns():
    env = cabc.make("BarcTrack-v0").unwrapped
    obs, info = env.reset(seed=3, options={"spawn": "fixed"})
    np.testing.assert_array_equal(obs, [0.5, 0.0, 0.0, 0.1, 0.0, 0.0])
    a, _ = env.reset(seed=3)
    b, _ = env.reset()
    c, _ = env.reset(seed=3)
    np.testing.assert_array_equal(a, c)
    assert not np.array_equal(a, b)
    assert info["laps"] == 0 and info["end_reason"] is None and info["lap_times"] == []


def test_leaving_the_track_terminates():
    env = cabc.make("BarcTrack-v0", spawn="fixed").unwrapped
    env.reset(seed=0)
    for _ in range(200):
        obs, reward, terminated, truncated, info = env.step([2.0, 0.45])
        if terminated or truncated:
            break
    assert terminated and not truncated
    assert info["end_reason"] in ("out-of-track", "left-band")


def test_a_stall_and_the_step_limit_truncate():
    env = cabc.make("BarcTrack-v0", spawn="fixed").unwrapped
    env.reset(seed=0)
    for _ in range(10):
        _, _, terminated, truncated, info = env.step([-2.0, 0.0])
        if terminated or truncated:
            break
    assert truncated and not terminated and info["end_reason"] == "stall"
    # The step limit: in Rust for the bare class (and make_vec), Gymnasium's TimeLimit through make.
    for env, reason in [
        (cabc.BarcTrackEnv(spawn="fixed", max_episode_steps=5), "budget"),
        (cabc.make("BarcTrack-v0", spawn="fixed", max_episode_steps=5), None),
    ]:
        obs, _ = env.reset(seed=0)
        pid = cabc.expert("pid")
        ends = []
        for _ in range(5):
            obs, _, terminated, truncated, info = env.step(pid(obs))
            ends.append((terminated, truncated, info["end_reason"]))
        assert ends[:4] == [(False, False, None)] * 4 and ends[4] == (False, True, reason)


def test_laps_rewards_and_lap_times():
    env = cabc.make("BarcTrack-v0", spawn="fixed", max_laps=1).unwrapped
    obs, _ = env.reset(seed=0)
    pid = cabc.expert("pid")
    total, steps = 0.0, 0
    while True:
        obs, reward, terminated, truncated, info = env.step(pid(obs))
        total += reward
        steps += 1
        if info["lap_completed"]:
            lap = info["lap_time"]
            assert info["lap_times"] == [lap] and info["laps"] == 1
        if terminated or truncated:
            break
    # One lap, then the simulator's lap limit.
    assert info["end_reason"] == "max-laps" and truncated
    assert lap == pytest.approx((steps - 1) * cabc._core.DT)
    # The reward is progress along the centreline: one lap's worth, from s = 0.1 to where the car stands now.
    assert total == pytest.approx(cabc._core.TRACK_LENGTH + obs[3] - 0.1, abs=1e-9)


def test_render_is_the_camera_view():
    env = cabc.make("BarcTrack-v0", render_mode="rgb_array", width=48, height=32).unwrapped
    env.reset(seed=1)
    frame = env.render()
    assert frame.shape == (32, 48, 3) and frame.dtype == np.uint8 and frame.std() > 0


def test_camera_observation_matches_render():
    env = cabc.make("BarcTrack-v0", observation="camera", render_mode="rgb_array", width=32, height=32).unwrapped
    obs, info = env.reset(seed=2)
    np.testing.assert_array_equal(obs["image"], env.render())
    np.testing.assert_array_equal(obs["velocity"], info["state"][:3])


@pytest.mark.parametrize(
    "action", [[math.nan, 0.0], [0.0, math.inf], [1.0, 2.0, 3.0], [[1.0, 0.0]], "fast", None, 1.0]
)
def test_bad_actions_raise(action):
    env = cabc.make("BarcTrack-v0").unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError):
        env.step(action)
    env.step([0.0, 0.0])  # still usable


def test_out_of_box_actions_are_clipped():
    a = cabc.make("BarcTrack-v0", spawn="fixed").unwrapped
    b = cabc.make("BarcTrack-v0", spawn="fixed").unwrapped
    a.reset(seed=0)
    b.reset(seed=0)
    np.testing.assert_array_equal(a.step([9.0, -9.0])[0], b.step([2.0, -0.45])[0])
    np.testing.assert_array_equal(a.step(np.array([1, 0], dtype=np.float32))[0], b.step([1.0, 0.0])[0])


@pytest.mark.parametrize(
    "kwargs",
    [
        {"observation": "lidar"},
        {"spawn": "anywhere"},
        {"width": 0},
        {"fov": 200.0},
        {"render_mode": "human"},
        {"max_episode_steps": 0},
    ],
)
def test_bad_arguments_raise(kwargs):
    with pytest.raises(ValueError):
        cabc.BarcTrackEnv(**kwargs)


def test_unknown_names_and_options_raise():
    with pytest.raises(ValueError):
        cabc.make("BarcTrack-v9")
    env = cabc.make("BarcTrack-v0").unwrapped
    with pytest.raises(ValueError):
        env.reset(options={"spawn": "nowhere"})
    with pytest.raises(ValueError):
        env.reset(options={"weather": "rain"})
