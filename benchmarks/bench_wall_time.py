r"""Wall time of the default ``packlab bench`` run, and time per decision of every policy.

Usage:
    python benchmarks/bench_wall_time.py                   # a quarter of the suite, extrapolated
    python benchmarks/bench_wall_time.py --fraction 1      # the whole default run, measured
    python benchmarks/bench_wall_time.py --records DIR     # only the tables, from an existing run
    python benchmarks/bench_wall_time.py --reuse both --difficulty easy   # reuse against none
    python benchmarks/bench_wall_time.py --honest structured-light \
        --policies dblf,hm,mta,ffp,sdf,plan-fast,vlm,irbpp,tapnet,proposer,random  # the robot path

It runs the default configuration (every heuristic + random + oracle, seeds 0,1,2, mujoco, all
local cores) on every k-th case of each difficulty of packlab-bench-v1, in a scratch directory,
and reports (``--honest PRESET``: the robot path instead, perceived + noisy with depth
segmentation under the preset, as the README's honest table; ``--policies`` the rows):

* the measured wall time and the extrapolation to the full suite: per difficulty, the summed
  episode CPU time scaled by (cases in the suite / cases run), divided by the parallel speed-up
  this run achieved (CPU time / wall time). Episode cost depends strongly on difficulty (hard
  piles take longest to settle), which is why the scaling is per difficulty;
* per policy and difficulty, the mean milliseconds per decision (``act``) and per environment
  step (placement + physics settling), from the records' timings.

The machine is shared: other processes' load shows up in these numbers, so the load average
at start and end is printed too.

Episodes the bench copied instead of playing (``reused_from_seed``, ``packlab.bench.reuse``)
carry the played episode's times; every sum and mean here counts played episodes only.
``--reuse both`` runs the configuration twice, with and without reuse (``--no-reuse``), and
prints per row the episodes played and copied, their summed episode wall and CPU seconds, the
run's wall time and the load average around each run.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

from msgspec import UNSET, UnsetType

from packlab.bench.config import RunConfig, local_cores, parse_physics
from packlab.bench.describe import difficulty_order
from packlab.bench.records import iter_ok, read_records
from packlab.bench.runner import run_bench
from packlab.bench.suites import DEFAULT_SUITE, load_suite
from packlab.cases import save_cases
from packlab.core.records import EpisodeOk, EpisodeRecord
from packlab.viz.labels import display_name


def subset(fraction: float) -> tuple[list, dict[str, int]]:
    """Every k-th case of each difficulty (k = round(1 / fraction)), and the suite's counts."""
    cases = load_suite(DEFAULT_SUITE)
    step = max(1, round(1 / fraction))
    counts: dict[str, int] = defaultdict(int)
    chosen = []
    for d in difficulty_order([c.difficulty for c in cases]):
        level = [c for c in cases if c.difficulty == d]
        counts[d] = len(level)
        chosen += level[::step]
    return chosen, dict(counts)


def _seconds(value: float | None | UnsetType, default: float = 0.0) -> float:
    """A timing field (absent in some records: then ``default``)."""
    return default if value is UNSET or value is None else float(value)


def _cpu_s(r: EpisodeOk) -> float:
    """The episode's CPU time; records without cpu_s count their wall time."""
    return _seconds(r.timing.cpu_s, _seconds(r.timing.episode_s))


def played(records: list[EpisodeRecord]) -> list[EpisodeOk]:
    """The finished episodes that were played (copies carry their lead's times)."""
    return [r for r in iter_ok(records) if r.reused_from_seed is UNSET]


