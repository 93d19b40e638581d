"""The robustness table of docs/perception.md: each policy's Overall under exact observation and
under one or more perceived / noisy runs, with intervals, and the perception's errors.

Usage: python scripts/robustness_table.py EXACT_RUNS LABEL=RUNS [LABEL=RUNS ...]

Each RUNS is a `packlab bench --out` directory or several, comma-separated, whose policies are
merged (e.g. the slow planner run apart). EXACT_RUNS is exact observation and execution; every
LABEL=RUNS a run of the same suite, backend and seeds in another mode (e.g.
``honest=runs/bench-perceived-noisy``). Printed, per policy: the average Overall of each run
with its 95 % bootstrap interval over cases (two-level over seeds for a policy whose scores vary
with the seed; ``packlab.bench.intervals``), the paired loss exact minus the first mode with its
paired interval (``*``: the interval excludes 0), objects perception missed per episode and
re-plans per episode in that mode; with more modes also each further mode minus the first
(paired the same way). Then, per mode, the perception errors over every estimate
(dims, yaw), every scan (heightmap MAE), with their counts, the missed-object rate and the share
of scans that needed a re-scan.
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from packlab.bench.intervals import bootstrap_interval, paired_difference, point_estimate
from packlab.viz.labels import display_name

LEVELS = ("easy", "medium", "hard")


def _episodes(argument: str) -> list[dict]:
    """Every ok episode record of the comma-separated run directories."""
    out = []
    for directory in argument.split(","):
        with open(Path(directory) / "episodes.jsonl", encoding="utf-8") as lines:
            out += [r for r in map(json.loads, lines) if r.get("status") == "ok"]
    return out


def _strata(records: list[dict], policy: str) -> list[dict[str, dict[str, float]]]:
    """Per level: case id -> seed -> Overall, for one policy."""
    by_level: dict[str, dict[str, dict[str, float]]] = {level: {} for level in LEVELS}
    for r in records:
        if r["policy"] == policy:
            by_level[r["difficulty"]].setdefault(r["case_id"], {})[str(r["seed"])] = r["metrics"][
                "overall"
            ]
    return [by_level[level] for level in LEVELS]


def _varies(strata) -> bool:
    return any(len(set(seeds.values())) > 1 for s in strata for seeds in s.values())


def _score(strata) -> str:
    mean = point_estimate(strata)
    interval = bootstrap_interval(strata, over_seeds=_varies(strata))
    if mean is None or interval is None:
        return "-"
    return f"{mean:.3f} [{interval.low:.3f}, {interval.high:.3f}]"


def _per_episode(records: list[dict], policy: str, key: str) -> str:
    values = [r["metrics"][key] for r in records if r["policy"] == policy and key in r["metrics"]]
    return f"{np.mean(values):.2f}" if values else "-"


def _loss(exact, mode) -> str:
    diff = paired_difference(exact, mode, over_seeds=_varies(exact) or _varies(mode))
    if diff is None:
        return "-"
    star = "*" if diff.interval.excludes(0.0) else ""
    return f"{diff.estimate:+.3f} [{diff.interval.low:+.3f}, {diff.interval.high:+.3f}]{star}"


def _table(exact: list[dict], modes: dict[str, list[dict]]) -> None:
    labels = list(modes)
    first = labels[0]
    others = [f" {label} - {first} |" for label in labels[1:]]
    print(
        "| Method | exact | "
        + " | ".join(labels)
        + f" | loss (exact - {first}) |"
        + "".join(others)
        + " missed / episode | re-plans / episode |"
    )
    print("|---|---|" + "---|" * (len(labels) + len(others)) + "---|---|---|")
    policies = list(dict.fromkeys(r["policy"] for r in modes[first]))
    for policy in policies:
        base = _strata(exact, policy)
        runs = [_strata(modes[label], policy) for label in labels]
        print(
            f"| {display_name(policy)} | {_score(base)} | "
            + " | ".join(_score(s) for s in runs)
            + f" | {_loss(base, runs[0])} | "
            + "".join(f"{_loss(other, runs[0])} | " for other in runs[1:])
            + f"{_per_episode(modes[first], policy, 'missed')} "
            f"| {_per_episode(modes[first], policy, 'replans')} |"
        )


def _errors(records: list[dict]) -> None:
    """The perception figures of one mode's episodes (with counts)."""
    values: dict[str, list[float]] = defaultdict(list)
    scans = rescans = 0
    for r in records:
        for step in r.get("steps", []):
            seen = step.get("perception")
            if not seen:
                continue
            values["dims error mm"] += [v for v in seen["dims_error_mm"] if v is not None]
            values["yaw error deg"] += [v for v in seen["yaw_error_deg"] if v is not None]
            if seen["heightmap_mae_mm"] is not None:
                values["heightmap MAE mm (per scan)"].append(seen["heightmap_mae_mm"])
            scans += 1
            rescans += seen.get("scans", 1) > 1
    for name, v in values.items():
        a = np.array(v)
        print(
            f"- {name}: mean {a.mean():.3f}, p95 {np.percentile(a, 95):.3f}, max {a.max():.3f} "
            f"(n = {len(a)})"
        )
    missed = sum(r["metrics"].get("missed", 0) for r in records)
    objects = sum(r["metrics"]["n_objects"] for r in records)
    print(f"- objects missed (set aside): {missed} of {objects} ({100 * missed / objects:.2f} %)")
    print(f"- steps that needed a re-scan: {rescans} of {scans} ({100 * rescans / scans:.2f} %)")


def main(argv: list[str]) -> None:
    if len(argv) < 2 or any("=" not in a for a in argv[1:]):
        sys.exit(__doc__)
    exact = _episodes(argv[0])
    modes = {a.split("=", 1)[0]: _episodes(a.split("=", 1)[1]) for a in argv[1:]}
    seeds = sorted({r["seed"] for r in exact})
    print(f"Average Overall, {len({r['case_id'] for r in exact})} cases, seeds {seeds}\n")
    _table(exact, modes)
    for label, records in modes.items():
        print(f"\nPerception ({label}):")
        _errors(records)


if __name__ == "__main__":
    main(sys.argv[1:])
