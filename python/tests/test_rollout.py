"""1,000 PID steps driven from Python against `cabc-sim rollout`: the same simulator, so the same numbers, bit for bit
(the trace prints every float in its shortest round-tripping form)."""

from __future__ import annotations

import csv
import json
import subprocess

import pytest

import cabc
from conftest import binary

STEPS = 1000


@pytest.mark.parametrize("spawn,seed", [("fixed", 0), ("random", 5)])
def test_python_pid_steps_equal_cabc_sim_rollout(bin_dir, tmp_path, spawn, seed):
    trace = tmp_path / "trace.csv"
    out = subprocess.run(
        [binary(bin_dir, "cabc-sim"), "rollout", "--policy", "pid", "--spawn", spawn, "--seed", str(seed),
         "--steps", str(STEPS), "--json", "--trace", str(trace)],
        check=True, capture_output=True, text=True,
    )
    summary = json.loads(out.stdout)
    with open(trace) as f:
        rows = list(csv.DictReader(f))

    env = cabc.make("BarcTrack-v0", spawn=spawn).unwrapped
    pid = cabc.expert("pid")
    obs, info = env.reset(seed=seed)
    names = ["v_long", "v_tran", "omega", "s", "x_tran", "e_psi"]
    assert obs.tolist() == [float(rows[0][k]) for k in names]
    steps, end = 0, None
    for row in rows[1:]:
        action = pid(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        steps += 1
        assert action.tolist() == [float(row["a"]), float(row["delta"])], f"step {steps}"
        assert obs.tolist() == [float(row[k]) for k in names], f"step {steps}"
        assert info["vehicle_state"][3:].tolist() == [float(row[k]) for k in ("X", "Y", "psi")], f"step {steps}"
        assert reward == float(row["reward"]) and info["laps"] == int(row["lap_no"]), f"step {steps}"
        assert (info["end_reason"] or "") == row["truncation"], f"step {steps}"
        if terminated or truncated:
            end = info["end_reason"]
            break
    assert steps == summary["steps"]
    assert info["laps"] == summary["laps"] and info["lap_times"] == summary["lap_times"]
    assert end == summary["truncation"]
    assert obs.tolist() == summary["final_state"]
    if spawn == "fixed":
        assert steps == STEPS and info["laps"] >= 5
