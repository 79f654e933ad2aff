#!/usr/bin/env python3
"""Issue 65 item 3's table: each run's crashes under `cabc robust` at the early stop's settings (judge) and at
settings it never used (unseen: wider spawns), per noise level (0, 1 = the judge's noise, 2 = twice), with Wilson
95 % intervals; then per method, summed over its runs; then per seed, the proposed policy against each baseline of
its experiment on the same seed (fewer crashes / as many / more), and the mean difference of their crash rates with
a bootstrap 95 % interval over the seeds (10000 resamples, seed 0). Reads <run>/{judge,unseen}.json beside this file
(unseen.sh).

    python3 docs/reproduction/robust/issue-65/table.py [--readme]

With --readme the tables go into README.md beside this file, between its markers (`<!-- table.py -->` and
`<!-- end table.py -->`), the summed and the paired-difference tables into docs/REPRODUCTION.md (between
`<!-- robust-issue-65 -->` and `<!-- end robust-issue-65 -->`), instead of stdout, and the figure robust.svg beside it
is drawn: per method summed over
its runs, the crash share with its Wilson interval, a panel per test and noise level.
"""
import json
import math
import random
import re
import sys
from pathlib import Path

here = Path(__file__).resolve().parent
readme = "--readme" in sys.argv[1:]
if readme:
    import io

    out, sys.stdout = sys.stdout, io.StringIO()


def wilson(k, n, z=1.959963984540054):
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return (max(0.0, c - h), min(1.0, c + h))


def method(run):
    # V-C's protocols apart: the reference's (v-c-ref-*ten), its variant (v-c-ref-*variant-ten) and the variant
    # with the judged early stop (v-c-ref-variant-judged).
    if run.startswith("v-b-auto-"):
        experiment = "V-B, an actor per core"
    elif run.startswith("v-b-tol-1e-2-"):
        experiment = "V-B, MPCC tolerances 1e-2"
    elif "variant-judged" in run:
        experiment = "V-C variant, judged stop"
    elif "variant" in run:
        experiment = "V-C variant"
    elif run.startswith("v-c"):
        experiment = "V-C"
    else:
        experiment = "V-B (the default)"
    if "-bc-" in run:
        return f"{experiment}, plain BC (lambda 0)"
    return f"{experiment}, " + ("baseline" if run.endswith("-baseline") else "proposed")


EXPERIMENTS = ["V-B (the default)", "V-B, an actor per core", "V-B, MPCC tolerances 1e-2", "V-C", "V-C variant", "V-C variant, judged stop"]


def order(m):
    """Methods in the experiments' order (a later experiment's rows, and their bootstrap draws, after the earlier)."""
    experiment = m.rsplit(", ", 1)[0]
    return (EXPERIMENTS.index(experiment) if experiment in EXPERIMENTS else len(EXPERIMENTS), m)


def cell(k, n):
    lo, hi = wilson(k, n)
    return f"{k}/{n} [{lo:.2f}, {hi:.2f}]"


runs = sorted(p for p in here.iterdir() if (p / "judge.json").exists() and (p / "unseen.json").exists())
levels = [0.0, 1.0, 2.0]
head = " | ".join(f"{t}, noise x{l:g}" for t in ("judge", "unseen") for l in levels)
print(f"| run | method | {head} |")
print("|---|---|" + "---|" * (2 * len(levels)))
# (run, test, level) -> crashes, episodes: each report read once.
crashes = {}
episodes = {}
for run in runs:
    for test in ("judge", "unseen"):
        report = json.loads((run / f"{test}.json").read_text())
        for l in report["levels"]:
            crashes[(run.name, test, l["level"])] = l["crashes"]
            episodes[(run.name, test, l["level"])] = l["episodes"]
sums = {}
for run in runs:
    cells = []
    for test in ("judge", "unseen"):
        for level in levels:
            key = (run.name, test, level)
            cells.append(cell(crashes[key], episodes[key]))
            s = sums.setdefault((method(run.name), test, level), [0, 0])
            s[0] += crashes[key]
            s[1] += episodes[key]
    print(f"| {run.name} | {method(run.name)} | " + " | ".join(cells) + " |")
