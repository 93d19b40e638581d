r"""How the ``plan`` policy's defaults were chosen: variants on generated training cases only.

Usage:
    python benchmarks/plan_sweep.py          # every variant; results in runs/plan-sweep
    python benchmarks/plan_sweep.py --variants default,no-completion,jokers-1
    python benchmarks/plan_sweep.py --list   # the variants, families and their options
    python benchmarks/plan_sweep.py --families random,cut-support,cut-base-height \
        --variants mixed-evidence-0.5,plan,plan-mixed-evidence-0.5 --out runs/plan-sweep-cut

The cases are generated here, in the ``train`` seed domain (``packlab.datagen.seeds``) with the
fixed seeds below, never read from a bench suite: 40 cases per level of the layered family in
each arrival order (``removal``, ``layers``) and 20 per level of the ``stepped`` and ``random``
families (``--families`` picks among these and the two cut families, 20 per level in support
and in base-height order); they pass ``packlab.datagen.guard.require_training_cases`` (bench
seeds refused).
Every variant plays every case once on the geometric backend (run seed 0). Results
are appended per variant to ``OUT/results.jsonl`` as they finish, so an interrupted sweep
resumes; the table gives each family's mean Overall and the paired difference to ``default``
over all cases with its 95 % bootstrap interval (a variant differs only when the interval
excludes zero), and the mean ms per decision on the hard level.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from packlab.core.types import Case
from packlab.datagen import generate_cases
from packlab.datagen.config import NO_LAYOUT_FAMILIES, CaseConfig
from packlab.datagen.guard import require_training_cases
from packlab.policies import make_policy
from packlab.sim.episode import run_episode

#: (family label, case config, user seed in the train domain, cases per level)
FAMILIES = (
    ("removal", CaseConfig(), 7302, 40),
    ("layers", CaseConfig(order="layers"), 7302, 40),
    ("stepped", CaseConfig(layout="stepped"), 7303, 20),
    ("random", CaseConfig(layout="random"), 7303, 20),
    ("cut-support", CaseConfig(layout="cut", order="support"), 7304, 20),
    ("cut-base-height", CaseConfig(layout="cut", order="base-height"), 7304, 20),
)
#: The families a sweep plays unless ``--families`` says otherwise (the defaults' tables in
#: docs/planner.md were made on these four).
DEFAULT_FAMILIES = ("removal", "layers", "stepped", "random")
LEVELS = ("easy", "medium", "hard")

#: label -> (policy, factory options). ``default`` is ``plan-fast`` as shipped.
VARIANTS: dict[str, tuple[str, dict]] = {
    "default": ("plan-fast", {}),
    "no-completion": ("plan-fast", {"complete": False}),
    "exact-only": ("plan-fast", {"jokers": 0}),
    "jokers-1": ("plan-fast", {"jokers": 1}),
    "jokers-2": ("plan-fast", {"jokers": 2}),
    "joker-seen-2": ("plan-fast", {"joker_seen": 2}),
    "joker-seen-4": ("plan-fast", {"joker_seen": 4}),
    "guesses-1": ("plan-fast", {"guesses": 1}),
    "guesses-128": ("plan-fast", {"guesses": 128}),
    "nodes-20k": ("plan-fast", {"nodes": 20_000}),
    "nodes-300k": ("plan-fast", {"nodes": 300_000}),
    "overflow-place": ("plan-fast", {"overflow": "place"}),  # the rim rule, no overflow rule
    "listed-4": ("plan-fast", {"listed": 4}),  # plan-fast with the students' listed placements
    "final-0": ("plan-fast", {"w_final": 0.0}),  # without the final-height shortfall
    "plan": ("plan", {}),
    "plan-final-0": ("plan", {"w_final": 0.0}),
    "plan-listed-0": ("plan", {"listed": 0}),  # plan without the students' listed placements
    # Rollout base policies: the proposer's first pick, or the cheapest of several.
    "plan-rollout-lowest": ("plan", {"rollout": "lowest"}),
    "plan-rollout-sdf+lowest": ("plan", {"rollout": "sdf+lowest"}),
    "plan-rollout-sdf+lowest+flush": ("plan", {"rollout": "sdf+lowest+flush"}),
    # The mixed-height stage's guesses (docs/planner.md).
    "mixed-jokers-0": ("plan-fast", {"mixed_jokers": 0}),
    "mixed-evidence-0.5": ("plan-fast", {"mixed_evidence": 0.5}),
    "plan-mixed-jokers-0": ("plan", {"mixed_jokers": 0}),
    "plan-mixed-evidence-0.5": ("plan", {"mixed_evidence": 0.5}),
    "depth-10": ("plan-fast", {"depth": 10}),  # plan-fast at plan's depth
    # The last boxes played out by the planner itself (docs/planner.md).
    "plan-endplay-0": ("plan", {"endplay": 0}),
    "endplay-3": ("plan-fast", {"endplay": 3}),
    "sdf": ("sdf", {}),
    "proposer": ("proposer", {}),
}


def training_cases(families: tuple[str, ...] = DEFAULT_FAMILIES) -> list[tuple[str, Case]]:
    """(family, case) for every generated training case of ``families`` (module docstring)."""
    out = []
    for family, config, seed, n in FAMILIES:
        if family not in families:
            continue
        for level in LEVELS:
            cases = generate_cases(level, n, seed, validate=False, config=config, domain="train")
            label = f"plan sweep family {family} (seed {seed})"
            out += [(family, c) for c in require_training_cases(cases, label, "tuning")]
    return out


def _play(job: tuple[str, Case, str, dict]) -> dict:
    family, case, policy, options = job
    agent = make_policy(policy, **options)
    start = time.perf_counter()
    result = run_episode(case, agent, seed=0, backend="geometric")
    return {
        "key": f"{family}:{case.episode_id}",
        "family": family,
        "level": case.difficulty,
        "overall": result.metrics.overall,
        "ms": 1000 * (time.perf_counter() - start) / max(len(case.objects), 1),
    }


def run_variant(label: str, cases: list[tuple[str, Case]], workers: int) -> list[dict]:
    policy, options = VARIANTS[label]
    jobs = [(family, case, policy, options) for family, case in cases]
    with ProcessPoolExecutor(workers) as pool:
        return list(pool.map(_play, jobs, chunksize=4))


def _interval(d: np.ndarray, rng: np.random.Generator) -> tuple[float, float]:
    means = d[rng.integers(0, d.size, (2000, d.size))].mean(axis=1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def table(
    results: dict[str, list[dict]], families: tuple[str, ...], reference: str = "default"
) -> str:
    rng = np.random.default_rng(0)
    head = f"| variant | {' | '.join(families)} | all - {reference} [95 % CI] | hard ms |"
    lines = [head, "| --- |" + " ---: |" * (len(families) + 2)]
    base = {r["key"]: r["overall"] for r in results.get(reference, [])}
    for label, rows in results.items():
        means = [np.mean([r["overall"] for r in rows if r["family"] == f]) for f in families]
        d = np.array([r["overall"] - base[r["key"]] for r in rows if r["key"] in base])
        lo, hi = _interval(d, rng) if d.size else (float("nan"),) * 2
        diff = "-" if label == reference else f"{d.mean():+.4f} [{lo:+.4f}, {hi:+.4f}]"
        hard = np.mean([r["ms"] for r in rows if r["level"] == "hard"])
        cells = " | ".join(f"{m:.3f}" for m in means)
        lines.append(f"| {label} | {cells} | {diff} | {hard:.0f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="runs/plan-sweep")
    p.add_argument("--variants", default=",".join(VARIANTS))
    p.add_argument("--families", default=",".join(DEFAULT_FAMILIES))
    p.add_argument(
        "--reference", default="default", help="the variant the others are paired against"
    )
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--list", action="store_true")
    args = p.parse_args(argv)
    if args.list:
        for label, (policy, options) in VARIANTS.items():
            print(f"{label}: {policy} {options}")
        for family, config, seed, n in FAMILIES:
            order = "draw" if config.layout in NO_LAYOUT_FAMILIES else config.order
            print(f"family {family}: {config.layout}, {order} order, seed {seed}, {n}/level")
        return 0
    families = tuple(f for f in args.families.split(",") if f)
    unknown_families = sorted(set(families) - {f for f, *_ in FAMILIES})
    if unknown_families or not families:
        p.error(f"--families: unknown {unknown_families}; see --list")
    labels = [v for v in args.variants.split(",") if v]
    unknown = sorted(set(labels) - set(VARIANTS))
    if unknown:
        p.error(f"--variants: unknown {unknown}; see --list")
    if "default" not in labels:
        labels.insert(0, "default")
    if args.reference not in labels:
        p.error(f"--reference {args.reference!r}: not among --variants")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "results.jsonl"
    done: dict[str, list[dict]] = {}
    if path.is_file():
        for line in path.read_text(encoding="utf-8").splitlines():
            entry = json.loads(line)
            # A variant played on other families is played again (results of one sweep only).
            if tuple(entry.get("families", DEFAULT_FAMILIES)) == families:
                done[entry["variant"]] = entry["rows"]
    cases = training_cases(families)
    for label in labels:
        if label in done:
            continue
        print(f"{label} ...", flush=True)
        done[label] = run_variant(label, cases, args.workers)
        with open(path, "a", encoding="utf-8") as fh:  # one line per finished variant
            entry = {"variant": label, "families": list(families), "rows": done[label]}
            fh.write(json.dumps(entry) + "\n")
    print(table({label: done[label] for label in labels}, families, args.reference))
    return 0


if __name__ == "__main__":
    sys.exit(main())
