"""Steps per second from Python against `cabc-sim bench`, side by side.

Each repeat runs, in turn, the Rust figure (`cabc-sim bench`: one env under the PID, a random respawn at each end, one
core), one environment stepped from Python, and `cabc.make_vec(64)` stepped from Python, each car under the PID from
the fixed spawn (the Python ones call `cabc.expert("pid")` from Python, batched for the vector env; at an episode's
end, after 50 laps, `cabc-sim bench` respawns at random and they at the fixed spawn: rare either way). The repeats
alternate so that a machine whose load drifts (a background campaign) weighs on all three alike; the medians and their
ratios are printed, and with --json written as JSON.

    python python/benches/steps.py --cabc-sim target/release/cabc-sim [--repeats 5] [--seconds 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import subprocess
import time

import cabc


def rust(cabc_sim: str, seconds: float) -> float:
    """`cabc-sim bench`'s env steps/s."""
    out = subprocess.run([cabc_sim, "bench", "--seconds", str(seconds)], check=True, capture_output=True, text=True)
    match = re.search(r"env: (\d+) steps/s", out.stdout)
    if not match:
        raise RuntimeError(f"unexpected cabc-sim bench output:\n{out.stdout}")
    return float(match.group(1))


def single(seconds: float) -> float:
    """One environment (the bare one, without Gymnasium's checking wrappers), the PID per step."""
    env = cabc.make("BarcTrack-v0", spawn="fixed").unwrapped
    pid = cabc.expert("pid")
    obs, _ = env.reset(seed=0)
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(1000):
            obs, _, terminated, truncated, _ = env.step(pid(obs))
            if terminated or truncated:
                obs, _ = env.reset()
                pid.reset()
        steps += 1000
    return steps / (time.perf_counter() - start)


def vector(seconds: float, n: int) -> float:
    """n environments in one call, the PID batched over them."""
    envs = cabc.make_vec(n, spawn="fixed")
    pid = cabc.expert("pid")
    obs, _ = envs.reset(seed=0)
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(100):
            obs, _, terminated, truncated, _ = envs.step(pid(obs))
            ended = (terminated | truncated).nonzero()[0]
            if len(ended):
                pid.reset(ended.tolist())
        steps += 100 * n
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cabc-sim", default="target/release/cabc-sim")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--json")
    args = parser.parse_args()
    runs: dict[str, list[float]] = {"rust": [], "python_single": [], "python_vec": []}
    for r in range(args.repeats):
        runs["rust"].append(rust(args.cabc_sim, args.seconds))
        runs["python_single"].append(single(args.seconds))
        runs["python_vec"].append(vector(args.seconds, args.envs))
        print(f"repeat {r}: " + ", ".join(f"{k} {v[-1]:,.0f}" for k, v in runs.items()), flush=True)
    med = {k: statistics.median(v) for k, v in runs.items()}
    # Each repeat's own ratios too: the three ran back to back, under about the same load.
    paired = {
        k: statistics.median(p / r for p, r in zip(runs[k], runs["rust"])) for k in ("python_single", "python_vec")
    }
    report = {
        "steps_per_s": runs,
        "median": med,
        "single_over_rust": med["python_single"] / med["rust"],
        "vec_over_rust": med["python_vec"] / med["rust"],
        "median_of_paired_ratios": paired,
        "envs": args.envs,
        "seconds": args.seconds,
    }
    print(
        f"median steps/s: rust {med['rust']:,.0f}, python single {med['python_single']:,.0f} "
        f"({report['single_over_rust']:.0%}), python vec{args.envs} {med['python_vec']:,.0f} "
        f"({report['vec_over_rust']:.0%}); median of the repeats' ratios: single {paired['python_single']:.0%}, "
        f"vec{args.envs} {paired['python_vec']:.0%}"
    )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=2)


if __name__ == "__main__":
    main()
