"""The ``plan`` policy's budget sweep beside the heuristics and the oracle: Overall per level and
milliseconds per decision on the hard level.

Usage:
    python benchmarks/plan_sweep.py                          # packlab-bench-v1, 3 seeds, mujoco
    python benchmarks/plan_sweep.py --cases DATASET_DIR      # e.g. a fresh `packlab generate` set
    python benchmarks/plan_sweep.py --backend geometric --seeds 0   # a quick look

Each budget is its own bench run under ``--out`` (default runs/plan-sweep-<cases>/<label>), so an
interrupted sweep resumes where it stopped and a finished one only prints its table. The
decision times are wall-clock means of ``policy.act`` over the hard level's decisions, measured
while the run used every local core (one episode per core: one core per decision).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from packlab.bench.compare import load_summary
from packlab.bench.config import RunConfig, parse_seeds
from packlab.bench.records import iter_ok, read_records
from packlab.bench.runner import run_bench
from packlab.bench.table import display_name

#: (label, plan factory keywords): from about heuristic speed to about a second per decision.
BUDGETS: tuple[tuple[str, dict[str, int]], ...] = (
    ("plan-first1-depth2", {"first": 1, "depth": 2}),
    ("plan-first2-depth4", {"first": 2, "depth": 4}),
    ("plan-first3", {"first": 3}),
    ("plan-first6", {"first": 6}),
)
BASELINES = ("sdf", "mta", "dblf", "oracle")


def hard_decision_ms(run_dir: Path, policy: str) -> float | None:
    """Mean ms per decision of ``policy`` over the hard level's finished episodes."""
    records = read_records(run_dir / "episodes.jsonl")
    hard = [r for r in iter_ok(records) if r.policy == policy and r.difficulty == "hard"]
    decisions = sum(int(r.timing.decisions or 0) for r in hard)
    seconds = sum(float(r.timing.policy_s or 0.0) for r in hard)
    return 1000 * seconds / decisions if decisions else None


def run(config: RunConfig) -> Path:
    run_bench(config, figures=False)
    return Path(config.out)


def rows(args: argparse.Namespace, root: Path) -> list[tuple[str, dict[str, float], float | None]]:
    """(label, {level: overall mean}, hard ms per decision) for the baselines, then each budget."""
    common = {
        "cases": args.cases,
        "seeds": parse_seeds(args.seeds),
        "backend": args.backend,
        "workers": args.workers,
        "progress": not args.quiet,
    }
    out = []
    base = run(RunConfig(policies=BASELINES, out=str(root / "baselines"), **common))
    summary = load_summary(base)
    for name in BASELINES:
        out.append((display_name(name), _levels(summary, name), hard_decision_ms(base, name)))
    for label, options in BUDGETS:
        args_ = tuple(("plan", k, v) for k, v in options.items())
        d = run(RunConfig(policies=("plan",), policy_args=args_, out=str(root / label), **common))
        out.append((label, _levels(load_summary(d), "plan"), hard_decision_ms(d, "plan")))
    return out


def _levels(summary, name: str) -> dict[str, float]:
    return {group: cells.overall.mean for group, cells in summary.table[name].items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="packlab-bench-v1")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--backend", default="mujoco", choices=("mujoco", "geometric"))
    parser.add_argument("--workers", type=int, default=0)
    parser.add_argument("--out", default=None)
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args()
    root = Path(args.out or f"runs/plan-sweep-{Path(args.cases).name}-{args.backend}")
    table = rows(args, root)
    levels = [g for g in table[0][1] if g != "average"] + ["average"]
    print(f"\n{args.cases}, {args.backend}, seeds {args.seeds}: Overall (mean over seeds)\n")
    print("| method | " + " | ".join(levels) + " | hard ms / decision |")
    print("| --- |" + " ---: |" * (len(levels) + 1))
    for label, by_level, ms in table:
        cells = " | ".join(f"{by_level.get(g, float('nan')):.3f}" for g in levels)
        print(f"| {label} | {cells} | {'-' if ms is None else f'{ms:.1f}'} |")


if __name__ == "__main__":
    main()
