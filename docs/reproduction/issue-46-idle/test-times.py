#!/usr/bin/env python3
"""deploy/test.sh's time, run by run and test binary by test binary (issue 46, item 5).

    test-times.py LABEL=DIR [LABEL=DIR ...]

Each DIR is a copy of a run's target/test-logs/: workspace.log and learning-oldest-kernels.log (cargo's output, whose
"finished in" lines time each test binary) and times.txt (the steps' seconds, which test.sh writes from d2c3feb on;
for an older test.sh, a times.txt of the same form written from its logs' modification times). Prints a Markdown
table of the steps, then one of the test binaries that take a second or more in any run.
"""
import re
import sys
from pathlib import Path

RUNNING = re.compile(r"\s*Running (.+?) \(.*/deps/(\w+?)-[0-9a-f]+\)")
RESULT = re.compile(r"test result: \w+\. (\d+) passed.*finished in ([0-9.]+)s")


def binaries(log):
    """{binary: (tests passed, seconds)} from cargo test's output."""
    out, current = {}, None
    if not log.exists():
        return out
    for line in log.read_text(errors="replace").splitlines():
        m = RUNNING.match(line)
        if m:
            path, name = m.groups()
            current = f"{name} ({path.split()[-1]})" if path.startswith("tests/") else f"{name} (unit)"
            continue
        m = RESULT.search(line)
        if m and current:
            key, i = current, 2
            while key in out:  # two crates with a test file of the same name
                key, i = f"{current} #{i}", i + 1
            out[key] = (int(m.group(1)), float(m.group(2)))
            current = None
    return out


def steps(folder):
    """{step: seconds} from times.txt."""
    out = {}
    for line in (folder / "times.txt").read_text().splitlines():
        name, seconds, _ = line.split()
        out[name] = int(seconds)
    return out


def main(args):
    if not args or any("=" not in a for a in args):
        sys.exit(__doc__)
    runs = [(label, Path(folder)) for label, folder in (a.split("=", 1) for a in args)]
    for _, folder in runs:
        if not (folder / "times.txt").exists():
            sys.exit(f"{folder}/times.txt is missing")
    labels = [label for label, _ in runs]
    head = "| {} | " + " | ".join(labels) + " |"
    rule = "|---|" + "---|" * len(runs)

    table = [steps(folder) for _, folder in runs]
    names = [n for n in ("build", "workspace", "learning-oldest-kernels", "python", "all") if any(n in t for t in table)]
    print(head.format("step (s)"))
    print(rule)
    for n in names:
        print(f"| {n} | " + " | ".join(str(t.get(n, "—")) for t in table) + " |")

    for log in ("workspace.log", "learning-oldest-kernels.log"):
        per_run = [binaries(folder / log) for _, folder in runs]
        keys = sorted(set().union(*per_run), key=lambda k: -max(r.get(k, (0, 0.0))[1] for r in per_run))
        print()
        print(head.format(f"{log}: test binary (tests, s)"))
        print(rule)
        for k in keys:
            if max(r.get(k, (0, 0.0))[1] for r in per_run) < 1.0:
                continue
            cells = [f"{r[k][0]}, {r[k][1]:.1f}" if k in r else "—" for r in per_run]
            print(f"| {k} | " + " | ".join(cells) + " |")
        totals = [f"{sum(n for n, _ in r.values())}, {sum(s for _, s in r.values()):.1f}" for r in per_run]
        print("| all binaries | " + " | ".join(totals) + " |")


if __name__ == "__main__":
    main(sys.argv[1:])