print()
print(f"| method | runs | {head} |")
print("|---|---|" + "---|" * (2 * len(levels)))
for m in sorted({method(r.name) for r in runs}, key=order):
    n = sum(method(r.name) == m for r in runs)
    cells = [cell(*sums[(m, t, l)]) for t in ("judge", "unseen") for l in levels]
    print(f"| {m} | {n} | " + " | ".join(cells) + " |")


def seed_of(run):
    return int(re.search(r"-s(\d+)(-baseline)?$", run).group(1))


def tally(pairs, t, l):
    """Over `pairs` of runs (first, second) at test t and level l: on how many the first crashed less, as often and
    more, and the crashes summed (first / second)."""
    a = [crashes[(p, t, l)] for p, _ in pairs]
    b = [crashes[(q, t, l)] for _, q in pairs]
    less = sum(x < y for x, y in zip(a, b))
    same = sum(x == y for x, y in zip(a, b))
    more = sum(x > y for x, y in zip(a, b))
    return f"{less} / {same} / {more} ({sum(a)} / {sum(b)})"


def shift(pairs, t, l, rng):
    """The crash rate's difference, first minus second, in points: the mean over `pairs` with its bootstrap 95 %
    interval (10000 resamples of the pairs drawn from `rng`)."""
    d = [100.0 * (crashes[(p, t, l)] / episodes[(p, t, l)] - crashes[(q, t, l)] / episodes[(q, t, l)])
         for p, q in pairs]
    means = sorted(sum(rng.choice(d) for _ in d) / len(d) for _ in range(10000))
    return f"{sum(d) / len(d):+.1f} [{means[249]:+.1f}, {means[9749]:+.1f}]"


differences = []
print()
print("Per seed, the proposed policy against a baseline's on the same seed: the seeds where it crashed less, as "
      "often, more (crashes summed over those seeds, proposed / baseline).")
print()
print(f"| proposed against | seeds | {head} |")
print("|---|---|" + "---|" * (2 * len(levels)))
for m in sorted({method(r.name) for r in runs}, key=order):
    if m.endswith("proposed"):
        continue
    experiment = m.split(",")[0]
    pairs = []
    for r in runs:
        if method(r.name) != m:
            continue
        mates = [q.name for q in runs if method(q.name) == f"{experiment}, proposed" and seed_of(q.name) == seed_of(r.name)]
        if mates:
            pairs.append((mates[0], r.name))
    if not pairs:
        continue
    cells = [tally(pairs, t, l) for t in ("judge", "unseen") for l in levels]
    print(f"| {m} | {len(pairs)} | " + " | ".join(cells) + " |")
    differences.append((m, pairs))

print()
print("The crash rate's difference, proposed minus baseline, in points, the mean over the paired seeds with its "
      "bootstrap 95 % interval over seeds (below 0: the proposed policy crashes less).")
print()
print(f"| proposed against | seeds | {head} |")
print("|---|---|" + "---|" * (2 * len(levels)))
rng = random.Random(0)
for m, pairs in differences:
    cells = [shift(pairs, t, l, rng) for t in ("judge", "unseen") for l in levels]
    print(f"| {m} | {len(pairs)} | " + " | ".join(cells) + " |")



