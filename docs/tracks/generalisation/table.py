#!/usr/bin/env python3
"""Issue 76's generalisation table from `deploy/tracks-study.sh`'s robust-<track>/robust.json of each run folder.

    python3 docs/tracks/generalisation/table.py NAME=RUN_PREFIX[:SEEN,SEEN] ... [--seeds 1,2,3,4,5] [--copy DIR]

A group is a run-name prefix (SEEN: the tracks it trained on, l-track-barc unless given): runs PREFIX-s<k> (proposed) and PREFIX-s<k>-baseline (baseline) under runs/. For each
track: the crash share over the seeds' 20 spawns each (mean of the seeds, 95 % bootstrap interval over seeds), laps
per episode, and the paired difference proposed - baseline (bootstrap over seeds). --copy DIR keeps each run's
robust.json files under DIR/<run>/ (the results this table is made from).
"""
import json
import random
import shutil
import sys
from pathlib import Path

TRACKS = ["l-track-barc", "oval", "chicane", "long"]


def level(run, track):
    data = json.loads((Path("runs") / run / f"robust-{track}" / "robust.json").read_text())
    row = data["levels"][0]
    return row["crashes"] / row["episodes"], row["laps_mean"]


def boot(values, n=10000, seed=76):
    rng = random.Random(seed)
    means = sorted(sum(rng.choice(values) for _ in values) / len(values) for _ in range(n))
    return sum(values) / len(values), means[int(0.025 * n)], means[int(0.975 * n) - 1]


def fmt(m, lo, hi, pct=True):
    if pct:
        return f"{100 * m:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}]"
    return f"{m:.2f} [{lo:.2f}, {hi:.2f}]"


def main(argv):
    seeds, groups, copy = [1, 2, 3, 4, 5], [], None
    args = iter(argv)
    for a in args:
        if a == "--seeds":
            seeds = [int(s) for s in next(args).split(",")]
        elif a == "--copy":
            copy = Path(next(args))
        else:
            name, prefix = a.split("=", 1)
            prefix, _, seen = prefix.partition(":")
            groups.append((name, prefix, seen.split(",") if seen else ["l-track-barc"]))
    print("| key | method | early stop | early-stop versions | first version with 50 laps, median |")
    print("|---|---|---|---|---|")
    for name, prefix, _ in groups:
        for method, suffix in [("proposed", ""), ("baseline (λ 0)", "-baseline")]:
            runs = [json.loads((Path("runs") / f"{prefix}-s{k}{suffix}" / "summary.json").read_text()) for k in seeds]
            stops = [r.get("early_stop_version") for r in runs]
            firsts = sorted(r.get("first_version_with_eval_laps") or 10**9 for r in runs)
            first = firsts[len(firsts) // 2]
            print(
                f"| {name} | {method} | {sum(v is not None for v in stops)} of {len(runs)} "
                f"| {', '.join(str(v) if v is not None else '-' for v in stops)} "
                f"| {first if first < 10**9 else '-'} |"
            )
    print()
    print("| key | track | seen in training | crashes, proposed | crashes, baseline | proposed - baseline (crashes) "
          "| laps per episode, proposed | laps per episode, baseline |")
    print("|---|---|---|---|---|---|---|---|")
    for name, prefix, seen in groups:
        for track in TRACKS:
            p = [level(f"{prefix}-s{k}", track) for k in seeds]
            b = [level(f"{prefix}-s{k}-baseline", track) for k in seeds]
            diff = [pc - bc for (pc, _), (bc, _) in zip(p, b)]
            print(
                f"| {name} | {track} | {'yes' if track in seen else 'no'} "
                f"| {fmt(*boot([c for c, _ in p]))} | {fmt(*boot([c for c, _ in b]))} "
                f"| {fmt(*boot(diff))} | {fmt(*boot([l for _, l in p]), pct=False)} "
                f"| {fmt(*boot([l for _, l in b]), pct=False)} |"
            )
            if copy:
                for run in [f"{prefix}-s{k}" for k in seeds] + [f"{prefix}-s{k}-baseline" for k in seeds]:
                    dst = copy / run
                    dst.mkdir(parents=True, exist_ok=True)
                    for f in ["summary.json", "metrics.csv", "evals.csv", "config.toml"]:
                        shutil.copy(Path("runs") / run / f, dst / f)
                for run in [f"{prefix}-s{k}" for k in seeds] + [f"{prefix}-s{k}-baseline" for k in seeds]:
                    dst = copy / run / f"robust-{track}"
                    dst.mkdir(parents=True, exist_ok=True)
                    shutil.copy(Path("runs") / run / f"robust-{track}" / "robust.json", dst / "robust.json")


if __name__ == "__main__":
    main(sys.argv[1:])
