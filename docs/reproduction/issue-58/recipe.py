#!/usr/bin/env python3
"""Issue 58, item 2: a group's cells over seeds 42-51 (first 50-lap version · early stop), both methods, from the
kept run folders.   python3 docs/reproduction/issue-58/recipe.py v-a-cpu-dart v-a-cpu-blind"""
import csv, json, os, sys

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def cell(run):
    d = os.path.join(ROOT, run)
    if not os.path.exists(os.path.join(d, "evals.csv")):
        return ""
    evals = list(csv.DictReader(open(os.path.join(d, "evals.csv"))))
    first = next((r["version"] for r in evals if int(r["laps"]) >= 50), None)
    s = json.load(open(os.path.join(d, "summary.json"))) if os.path.exists(os.path.join(d, "summary.json")) else {}
    stop = s.get("early_stop_version")
    if first is None:
        best = max((int(r["laps"]) for r in evals), default=0)
        return f"no 50 laps ({best}) in {s.get('epochs', len(evals))}"
    return f"{first} · {stop if stop is not None else 'no stop'}"


print("| group | method | " + " | ".join(str(41 + k) for k in range(1, 11)) + " |")
print("|---|---|" + "---|" * 10)
for group in sys.argv[1:]:
    for method, suffix in (("proposed", ""), ("baseline", "-baseline")):
        cells = [cell(f"{group}-s{k}{suffix}") for k in range(1, 11)]
        print(f"| `{group}` | {method} | " + " | ".join(cells) + " |")