def timing_tables(
    records: list[EpisodeRecord],
    suite_counts: dict[str, int] | None,
    wall_s: float | None,
    workers: int,
) -> str:
    ok = played(records)
    levels = difficulty_order([r.difficulty for r in ok])
    policies = list(dict.fromkeys(r.policy for r in ok))
    lines = []
    wall_ep, cpu_ep = defaultdict(float), defaultdict(float)
    ran_cases = defaultdict(set)
    for r in ok:
        wall_ep[r.difficulty] += _seconds(r.timing.episode_s)
        cpu_ep[r.difficulty] += _cpu_s(r)
        ran_cases[r.difficulty].add(r.case_id)
    total_wall, total_cpu = sum(wall_ep.values()), sum(cpu_ep.values())
    scale = {d: (suite_counts[d] / len(ran_cases[d]) if suite_counts else 1.0) for d in levels}
    full_cpu = sum(cpu_ep[d] * scale[d] for d in levels)
    if wall_s is not None:
        lines.append(
            f"measured: {len(records)} episodes on {workers} workers in {wall_s:.1f} s wall; "
            f"episode CPU {total_cpu:.1f} s (episode wall {total_wall:.1f} s: the excess is "
            f"waiting for a core on a shared machine)"
        )
        if suite_counts:
            lines.append(
                f"full default run, extrapolated per difficulty: CPU {full_cpu:.0f} s -> "
                f"~{full_cpu / workers:.0f} s ({full_cpu / workers / 60:.1f} min) "
                f"on {workers} idle cores; "
                f"~{wall_s * full_cpu / total_cpu:.0f} s at this run's load"
            )
        else:
            lines.append(
                f"CPU / workers = {full_cpu / workers:.0f} s ({full_cpu / workers / 60:.1f} min): "
                f"the wall time on {workers} idle cores"
            )
    else:
        lines.append(
            f"{len(records)} episodes: episode CPU {total_cpu:.1f} s "
            f"-> ~{total_cpu / workers:.0f} s "
            f"({total_cpu / workers / 60:.1f} min) on {workers} idle cores (records without cpu_s "
            f"count their wall time)"
        )
    lines.append("")
    head = (
        f"{'method':<18}"
        + "".join(f"{d + ' ms/dec':>16}{d + ' ms/step':>17}" for d in levels)
        + f"{'CPU s/ep':>10}{'CPU share':>11}"
    )
    lines += [
        "time per decision (policy.act) and per environment step (place + settle), means (wall):",
        head,
        "-" * len(head),
    ]
    for p in policies:
        row = f"{display_name(p):<18}"
        mine = [r for r in ok if r.policy == p]
        for d in levels:
            rs = [r for r in mine if r.difficulty == d]
            dec = sum(int(_seconds(r.timing.decisions)) for r in rs)
            row += (
                (
                    f"{1000 * sum(_seconds(r.timing.policy_s) for r in rs) / dec:>16.2f}"
                    f"{1000 * sum(_seconds(r.timing.env_s) for r in rs) / dec:>17.2f}"
                )
                if dec
                else f"{'-':>16}{'-':>17}"
            )
        cpu = sum(_cpu_s(r) * scale[r.difficulty] for r in mine)
        mean_weight = sum(scale[r.difficulty] for r in mine) / max(1, len(mine))
        row += f"{cpu / max(1, len(mine)) / mean_weight:>10.3f}"
        row += f"{100 * cpu / full_cpu:>10.1f}%"
        lines.append(row)
    return "\n".join(lines)


def outcome_workers(cfg: RunConfig) -> int:
    return cfg.workers or local_cores()


@dataclass(frozen=True, slots=True)
class Measured:
    """One run of the configuration: its records, wall time and the load around it."""

    records: list[EpisodeRecord]
    wall_s: float
    load_before: float
    load_after: float


def measure(cfg: RunConfig) -> Measured:
    """Run ``cfg`` (into its ``out``) and time it."""
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    outcome = run_bench(cfg, figures=False)
    wall = time.perf_counter() - t0
    records = read_records(outcome.run_dir / "episodes.jsonl")
    return Measured(records, wall, load, os.getloadavg()[0])


def _row_times(records: list[EpisodeRecord], policy: str) -> tuple[int, int, float, float]:
    """(played, copied, summed episode wall s, summed episode CPU s) of one row."""
    mine = [r for r in iter_ok(records) if r.policy == policy]
    ran = [r for r in mine if r.reused_from_seed is UNSET]
    wall = sum(_seconds(r.timing.episode_s) for r in ran)
    return len(ran), len(mine) - len(ran), wall, sum(_cpu_s(r) for r in ran)


def reuse_table(reused: Measured, full: Measured) -> str:
    """Per row and in total: what the run with reuse played and copied and what its played
    episodes cost, beside the run that plays every seed."""
    policies = list(dict.fromkeys(r.policy for r in full.records))
    w = max([len("method"), *(len(display_name(p)) for p in policies)]) + 2
    head = (
        f"{'method':<{w}}{'played':>8}{'copied':>8}{'wall s':>9}{'CPU s':>9}"
        f"{'| all: wall s':>14}{'CPU s':>9}{'CPU saved':>11}"
    )
    lines = ["per row, summed over episodes: with reuse | with --no-reuse", head, "-" * len(head)]
    totals = [0.0, 0.0, 0.0, 0.0]
    for p in policies:
        n, copied, wall, cpu = _row_times(reused.records, p)
        _, _, full_wall, full_cpu = _row_times(full.records, p)
        totals = [a + b for a, b in zip(totals, (wall, cpu, full_wall, full_cpu))]
        lines.append(
            f"{display_name(p):<{w}}{n:>8}{copied:>8}{wall:>9.1f}{cpu:>9.1f}"
            f"{full_wall:>14.1f}{full_cpu:>9.1f}{_saved(cpu, full_cpu):>11}"
        )
    wall, cpu, full_wall, full_cpu = totals
    lines += [
        "-" * len(head),
        (
            f"{'total':<{w + 16}}{wall:>9.1f}{cpu:>9.1f}{full_wall:>14.1f}{full_cpu:>9.1f}"
            f"{_saved(cpu, full_cpu):>11}"
        ),
        "",
        (
            f"run wall time: {reused.wall_s:.1f} s with reuse (load average "
            f"{reused.load_before:.2f} -> {reused.load_after:.2f}), {full.wall_s:.1f} s with "
            f"--no-reuse (load average {full.load_before:.2f} -> {full.load_after:.2f})"
        ),
    ]
    return "\n".join(lines)


