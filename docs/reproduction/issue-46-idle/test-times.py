#!/usr/bin/env python3
"""deploy/test.sh's time, run by run and test binary by test binary (issue 46, item 5).

    test-times.py LABEL=DIR [LABEL=DIR ...]

Each DIR is a copy of a run's target/test-logs/: workspace.log and learning-oldest-kernels.log (cargo's output, whose
"finished in" lines time each test binary) and times.txt (the steps' seconds, which test.sh writes from d2c3feb on).
An older test.sh wrote no times.txt: then DIR also holds its output as test.log, and the logs copied with their
modification times (`cp -p`), which end the steps. Prints a Markdown table of the steps, then one of the test
binaries that take a second or more in any run.
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
    """{step: seconds} from times.txt, or from test.log and the logs' modification times (an older test.sh)."""
    times = folder / "times.txt"
    if times.exists():
        return {name: int(seconds) for name, seconds, _ in map(str.split, times.read_text().splitlines())}
    log = (folder / "test.log").read_text(errors="replace")
    total = int(re.search(r"all steps took (\d+) s", log).group(1))
    build = int(re.search(r"release build took (\d+) s", log).group(1))
    ends = [(n, (folder / f"{n}.log").stat().st_mtime) for n in ("workspace", "learning-oldest-kernels", "python")]
    begin = ends[-1][1] - total + build
    out = {"build": build}
    for name, end in ends:
        out[name], begin = round(end - begin), end
    out["all"] = total
    return out


def main(args):
    if not args or any("=" not in a for a in args):
        sys.exit(__doc__)
    runs = [(label, Path(folder)) for label, folder in (a.split("=", 1) for a in args)]
    for _, folder in runs:
        if not (folder / "times.txt").exists() and not (folder / "test.log").exists():
            sys.exit(f"{folder} has neither times.txt nor test.log")
    labels = [label for label, _ in runs]
    head = "| {} | " + " | ".join(labels) + " |"
    rule = "|---|" + "---|" * len(runs)

    table = [steps(folder) for _, folder in runs]
    names = list(dict.fromkeys(n for t in table for n in t))
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
