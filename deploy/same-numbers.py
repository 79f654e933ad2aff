#!/usr/bin/env python3
"""Whether two run folders have the same numbers: metrics.csv (every column but the wall-clock times) and evals.csv,
row for row over the epochs both have (issue 46's bit-for-bit check of a speed-up).

    target/release/learner run --local -c docs/reproduction/<run>/config.toml --run-dir /tmp/check --fresh \\
        --set run.max_epochs=14
    deploy/same-numbers.py docs/reproduction/<run> /tmp/check

A column only one of the two tables has (a metric newer than the other run) is not compared. Exits 1 on a difference.
"""
import csv
import sys


def is_time(column):
    """A wall clock: collect_s, train_s, epoch_s, evaluate_s and the collection's phases (collect_<phase>_s)."""
    return column.endswith("_s")


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def main(a, b):
    differences = 0
    ma, mb = rows(f"{a}/metrics.csv"), rows(f"{b}/metrics.csv")
    n = min(len(ma), len(mb))
    columns = [c for c in ma[0] if c in mb[0] and not is_time(c)] if n else []
    for i in range(n):
        for c in columns:
            x, y = ma[i].get(c) or "", mb[i].get(c) or ""
            if x != y:
                differences += 1
                if differences <= 5:
                    print(f"metrics.csv row {i}, {c}: {x!r} against {y!r}")
    ea, eb = rows(f"{a}/evals.csv"), rows(f"{b}/evals.csv")
    m = min(len(ea), len(eb))
    shared = [c for c in ea[0] if c in eb[0]] if m else []
    for i in range(m):
        if any(ea[i][c] != eb[i][c] for c in shared):
            differences += 1
            if differences <= 10:
                print(f"evals.csv row {i}: {ea[i]} against {eb[i]}")
    print(f"{n} epochs and {m} evaluations compared: {differences} differences")
    return 1 if differences else 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    sys.exit(main(sys.argv[1], sys.argv[2]))
