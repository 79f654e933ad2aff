"""Tracks other than the L-track (issue 76): ``track=`` names a shipped track or a file, ``track_scale=`` and
``track_half_width=`` size it; the spaces, the attributes and the MPCC follow the environment's own track; a bad
track is a ValueError with the track's error; the default stays the L-track to the last bit."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

import cabc

OVAL_LENGTH = 8 + 3 * math.pi  # two 4 m straights, two half circles of 1.5 m
L_TRACK_LENGTH = 17.461412207630154


def circle_csv(path, r=4.0, n=60, width=0.5, bad_line=None):
    """A circle of radius ``r`` as an F1TENTH centre line of ``n`` points; ``bad_line``: the file line (1-based,
    after the header) whose left width is 0."""
    lines = ["# x_m, y_m, w_tr_right_m, w_tr_left_m"]
    for i in range(n):
        a = 2 * math.pi * i / n
        lines.append(f"{r * math.cos(a)}, {r * math.sin(a)}, {width}, {width}")
    if bad_line is not None:
        lines[bad_line - 1] = lines[bad_line - 1].rsplit(",", 1)[0] + ", 0"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_an_oval_env_resets_steps_and_reports_its_track():
    env = cabc.make("BarcTrack-v0", track="oval", spawn="fixed").unwrapped
    assert env.track_length == pytest.approx(OVAL_LENGTH, abs=1e-12)
    assert env.half_width == 0.55 and "oval" in env.track
    low, high = env.observation_space.low, env.observation_space.high
    assert high[3] == env.track_length and low[3] == 0.0
    assert high[4] > 0.55 and low[4] == -high[4]
    obs, info = env.reset(seed=0)
    np.testing.assert_array_equal(obs, [0.5, 0.0, 0.0, 0.1, 0.0, 0.0])
    pid = cabc.expert("pid")
    total = 0.0
    for _ in range(600):
        obs, reward, terminated, truncated, info = env.step(pid(obs))
        total += reward
        assert not (terminated or truncated), info["end_reason"]
        if info["laps"]:
            break
    # A lap of the oval: the rewards add up to its length (from s = 0.1 to where the car stands).
    assert info["laps"] == 1
    assert total == pytest.approx(OVAL_LENGTH + obs[3] - 0.1, abs=1e-9)
    # The module's constants stay the L-track's.
    assert cabc._core.TRACK_LENGTH == L_TRACK_LENGTH


def test_the_default_is_the_l_track_to_the_last_bit():
    default = cabc.make("BarcTrack-v0").unwrapped
    named = cabc.make("BarcTrack-v0", track="l-track-barc", track_scale=1.0).unwrapped
    for env in (default, named):
        assert env.track_length == cabc._core.TRACK_LENGTH == L_TRACK_LENGTH
        assert env.half_width == cabc._core.HALF_WIDTH == 0.55
        np.testing.assert_array_equal(env.observation_space.low, cabc._core.STATE_LOW)
        np.testing.assert_array_equal(env.observation_space.high, cabc._core.STATE_HIGH)
    a, _ = default.reset(seed=9)
    b, _ = named.reset(seed=9)
    np.testing.assert_array_equal(a, b)
    for _ in range(50):
        action = [0.8, 0.1]
        a, ra, *_ = default.step(action)
        b, rb, *_ = named.step(action)
        np.testing.assert_array_equal(a, b)
        assert ra == rb


def test_an_unknown_track_raises_naming_it():
    with pytest.raises(ValueError, match="no track named `roundabout`"):
        cabc.make("BarcTrack-v0", track="roundabout")
    with pytest.raises(ValueError, match="roundabout"):
        cabc.make_vec(2, track="roundabout")
    with pytest.raises(ValueError, match="roundabout"):
        cabc.expert("mpcc", track="roundabout")
    for kwargs in ({"track_scale": 0.0}, {"track_scale": math.nan}, {"track_half_width": -1.0}):
        with pytest.raises(ValueError, match="must be a positive number"):
            cabc.BarcTrackEnv(track="oval", **kwargs)


def test_a_centre_line_file_loads_and_drives(tmp_path):
    path = circle_csv(tmp_path / "circle.csv")
    env = cabc.make("BarcTrack-v0", track=str(path), spawn="fixed", render_mode="rgb_array", width=32, height=24)
    bare = env.unwrapped
    assert bare.track_length == pytest.approx(2 * math.pi * 4, abs=1e-3)
    assert bare.half_width == 0.5 and str(path) in bare.track
    assert bare.observation_space.high[3] == bare.track_length
    obs, _ = env.reset(seed=0)
    pid = cabc.expert("pid")
    for _ in range(50):
        obs, _, terminated, truncated, info = env.step(pid(obs))
        assert not (terminated or truncated), info["end_reason"]
    frame = env.render()
    assert frame.shape == (24, 32, 3) and frame.std() > 0
    # Sized: twice as large, a narrower constraint.
    big = cabc.BarcTrackEnv(track=str(path), track_scale=2.0, track_half_width=0.4)
    assert big.track_length == pytest.approx(2 * bare.track_length, abs=1e-6) and big.half_width == 0.4


def test_a_bad_file_raises_naming_the_file_and_line(tmp_path):
    path = circle_csv(tmp_path / "zero.csv", bad_line=5)
    with pytest.raises(ValueError, match=re.escape(f"{path}:5: the width to the left is 0")):
        cabc.make("BarcTrack-v0", track=str(path))
    missing = tmp_path / "missing.csv"
    with pytest.raises(ValueError, match=re.escape(str(missing))):
        cabc.make("BarcTrack-v0", track=str(missing))


def test_a_vector_env_on_the_oval():
    envs = cabc.make_vec(3, track="oval", spawn="fixed")
    assert envs.track_length == pytest.approx(OVAL_LENGTH, abs=1e-12) and envs.half_width == 0.55
    assert envs.single_observation_space.high[3] == envs.track_length
    obs, _ = envs.reset(seed=0)
    single = cabc.make("BarcTrack-v0", track="oval", spawn="fixed").unwrapped
    one, _ = single.reset(seed=0)
    np.testing.assert_array_equal(obs[0], one)
    pid = cabc.expert("pid")
    for _ in range(20):
        obs, *_ = envs.step(pid(obs))
        one, *_ = single.step(pid(one))
        np.testing.assert_array_equal(obs[0], one)


def test_the_mpcc_drives_the_envs_track():
    env = cabc.make("BarcTrack-v0", track="oval", spawn="fixed").unwrapped
    mpcc = cabc.expert("mpcc", track="oval")
    obs, info = env.reset(seed=0)
    # From the Frenet state alone it measures the pose on the oval: the vehicle state the env reports.
    np.testing.assert_allclose(cabc.expert("mpcc", track="oval")(obs), mpcc(obs, vehicle=info["vehicle_state"]))
    mpcc.reset()
    for _ in range(60):
        obs, _, terminated, truncated, info = env.step(mpcc(obs, vehicle=info["vehicle_state"]))
        assert mpcc.success
        assert not (terminated or truncated), info["end_reason"]
    assert obs[0] > 1.5
