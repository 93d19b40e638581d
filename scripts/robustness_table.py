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
of scans that needed a re-scan. A run with no perception (exact observation, e.g. noisy
execution alone, or an exact run given as a mode) says so instead of printing rates of nothing.
A directory without episodes.jsonl is one line on stderr and exit code 2.
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


class BadRun(ValueError):
    """A run directory the script cannot read."""


def _episodes(argument: str) -> list[dict]:
    """Every ok episode record of the comma-separated run directories."""
    out = []
    for directory in argument.split(","):
        path = Path(directory) / "episodes.jsonl"
        if not path.is_file():
            raise BadRun(f"{str(path)!r}: no such file; give `packlab bench --out` directories")
        with open(path, encoding="utf-8") as lines:
            out += [r for r in map(json.loads, filter(str.strip, lines)) if r.get("status") == "ok"]
    return out


def _levels(records: list[dict]) -> list[str]:
    """The bench's levels first, in their order, then any other difficulty the runs hold."""
    seen = {r["difficulty"] for r in records}
    return [lv for lv in LEVELS if lv in seen] + sorted(seen - set(LEVELS))


def _strata(
    records: list[dict], policy: str, levels: list[str]
) -> list[dict[str, dict[str, float]]]:
    """Per level: case id -> seed -> Overall, for one policy."""
    by_level: dict[str, dict[str, dict[str, float]]] = {level: {} for level in levels}
    for r in records:
        if r["policy"] == policy and r["difficulty"] in by_level:
            by_level[r["difficulty"]].setdefault(r["case_id"], {})[str(r["seed"])] = r["metrics"][
                "overall"
            ]
    return [by_level[level] for level in levels]


def _share(part: int, whole: int) -> str:
    return f"{part} of {whole} ({100 * part / whole:.2f} %)" if whole else f"{part} of 0"


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
    levels = _levels(exact + [r for records in modes.values() for r in records])
    for policy in policies:
        base = _strata(exact, policy, levels)
        runs = [_strata(modes[label], policy, levels) for label in labels]
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
    if not scans:
        print("- no perception in this run (exact observation): no perception errors to show")
    for name, v in values.items():
        a = np.array(v)
        print(
            f"- {name}: mean {a.mean():.3f}, p95 {np.percentile(a, 95):.3f}, max {a.max():.3f} "
            f"(n = {len(a)})"
        )
    missed = sum(r["metrics"].get("missed", 0) for r in records)
    objects = sum(r["metrics"]["n_objects"] for r in records)
    print(f"- objects missed (set aside): {_share(missed, objects)}")
    if scans:
        print(f"- steps that needed a re-scan: {_share(rescans, scans)}")


def main(argv: list[str]) -> int:
    if argv in (["-h"], ["--help"]):
        print(__doc__)
        return 0
    if len(argv) < 2 or any("=" not in a for a in argv[1:]):
        print(__doc__, file=sys.stderr)
        return 2
    try:
        exact = _episodes(argv[0])
        modes = {a.split("=", 1)[0]: _episodes(a.split("=", 1)[1]) for a in argv[1:]}
    except BadRun as exc:
        print(f"robustness_table: error: {exc}", file=sys.stderr)
        return 2
    seeds = sorted({r["seed"] for r in exact})
    print(f"Average Overall, {len({r['case_id'] for r in exact})} cases, seeds {seeds}\n")
    _table(exact, modes)
    for label, records in modes.items():
        print(f"\nPerception ({label}):")
        _errors(records)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
