#!/usr/bin/env python3
"""Issue 58, item 1: the discriminating runs side by side, from their kept run folders (docs/reproduction/<run>/).

    python3 docs/reproduction/issue-58/discriminate.py > docs/reproduction/issue-58/discriminate.md

Per run: the first 50-lap version and the early stop (summary.json), L_clone at epoch 0 and at the last epoch, the
first epoch at which D? holds more than 50 states and its size at epochs 10 and 25, and the evaluations' lengths
(evals.csv: the median over versions 0-9 and the longest before the first lap). The constant predictor's L_clone on
the same kind of data is `cabc probe`'s (docs/reproduction/issue-58/probe-v-a-cpu-s1.md).
"""
import csv, json, os, statistics, sys

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
GROUPS = [
    ("v-a-cpu-rerun", "none (v-a-cpu, issue 18's binaries)"),
    ("v-a-cpu-state", "full state instead of the camera"),
    ("v-a-cpu-aggregate", "DAgger's aggregate"),
    ("v-a-cpu-dart", "DART noise in collection"),
    ("v-a-cpu-dart-aggregate", "DART + aggregate (the lead)"),
    ("v-a-cpu-blind", "no velocity inputs"),
    ("v-a-cpu-vlong", "v_long alone"),
]


def rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def cell(run):
    d = os.path.join(ROOT, run)
    if not os.path.exists(os.path.join(d, "metrics.csv")):
        return None
    m = rows(os.path.join(d, "metrics.csv"))
    e = rows(os.path.join(d, "evals.csv")) if os.path.exists(os.path.join(d, "evals.csv")) else []
    s = json.load(open(os.path.join(d, "summary.json"))) if os.path.exists(os.path.join(d, "summary.json")) else {}
    first50 = next((int(r["version"]) for r in e if int(r["laps"]) >= 50), None)
    stop = s.get("early_stop_version")
    loss = [float(r["imitation_loss"]) for r in m if r["imitation_loss"]]
    du = [int(r["d_uncertain"]) for r in m]
    over50 = next((i for i, n in enumerate(du) if n > 50), None)
    first_lap = next((int(r["version"]) for r in e if int(r["laps"]) > 0), None)
    before = [int(r["steps"]) for r in e if first_lap is None or int(r["version"]) < first_lap]
    early = [int(r["steps"]) for r in e if int(r["version"]) < 10]
    return {
        "epochs": len(m),
        "first50": first50,
        "stop": stop,
        "l0": loss[0] if loss else None,
        "llast": loss[-1] if loss else None,
        "over50": over50,
        "du10": du[10] if len(du) > 10 else None,
        "du25": du[25] if len(du) > 25 else None,
        "eval_med": statistics.median(early) if early else None,
        "eval_max": max(before) if before else None,
    }


def fmt(x, spec=""):
    return "—" if x is None else format(x, spec)


print("| keys | run | epochs | 1st 50 laps | early stop | L_clone epoch 0 | L_clone last | D? > 50 from epoch | D? at 10 | D? at 25 | eval steps, median v0-9 | longest eval before a lap |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for group, what in GROUPS:
    for k in (1, 2, 3):
        run = f"{group}-s{k}"
        c = cell(run)
        if c is None:
            continue
        print(
            f"| {what} | `{run}` | {c['epochs']} | {fmt(c['first50'])} | {fmt(c['stop'])} | {fmt(c['l0'], '.4f')} | "
            f"{fmt(c['llast'], '.4f')} | {fmt(c['over50'])} | {fmt(c['du10'])} | {fmt(c['du25'])} | "
            f"{fmt(c['eval_med'])} | {fmt(c['eval_max'])} |"
        )
