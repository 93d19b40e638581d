"""The candidate proposer's own ceiling: how much of each teacher survives its K listed placements.

Usage:
    python benchmarks/proposer_ceiling.py                      # generated cases, geometric, seed 0
    python benchmarks/proposer_ceiling.py --k 8 --rules lowest --teachers sdf   # a quick look
    python benchmarks/proposer_ceiling.py --cases runs/data/packdata-mini      # generated on disk

The proposer's defaults (K and rule) are chosen from this table, so it never reads the bench:
its cases are generated here in the ``train`` seed domain (``packlab.datagen.seeds``), user seed
``--seed`` (default 2611), ``--per-level`` cases per level (default 12), or read from
``--cases`` (a ``packlab generate`` directory or a case file); either way they pass
``packlab.datagen.guard.require_training_cases``, which refuses bench cases by their seeds.

For each teacher (registered policies ``sdf``, ``mta``, ``plan``) and each proposer setting
(``--rules`` x ``--k``, see ``packlab.policies.candidates``) it reports, per level:

- **match**: on the teacher's own closed-loop trajectories, the share of steps whose chosen
  action is one of the listed placements exactly (same shown object, rotation, x, y);
- **restricted**: the closed-loop Overall of the teacher restricted to the listed set. At each
  step the teacher ranks only the listed placements by its own score and takes the best: SDF-Pack
  and MTA by their keys and the shared tie-break (rim rule first, as always: every listed
  placement is already in the rim pool), the planner by its own pick where that is listed and
  otherwise by rolling out each listed placement as a first placement (its search with the
  proposer's set instead of its own proposals). This is the
  best a policy that picks among the listed placements could do when it imitates that teacher
  perfectly.

It also reports ``first``: the closed-loop Overall of always taking index 0, the proposer's own
choice (what a model that learned nothing but the listing order would score). Overall is the
mean over the level's cases, and the last column the mean of the three levels, as in the bench.

Episodes run on ``--workers`` processes (default 2); every episode is independent. The measured
table is in docs/candidates.md.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from packlab.bench.suites import resolve_cases
from packlab.core.feasibility import observation_candidates
from packlab.core.types import Action, Case, Observation
from packlab.datagen import generate_cases
from packlab.datagen.guard import require_training_cases
from packlab.policies.candidates import ProposerConfig, propose_from
from packlab.policies.listed import ListedTeacher, best_by_plan
from packlab.policies.registry import make_policy
from packlab.sim.episode import run_episode

LEVELS = ("easy", "medium", "hard")
#: Default user seed of the generated cases (train seed domain).
SEED = 2611


@dataclass
class Restricted:
    """A teacher that may only take one of the proposer's listed placements (or index 0)."""

    teacher: str  # sdf | mta | plan | first (always index 0)
    config: ProposerConfig
    name: str = "restricted"

    def reset(self, case: Case, seed: int) -> None:
        self._fallback = make_policy("sdf")  # nothing listed: nothing fits, any action will do
        self._teacher = ListedTeacher(self.teacher)
        self._teacher.reset(case, seed)

    def act(self, observation: Observation) -> Action:
        cands = observation_candidates(observation)
        proposed = propose_from(cands, self.config)
        if not proposed:
            return self._fallback.act(observation)
        pick = self._teacher.choose(observation, cands, proposed)
        if not 0 <= pick < len(proposed):
            # The teacher's own action is not listed (``plan`` then returns the index of its
            # pick appended to the list, the oracle -1): the planner rolls out the listed
            # placements instead, any other teacher takes index 0.
            pick = best_by_plan(observation, cands, proposed) if self.teacher == "plan" else 0
        return proposed[pick].action


@dataclass
class Probe:
    """The teacher itself, counting how often its action is among each setting's listed set."""

    teacher: str
    configs: tuple[ProposerConfig, ...]
    name: str = "probe"

    def reset(self, case: Case, seed: int) -> None:
        self._policy = make_policy(self.teacher)
        self._policy.reset(case, seed)
        self.hits = [0] * len(self.configs)
        self.steps = 0

    def act(self, observation: Observation) -> Action:
        action = self._policy.act(observation)
        cands = observation_candidates(observation)
        self.steps += 1
        for n, config in enumerate(self.configs):
            self.hits[n] += action in [c.action for c in propose_from(cands, config)]
        return action


def run_item(item: tuple[str, str, tuple[ProposerConfig, ...], Case]) -> dict[str, Any]:
    """One episode: ``("probe", teacher, configs, case)`` or ``("restricted", teacher, (config,),
    case)``; geometric backend, seed 0."""
    kind, teacher, configs, case = item
    policy = Probe(teacher, configs) if kind == "probe" else Restricted(teacher, configs[0])
    start = time.perf_counter()
    result = run_episode(case, policy, seed=0, backend="geometric")
    out = {
        "kind": kind,
        "teacher": teacher,
        "level": case.difficulty,
        "case": case.episode_id,
        "overall": result.metrics.overall,
        "seconds": time.perf_counter() - start,
    }
    if kind == "probe":
        out["hits"] = list(policy.hits)
        out["steps"] = policy.steps
    else:
        out["config"] = [configs[0].rule, configs[0].k]
    return out


