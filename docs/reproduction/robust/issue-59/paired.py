#!/usr/bin/env python3
"""Issue 59 item 3: crashes from `cabc robust`'s 50 random spawns per seed, the proposed method beside its baseline,
for a group of runs (its reports kept here, or under docs/reproduction/robust/ for issue 45's), and the goal's count:
the proposed policy crashes no more often than its baseline without noise, and less often under noise.

    python3 docs/reproduction/robust/issue-59/paired.py v-b-dart                                   # reports here
    python3 docs/reproduction/robust/issue-59/paired.py v-b-frozen-eq14-hinged v-b-frozen ..       # issue 45's
    SEEDS=960-962 python3 docs/reproduction/robust/issue-59/paired.py v-b-dart-sensor     # held out: 1001-1003
"""
import json, os, sys

here = os.path.dirname(os.path.abspath(__file__))
group = sys.argv[1]
baseline_group = sys.argv[2] if len(sys.argv) > 2 else group
folder = os.path.join(here, sys.argv[3]) if len(sys.argv) > 3 else here
first, last = map(int, os.environ.get("SEEDS", "1-10").split("-"))


def crashes(run):
    path = os.path.join(folder, run + ".json")
    if not os.path.exists(path):
        return None
    levels = {l["level"]: l["crashes"] for l in json.load(open(path))["levels"]}
    return levels[0.0], levels[1.0]


print(f"| seed | {group}: crashes without noise | with noise | baseline: without | with | "
      "no more without noise | fewer with noise |")
print("|---|---|---|---|---|---|---|")
totals, wins = [0, 0, 0, 0], [0, 0, 0]
for k in range(first, last + 1):
    p, b = crashes(f"{group}-s{k}"), crashes(f"{baseline_group}-s{k}-baseline")
    if p is None or b is None:
        continue
    calm, noisy = p[0] <= b[0], p[1] < b[1]
    for i, v in enumerate(p + b):
        totals[i] += v
    wins[0] += calm
    wins[1] += noisy
    wins[2] += 1
    print(f"| {41 + k} | {p[0]} | {p[1]} | {b[0]} | {b[1]} | {'yes' if calm else 'no'} | {'yes' if noisy else 'no'} |")
n = wins[2]
print(f"| all ({n} seeds, of {50 * n} episodes each) | {totals[0]} | {totals[1]} | {totals[2]} | {totals[3]} | "
      f"{wins[0]} of {n} | {wins[1]} of {n} |")
