"""How often the ``plan`` policy's support test changes its choice, and what it does to the score.

Usage:
    python benchmarks/maintainers/plan_stability.py    # packlab-bench-v1, seed 0, mujoco
    python benchmarks/maintainers/plan_stability.py --cases DATASET_DIR --backend geometric

Runs ``plan`` with ``stability=off`` and ``stability=support`` on every case (one process per
core) and prints, per level: Overall for each, the share of decisions where the cheapest
placement's centre was not over its support (the fallback rate) and the mujoco settle's
unsettled steps (boxes still moving when the settle gave up).
"""

from __future__ import annotations

import argparse
import multiprocessing
from dataclasses import dataclass

import numpy as np

from packlab.bench.suites import resolve_cases
from packlab.core.types import Case
from packlab.policies import make_policy
from packlab.sim.episode import run_episode


@dataclass(frozen=True)
class Outcome:
    level: str
    stability: str
    overall: float
    decisions: int
    fallbacks: int
    unsettled: int


def one(job: tuple[Case, str, str, int, dict[str, int]]) -> Outcome:
    case, stability, backend, seed, budget = job
    policy = make_policy("plan", stability=stability, **budget)
    result = run_episode(case, policy, seed=seed, backend=backend)
    return Outcome(
        case.difficulty,
        stability,
        result.metrics.overall,
        policy.decisions,
        policy.fallbacks,
        result.metrics.unsettled_steps,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="packlab-bench-v1")
    parser.add_argument("--backend", default="mujoco", choices=("mujoco", "geometric"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--first", type=int, default=3)
    parser.add_argument("--workers", type=int, default=0, help="0: one per core")
    args = parser.parse_args()
    cases = resolve_cases(args.cases).cases
    budget = {"first": args.first}
    jobs = [(c, s, args.backend, args.seed, budget) for s in ("off", "support") for c in cases]
    workers = args.workers or multiprocessing.cpu_count()
    with multiprocessing.get_context("fork").Pool(workers) as pool:
        outcomes = pool.map(one, jobs, chunksize=1)
    print(f"\n{args.cases}, {args.backend}, seed {args.seed}, plan first={args.first}\n")
    print("| level | Overall off | Overall support | fallback rate | unsettled off / support |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for level in sorted({o.level for o in outcomes}):
        rows = {
            s: [o for o in outcomes if o.level == level and o.stability == s]
            for s in ("off", "support")
        }
        mean = {s: float(np.mean([o.overall for o in r])) for s, r in rows.items()}
        fell = sum(o.fallbacks for o in rows["support"])
        took = sum(o.decisions for o in rows["support"])
        unsettled = {s: sum(o.unsettled for o in r) for s, r in rows.items()}
        print(
            f"| {level} | {mean['off']:.3f} | {mean['support']:.3f} | "
            f"{fell}/{took} ({100 * fell / max(took, 1):.1f}%) | "
            f"{unsettled['off']} / {unsettled['support']} |"
        )


if __name__ == "__main__":
    main()