def items(
    cases: tuple[Case, ...],
    teachers: list[str],
    restricted: list[str],
    configs: tuple[ProposerConfig, ...],
) -> list[tuple[str, str, tuple[ProposerConfig, ...], Case]]:
    """Every episode to run, the slow planner ones first for a balanced end."""
    out = [("probe", t, configs, c) for t in teachers for c in cases]
    for config in configs:
        out += [("restricted", t, (config,), c) for t in [*restricted, "first"] for c in cases]
    return sorted(out, key=lambda it: (it[1] != "plan", it[3].difficulty != "hard"))


def _cells(values: dict[str, list[float]], fmt: str) -> str:
    """Per-level means and their mean; blank cells where nothing ran."""
    if not any(values.get(level) for level in LEVELS):
        return " | ".join(" " for _ in range(len(LEVELS) + 1))
    means = [float(np.mean(values[level])) for level in LEVELS]
    return " | ".join(fmt.format(m) for m in [*means, float(np.mean(means))])


def table(results: list[dict[str, Any]], configs: tuple[ProposerConfig, ...]) -> str:
    """Markdown rows: teacher alone, then each setting's match and restricted Overall."""
    head = "| teacher | proposer | match easy | medium | hard | all | Overall easy | medium | "
    lines = [head + "hard | avg |", "|---" * 10 + "|"]
    teachers = sorted({r["teacher"] for r in results if r["kind"] == "probe"})
    for t in [*teachers, "first"]:
        probes = [r for r in results if r["kind"] == "probe" and r["teacher"] == t]
        if probes:
            alone: dict[str, list[float]] = defaultdict(list)
            for r in probes:
                alone[r["level"]].append(r["overall"])
            lines.append(f"| {t} | (all placements) | | | | | {_cells(alone, '{:.3f}')} |")
        for n, config in enumerate(configs):
            match: dict[str, list[float]] = defaultdict(list)
            for r in probes:
                match[r["level"]].append(r["hits"][n] / max(r["steps"], 1))
            overall: dict[str, list[float]] = defaultdict(list)
            for r in results:
                same = r["kind"] == "restricted" and r["config"] == [config.rule, config.k]
                if same and r["teacher"] == t:
                    overall[r["level"]].append(r["overall"])
            m = _cells(match, "{:.1%}")
            lines.append(
                f"| {t} | {config.rule} K={config.k} | {m} | {_cells(overall, '{:.3f}')} |"
            )
    return "\n".join(lines)


#: Restricted-plan averages within this of the best count as tied (the table's rounding).
TIE = 0.005


def choose(results: list[dict[str, Any]], configs: tuple[ProposerConfig, ...]) -> ProposerConfig:
    """The decision rule of docs/candidates.md: the best restricted-plan Overall (mean of the
    level means), ties within ``TIE`` to the smaller K, then to ``"lowest"``."""
    scores = {}
    for config in configs:
        by: dict[str, list[float]] = defaultdict(list)
        key = ["restricted", "plan", [config.rule, config.k]]
        for r in results:
            if [r["kind"], r["teacher"], r.get("config")] == key:
                by[r["level"]].append(r["overall"])
        if by:
            scores[config] = float(np.mean([np.mean(v) for v in by.values()]))
    if not scores:
        raise ValueError("no restricted-plan results: run with plan among --restricted")
    best = max(scores.values())
    tied = [c for c, v in scores.items() if v >= best - TIE]
    return min(tied, key=lambda c: (c.k, c.rule != "lowest"))


def tuning_cases(spec: str | None, seed: int, per_level: int) -> tuple[tuple[Case, ...], str]:
    """The cases to tune on and how to name them: generated now (train seed domain) unless
    ``spec`` names generated cases on disk; bench cases are refused by their seeds."""
    if spec is None:
        label = f"generated train-domain cases, seed {seed}, {per_level} per level"
        cases = [
            c
            for level in LEVELS
            for c in generate_cases(level, per_level, seed, False, domain="train")
        ]
    else:
        label, cases = spec, list(resolve_cases(spec).cases)
    return tuple(require_training_cases(cases, label, "tuning")), label


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=None, help="generated cases on disk (default: none)")
    parser.add_argument("--seed", type=int, default=SEED, help="user seed (train domain)")
    parser.add_argument("--per-level", type=int, default=12, help="generated cases per level")
    parser.add_argument("--teachers", default="sdf,mta,plan")
    parser.add_argument("--rules", default="lowest,lowest+largest")
    parser.add_argument("--k", default="8,16", help="comma-separated list sizes")
    parser.add_argument(
        "--restricted",
        default=None,
        help="teachers to run restricted to the listed set (default: all of --teachers; the "
        "planner restricted to K placements costs about K / 6 times the planner)",
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", default=None, help="also write the per-episode results here")
    args = parser.parse_args()
    configs = tuple(
        ProposerConfig(int(k), rule) for rule in args.rules.split(",") for k in args.k.split(",")
    )
    cases, label = tuning_cases(args.cases, args.seed, args.per_level)
    teachers = args.teachers.split(",")
    restricted = teachers if args.restricted is None else args.restricted.split(",")
    todo = items(cases, teachers, [t for t in restricted if t], configs)
    start = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        results = list(pool.map(run_item, todo))
    print(
        f"{len(results)} episodes in {time.perf_counter() - start:.0f} s ({label}, "
        "geometric backend, seed 0)"
    )
    print(table(results, configs))
    if "plan" in restricted:
        chosen = choose(results, configs)
        print(f"chosen by the rule (best restricted plan, ties to smaller K): {chosen}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(results, f)


if __name__ == "__main__":
    main()
