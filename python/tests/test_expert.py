"""The experts as callables: the PID's closed form, the MPCC driving from the fixed spawn, batches as streams."""

from __future__ import annotations

import numpy as np
import pytest

import cabc


def test_pid_is_the_closed_form():
    pid = cabc.expert("pid")
    for v, x, e in [(0.5, 0.0, 0.0), (1.7, 0.1, -0.2), (3.0, -0.5, 0.4)]:
        a = pid([v, 0.0, 0.0, 1.0, x, e])
        assert a.shape == (2,)
        assert a[0] == pytest.approx(np.clip(1.5 * (1.0 - v), -2, 2), abs=1e-12)
        assert a[1] == pytest.approx(np.clip(-2.5 * x - 0.5 * e, -0.436, 0.436), abs=1e-12)
    assert pid.success is True and pid.name == "pid"


def test_mpcc_drives_from_the_fixed_spawn():
    env = cabc.make("BarcTrack-v0", spawn="fixed").unwrapped
    mpcc = cabc.expert("mpcc")
    obs, info = env.reset(seed=0)
    for _ in range(40):
        obs, _, terminated, truncated, info = env.step(mpcc(obs, vehicle=info["vehicle_state"]))
        assert mpcc.success
        assert not (terminated or truncated)
    assert obs[0] > 1.5  # it accelerates well beyond the PID's 1 m/s


def test_mpcc_from_the_frenet_state_alone_matches_the_vehicle_state():
    env = cabc.make("BarcTrack-v0", spawn="fixed").unwrapped
    obs, info = env.reset(seed=0)
    a = cabc.expert("mpcc")(obs)
    b = cabc.expert("mpcc")(obs, vehicle=info["vehicle_state"])
    np.testing.assert_allclose(a, b, atol=1e-6)


def test_rows_are_streams():
    envs = cabc.make_vec(3, spawn="fixed")
    obs, _ = envs.reset(seed=0)
    batch = cabc.expert("pid")
    singles = [cabc.expert("pid") for _ in range(3)]
    for _ in range(5):
        actions = batch(obs)
        assert actions.shape == (3, 2)
        for i in range(3):
            np.testing.assert_array_equal(actions[i], singles[i](obs[i]))
        obs, *_ = envs.step(actions)
    batch.reset(1)
    batch.reset([0, 2])
    batch.reset()
    assert batch.success.shape == (3,)


@pytest.mark.parametrize("state", [[1.0, 0.0], [[1.0] * 6] * 2 + [[np.nan] * 6], "state", np.zeros((2, 3, 6))])
def test_bad_states_raise(state):
    for name in ("pid", "mpcc"):
        with pytest.raises(ValueError):
            cabc.expert(name)(state)


def test_off_track_states_and_unknown_names_raise():
    mpcc = cabc.expert("mpcc")
    with pytest.raises(ValueError, match="off the track"):
        mpcc([1.0, 0.0, 0.0, 1.0, 5.0, 0.0])
    # A huge s is wrapped onto the track, not looped over.
    assert mpcc([1.0, 0.0, 0.0, 1e300, 0.0, 0.0]).shape == (2,)
    for bad in ("lqr", "PID"):
        with pytest.raises(ValueError):
            cabc.expert(bad)
    with pytest.raises(ValueError):
        cabc.expert("pid", target_speed=float("nan"))
    with pytest.raises(ValueError):
        mpcc.reset(-1)