def figure(path):
    """robust.svg: a panel per (test, level), a row per method: the summed crash share, a dot, and its Wilson 95 %
    interval, a line; the axis from 0 to 1."""
    methods = sorted({method(r.name) for r in runs}, key=order)
    colours = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
               "#17becf"]
    label_w, panel_w, row_h, top, gap = 290, 150, 22, 46, 12
    panels = [(t, l) for t in ("judge", "unseen") for l in levels]
    width = label_w + len(panels) * (panel_w + gap) + 10
    height = top + len(methods) * row_h + 40
    svg = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="sans-serif" '
           f'font-size="11"><rect width="100%" height="100%" fill="white"/>',
           f'<text x="10" y="16" font-size="13">Crashes from random spawns under cabc robust, per method summed over '
           f'its runs: the share and its Wilson 95 % interval</text>']
    for i, m in enumerate(methods):
        y = top + i * row_h + row_h / 2
        n = sum(method(r.name) == m for r in runs)
        svg.append(f'<text x="10" y="{y + 4:.1f}" fill="{colours[i % len(colours)]}">{m} ({n} runs)</text>')
    for j, (t, l) in enumerate(panels):
        x0 = label_w + j * (panel_w + gap)
        svg.append(f'<text x="{x0}" y="{top - 8}">{t}, noise x{l:g}</text>')
        svg.append(f'<rect x="{x0}" y="{top}" width="{panel_w}" height="{len(methods) * row_h}" fill="none" '
                   f'stroke="#999"/>')
        for tick in (0.0, 0.5, 1.0):
            x = x0 + tick * panel_w
            svg.append(f'<line x1="{x:.1f}" y1="{top}" x2="{x:.1f}" y2="{top + len(methods) * row_h}" '
                       f'stroke="#ddd"/>')
            svg.append(f'<text x="{x:.1f}" y="{top + len(methods) * row_h + 14}" text-anchor="middle">{tick:g}</text>')
        for i, m in enumerate(methods):
            k, n = sums[(m, t, l)]
            lo, hi = wilson(k, n)
            y = top + i * row_h + row_h / 2
            c = colours[i % len(colours)]
            svg.append(f'<line x1="{x0 + lo * panel_w:.1f}" y1="{y:.1f}" x2="{x0 + hi * panel_w:.1f}" y2="{y:.1f}" '
                       f'stroke="{c}" stroke-width="2"/>')
            svg.append(f'<circle cx="{x0 + k / n * panel_w:.1f}" cy="{y:.1f}" r="4" fill="{c}"/>')
    svg.append(f'<text x="{label_w}" y="{height - 6}">crash share (crashes / episodes); judge: the early stop\'s '
               f'spawn ranges, unseen: wider; x1: the default early stop\'s noise</text>')
    svg.append("</svg>")
    path.write_text("\n".join(svg) + "\n")


# The judged block: each judged run beside its twin, the same seed and method under the fixed-spawn stop (a judged
# run is that run up to its stop, then goes on until the judge passes twice).
twins = [(q.name.replace("variant-judged", "variant-ten"), q.name) for q in runs if "variant-judged" in q.name]
twins = [(a, b) for a, b in twins if (a, "judge", 0.0) in crashes]
if twins:
    def stop(run):
        summary = here.parents[1] / run / "summary.json"
        return json.loads(summary.read_text()).get("early_stop_version") if summary.exists() else None

    print()
    print("The judged stop against the fixed-spawn stop: each judged run's policy beside its twin's, the same seed and "
          "method without the judged stop (crashes of 20, twin / judged).")
    print()
    print(f"| judged run | stop, twin / judged | {head} |")
    print("|---|---|" + "---|" * (2 * len(levels)))
    for a, b in twins:
        cells = [f"{crashes[(a, t, l)]} / {crashes[(b, t, l)]}" for t in ("judge", "unseen") for l in levels]
        print(f"| {b} | {stop(a)} / {stop(b)} | " + " | ".join(cells) + " |")
    # Over the pairs: where the judged policy crashed less, as often, more (sums judged / twin), and the crash
    # rate's difference, judged minus twin, in points: the mean over pairs with its bootstrap 95 % interval.
    judged_first = [(b, a) for a, b in twins]
    twin_rng = random.Random(0)
    counts = [tally(judged_first, t, l) for t in ("judge", "unseen") for l in levels]
    shifts = [shift(judged_first, t, l, twin_rng) for t in ("judge", "unseen") for l in levels]
    print(f"| {len(twins)} pairs: judged fewer / as many / more (judged / twin) | | " + " | ".join(counts) + " |")
    print(f"| {len(twins)} pairs: judged minus twin, points, mean [95 % CI] | | " + " | ".join(shifts) + " |")