def _saved(cpu: float, full_cpu: float) -> str:
    """The share of CPU time reuse saved, as a percentage ("-" without a baseline)."""
    return f"{100 * (1 - cpu / full_cpu):.0f}%" if full_cpu else "-"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--fraction", type=float, default=0.25, help="share of each difficulty's cases to run"
    )
    p.add_argument("--workers", type=int, default=0, help="0 = all local cores")
    p.add_argument("--policies", default="", help="comma-separated rows (default: the bench's)")
    p.add_argument(
        "--honest",
        metavar="PRESET",
        help="run the robot path: perceived + noisy, depth segmentation, this noise preset",
    )
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--backend", default="mujoco", choices=("mujoco", "geometric"))
    p.add_argument(
        "--physics",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="PhysicsConfig override, as packlab bench --physics (repeatable)",
    )
    p.add_argument(
        "--keep", metavar="DIR", help="write the run here instead of a scratch directory"
    )
    p.add_argument(
        "--records", help="print the timing tables of an existing run directory and exit"
    )
    p.add_argument(
        "--reuse",
        choices=("on", "off", "both"),
        default="on",
        help="copy seed-free episodes (the bench's default), play every seed (--no-reuse), or "
        "run both and compare them",
    )
    p.add_argument(
        "--difficulty", default="", help="comma-separated levels to run (default: every level)"
    )
    args = p.parse_args(argv)
    print(
        f"python {platform.python_version()}, {platform.machine()}, {local_cores()} cores, "
        f"load average {os.getloadavg()[0]:.2f}"
    )
    if args.records:
        cfg = json.loads((Path(args.records) / "config.json").read_text())
        print(
            timing_tables(
                read_records(Path(args.records) / "episodes.jsonl"),
                None,
                None,
                cfg["execution"]["workers"],
            )
        )
        return 0
    if not 0 < args.fraction <= 1:
        print("--fraction must be in (0, 1]", file=sys.stderr)
        return 2
    cases, counts = subset(args.fraction)
    if args.difficulty:
        levels = set(args.difficulty.split(","))
        cases = [c for c in cases if c.difficulty in levels]
        counts = {d: n for d, n in counts.items() if d in levels}
    with tempfile.TemporaryDirectory(prefix="packlab-bench-time-") as scratch:
        suite = Path(scratch) / f"{DEFAULT_SUITE}-subset.jsonl"
        save_cases(cases, suite)
        base = args.keep or str(Path(scratch) / "run")
        cfg = RunConfig(
            cases=str(suite),
            out=base,
            backend=args.backend,
            seeds=tuple(int(s) for s in args.seeds.split(",")),
            workers=args.workers,
            physics_overrides=parse_physics(args.physics),
            policies=tuple(p for p in args.policies.split(",") if p),
            reuse=args.reuse != "off",
            progress=False,
            **(
                {"observation": "perceived", "execution": "noisy", "noise": args.honest}
                if args.honest
                else {}
            ),
        )
        if args.reuse == "both":
            reused = measure(dataclasses.replace(cfg, out=f"{base}-reuse"))
            full = measure(dataclasses.replace(cfg, out=f"{base}-no-reuse", reuse=False))
        else:
            full = measure(cfg)
    print(
        f"{len(cases)} of {sum(counts.values())} cases "
        f"({', '.join(f'{d} {n}' for d, n in counts.items())} "
        f"in the suite), seeds {args.seeds}, backend {args.backend}, "
        f"{'honest ' + args.honest if args.honest else 'exact'}, {len(full.records)} episodes; "
        f"load average now {os.getloadavg()[0]:.2f}"
    )
    scale = counts if args.fraction < 1 else None
    print(timing_tables(full.records, scale, full.wall_s, outcome_workers(cfg)))
    if args.reuse == "both":
        print()
        print(reuse_table(reused, full))
    print()
    print(json.dumps({"wall_s": round(full.wall_s, 2), "episodes": len(full.records)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
