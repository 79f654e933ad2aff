"""make_vec: n cars in one call, Gymnasium's vector conventions, the same cars as single environments."""

from __future__ import annotations

import numpy as np
import pytest

import cabc


def test_shapes_and_spaces():
    envs = cabc.make_vec(5)
    obs, info = envs.reset(seed=0)
    assert obs.shape == (5, 6) and obs.dtype == np.float64 and info == {}
    assert envs.action_space.shape == (5, 2) and envs.observation_space.shape == (5, 6)
    obs, rewards, terminated, truncated, info = envs.step(np.zeros((5, 2)))
    assert rewards.shape == terminated.shape == truncated.shape == (5,)
    assert terminated.dtype == truncated.dtype == np.bool_
    assert info["laps"].shape == (5,) and info["lap_time"].shape == (5,)
    camera = cabc.make_vec(3, observation="camera", width=16, height=8)
    obs, _ = camera.reset(seed=0)
    assert obs["image"].shape == (3, 8, 16, 3) and obs["velocity"].shape == (3, 3)
    assert camera.observation_space["image"].shape == (3, 8, 16, 3)


def test_env_i_is_stream_i_of_the_seed_and_env_0_the_single_env():
    envs = cabc.make_vec(3, spawn="random")
    single = cabc.make("BarcTrack-v0", spawn="random").unwrapped
    obs, _ = envs.reset(seed=11)
    one, _ = single.reset(seed=11)
    np.testing.assert_array_equal(obs[0], one)
    assert len({tuple(o) for o in obs}) == 3
    actions = np.array([[0.5, 0.1]] * 3)
    for _ in range(5):
        obs, rewards, terminated, truncated, _ = envs.step(actions)
        one, reward, term, trunc, _ = single.step(actions[0])
        if term or trunc:
            break
        np.testing.assert_array_equal(obs[0], one)
        assert rewards[0] == reward


def test_ended_episodes_reset_in_the_same_step():
    envs = cabc.make_vec(2, spawn="fixed")
    envs.reset(seed=0)
    # Env 0 brakes into a stall; env 1 drives on.
    for _ in range(10):
        obs, _, terminated, truncated, info = envs.step(np.array([[-2.0, 0.0], [0.5, 0.0]]))
        if truncated[0]:
            break
    assert truncated[0] and not terminated[0] and not truncated[1]
    assert info["_end_reason"].tolist() == [True, False]
    assert info["end_reason"][0] == "stall" and info["end_reason"][1] is None
    assert info["_final_obs"][0] and info["final_obs"][0][0] < 0.25
    # The returned observation is the next episode's: the fixed spawn.
    np.testing.assert_array_equal(obs[0], [0.5, 0.0, 0.0, 0.1, 0.0, 0.0])


def test_camera_final_obs_carries_the_image():
    envs = cabc.make_vec(1, observation="camera", spawn="fixed", width=8, height=8)
    envs.reset(seed=0)
    for _ in range(10):
        _, _, _, truncated, info = envs.step(np.array([[-2.0, 0.0]]))
        if truncated[0]:
            break
    final = info["final_obs"][0]
    assert final["image"].shape == (8, 8, 3) and final["velocity"][0] < 0.25


@pytest.mark.parametrize("actions", [np.zeros((3, 3)), np.zeros((2, 2)), np.zeros(2), np.full((3, 2), np.nan)])
def test_bad_actions_raise(actions):
    envs = cabc.make_vec(3)
    envs.reset(seed=0)
    with pytest.raises(ValueError):
        envs.step(actions)


def test_bad_sizes_raise():
    for n in (0, -1, 10**6):
        with pytest.raises((ValueError, OverflowError)):
            cabc.make_vec(n)
    # 60,000 cameras of 224 x 224 would need 9 GB a step.
    with pytest.raises(ValueError, match="bytes of images"):
        cabc.make_vec(60_000, observation="camera")