def paired(prefix, other, title):
    """Each `prefix` run beside the `other` run of its seed and method: the seeds where it crashed less, as often,
    more, and the crash rate's difference in points (a mean over seeds, bootstrap 95 % interval)."""
    pairs_all = [(q.name, q.name.replace(prefix, other)) for q in runs if q.name.startswith(prefix)]
    pairs_all = [(a, b) for a, b in pairs_all if (b, "judge", 0.0) in crashes]
    if not pairs_all:
        return
    print()
    print(title)
    print()
    print(f"| method | seeds | {head} |")
    print("|---|---|" + "---|" * (2 * len(levels)))
    rng = random.Random(0)
    for kind in ("proposed", "baseline"):
        pairs = [(a, b) for a, b in pairs_all if a.endswith("-baseline") == (kind == "baseline")]
        if pairs:
            counts = [tally(pairs, t, l) for t in ("judge", "unseen") for l in levels]
            shifts = [shift(pairs, t, l, rng) for t in ("judge", "unseen") for l in levels]
            print(f"| {kind}: fewer / as many / more | {len(pairs)} | " + " | ".join(counts) + " |")
            print(f"| {kind}: difference, points | {len(pairs)} | " + " | ".join(shifts) + " |")


# Issue 75: the default with an actor per core (`v-b-auto-*`, two actors here) against the default with one
# (`calm-v-b-*`), seed by seed, each method.
paired("v-b-auto-", "calm-v-b-",
       "An actor per core against one actor (issue 75): each v-b-auto run beside calm-v-b's on the same seed and "
       "method; the seeds where it crashed less, as often, more (crashes summed, an actor per core / one), then "
       "the crash rate's difference in points, a mean over seeds with its bootstrap 95 % interval (below 0: fewer "
       "crashes with an actor per core).")
# Issue 75, a later session: the MPCC at tolerances 1e-2 / 1e-3 (`v-b-tol-1e-2-*`) against the default's
# (`v-b-auto-*`, the same two actors), seed by seed, each method.
paired("v-b-tol-1e-2-", "v-b-auto-",
       "The MPCC at tolerances 1e-2 / 1e-3 against the reference's (issue 75): each v-b-tol-1e-2 run beside "
       "v-b-auto's on the same seed and method (both two actors); the seeds where it crashed less, as often, more "
       "(crashes summed, looser / reference), then the crash rate's difference in points, a mean over seeds with "
       "its bootstrap 95 % interval (below 0: fewer crashes with the looser expert).")


def splice(path, name, middle):
    """Puts `middle` between the markers `<!-- NAME -->` and `<!-- end NAME -->` of the file at `path`."""
    text = path.read_text()
    start, end = f"<!-- {name} -->\n", f"<!-- end {name} -->\n"
    if start not in text or end not in text:
        sys.exit(f"{path}: no markers {start.strip()} ... {end.strip()}")
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    path.write_text(head + start + middle + end + tail)


if readme:
    figure(here / "robust.svg")
    tables, sys.stdout = sys.stdout.getvalue(), out
    splice(here / "README.md", "table.py", tables)
    blocks = tables.split("\n\n")
    summed = next(b for b in blocks if b.startswith("| method | runs |"))
    difference = [b for b in blocks if b.startswith("| proposed against")][-1]
    report = here.parents[2] / "REPRODUCTION.md"
    splice(report, "robust-issue-65",
           summed.strip() + "\n\nThe crash rate's difference, proposed minus baseline, in points: the mean over the "
           "paired seeds with its\nbootstrap 95 % interval over seeds (below 0: the proposed policy crashes "
           "less).\n\n" + difference.strip() + "\n")
    print(f"wrote the tables into {here / 'README.md'}, {report} and the figure into {here / 'robust.svg'}")
