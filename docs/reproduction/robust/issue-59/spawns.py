#!/usr/bin/env python3
"""Issue 59 item 3, a first look: which random spawns the default's early-stopped policies crash from.

    for k in 1 2 3; do target/release/cabc robust runs/v-b-s$k --spawns 50 --laps 50 --action-noise 0.02,0.005 \
        --state-noise 0.002 --levels 0,1 --out /tmp/robust-v-b-main-s$k; done   # runs/v-b-s<k>: the idle runs
    python3 docs/reproduction/robust/issue-59/spawns.py docs/reproduction/robust/issue-59/v-b-main-s*.json

Crashes per level by the spawn's place on the track (s), speed (v_long) and lateral offset (|x_tran|)."""
import json, statistics, sys

rows = []
for path in sys.argv[1:]:
    d = json.load(open(path))
    for level in d["levels"]:
        for p, o in zip(d["spawn_points"], level["outcomes"]):
            rows.append((level["level"], p["s"], p["v_long"], abs(p["x_tran"]), o["crashed"], o["steps"], o["laps"]))

for level in sorted({r[0] for r in rows}):
    r = [x for x in rows if x[0] == level]
    crashed = [x for x in r if x[4]]
    steps = statistics.median([x[5] for x in crashed]) if crashed else None
    print(f"\nlevel {level}: {len(crashed)} crashes of {len(r)}; median steps before a crash {steps}; "
          f"crashes before the first lap {sum(1 for x in crashed if x[6] == 0)}")
    print("| by | bin | crashes |\n|---|---|---|")
    for name, i, bins in (("s (m)", 1, [(0, 5), (5, 10), (10, 15), (15, 100)]),
                          ("v_long (m/s)", 2, [(0.5, 1.0), (1.0, 1.5), (1.5, 2.01)]),
                          ("abs(x_tran) (m)", 3, [(0, 0.05), (0.05, 0.1), (0.1, 0.2), (0.2, 1.0)])):
        for lo, hi in bins:
            rr = [x for x in r if lo <= x[i] < hi]
            print(f"| {name} | [{lo}, {hi}) | {sum(1 for x in rr if x[4])} of {len(rr)} |")
