#!/usr/bin/env python3
"""Issue 64's chaos table: one row per run of docs/chaos/<run>/chaos.json (deploy/chaos.sh's report), beside the
undisturbed run of the same seed (its summary.json: docs/reproduction/v-b-robust-judged-s<k>/, or docs/chaos/calm-v-b-s<k>/
when it ran here). A fault's cost is its epoch's interval less the median of the epochs without one; an epoch struck
twice is counted once, under its first fault.

    python3 docs/chaos/table.py > docs/chaos/table.md
"""
import json
import statistics
from pathlib import Path

here = Path(__file__).resolve().parent
repro = here.parent / "reproduction"


def calm(k, name):
    # The first measure (chaos-v-b-s<k>) ran on another machine: its undisturbed runs are the recorded ones. Later
    # measures ran beside calm-v-b-s<k> (`run.sh --calm`), on their machine and binaries.
    here_first = (here / f"calm-v-b-s{k}" / "summary.json",) if name != f"chaos-v-b-s{k}" else ()
    for path in here_first + (repro / f"v-b-robust-judged-s{k}" / "summary.json",):
        if path.exists():
            return json.loads(path.read_text()), path.parent
    return None, None


def cost(faults, role):
    seen, costs = set(), []
    for f in faults:
        if f["lost_s"] is None or f["epoch"] in seen:
            continue
        seen.add(f["epoch"])
        if f["role"] == role:
            costs.append(f["lost_s"])
    return costs


def fmt(costs):
    if not costs:
        return "–"
    return f"{statistics.median(costs):.1f} [{min(costs):.1f}–{max(costs):.1f}] ({len(costs)})"


ROLES = ["router", "learner", "expert", "actor", "evaluator"]


def kinds(faults):
    kills = sum(f.get("kind", "kill") == "kill" for f in faults)
    return f"{kills} kills, {len(faults) - kills} pauses"


reports = sorted(here.glob("*-v-b-s*/chaos.json"))
print("| run | faults (router / learner / expert / actor / evaluator) | kinds | wall clock | stalls "
      "| steps published / stored | epochs short | duplicates | early stop (undisturbed) "
      + "".join(f"| cost of a fault: {role}, s " for role in ROLES) + "|")
print("|---|---|---|---|---|---|---|---|---|" + "---|" * len(ROLES))
for report_path in reports:
    r = json.loads(report_path.read_text())
    k = int(report_path.parent.name.rsplit("-s", 1)[1])
    undisturbed, where = calm(k, report_path.parent.name)
    by = r["faults_by_target_role"]
    stop = r["early_stop_version"]
    base = undisturbed.get("early_stop_version") if undisturbed else None
    rel = f" ({base}: {100 * (stop - base) / base:+.0f} %)" if stop is not None and base else f" ({base})"
    print(
        f"| {report_path.parent.name} | {len(r['faults'])} ("
        + " / ".join(str(by.get(role, 0)) for role in ROLES)
        + f") | {kinds(r['faults'])} | {r['wall_s'] / 60:.1f} min | {r['stalls']} | "
        f"{r['steps_published']} / {r['steps_stored']} | {r['epochs_short']} | {r['duplicate_segments']} | "
        f"{stop}{rel} | " + " | ".join(fmt(cost(r["faults"], role)) for role in ROLES) + " |"
    )
print()
print("Median epoch interval without a fault (s): " + ", ".join(
    f"{p.parent.name} {json.loads(p.read_text())['median_epoch_s']:.1f}" for p in reports))

# The audit (issue 74): the runs whose actors kept a journal, each published segment's fate (`cabc audit`).
audited = [(p, json.loads(p.read_text())) for p in reports]
audited = [(p, r) for p, r in audited if r.get("audit")]
if audited:
    FATES = ["stored", "refused", "never_sent", "in_flight_at_its_actors_end", "held_by_a_learner_that_stopped",
             "after_the_runs_end", "lost"]
    print()
    print("| run | bus | actor / learner processes | segments published | " + " | ".join(
        f.replace("_", " ") for f in FATES) + " | copies dropped | steps never published: staged / in flight | problems |")
    print("|---|---|---|---|" + "---|" * len(FATES) + "---|---|---|")
    for p, r in audited:
        a = r["audit"]
        fates = a["fates"]
        total = sum(c["segments"] for c in fates.values())
        steps = sum(c["steps"] for c in fates.values())
        cells = [str(fates.get(f, {}).get("segments", 0)) for f in FATES]
        config = (p.parent / "config.toml").read_text() if (p.parent / "config.toml").exists() else ""
        bus = "mutual TLS" if 'mode = "mtls"' in config else "plain"
        print(f"| {p.parent.name} | {bus} | {a['actor_processes']} / {a['learner_processes']} | {total} ({steps} steps) | "
              + " | ".join(cells)
              + f" | {r['duplicate_segments']} | {a['never_published_staged']} / {a['never_published_in_flight']} | "
              + f"{len(r.get('audit_problems', []))} |")
