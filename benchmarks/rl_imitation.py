"""Imitation warm-start of the RL agents from planner-labelled states, measured on held-out
generated cases (never the bench).

Usage:
    python benchmarks/rl_imitation.py --states STATES.jsonl --work DIR [--seeds 0,1]
        [--epochs 30] [--per-level 12] [--case-seed 7411] [--extra NAME=MODEL_DIR ...]

1. Behaviour-clones ``irbpp`` and ``tapnet`` on the states (``packlab train rl-imitate``'s
   code path), one model per training seed, under ``DIR/{agent}-imit-s{seed}``.
2. Plays each policy greedily on ``generate_cases(level, per_level, case_seed, False,
   domain="train")`` for easy, medium and hard, geometric backend, run seed 0; per-case Overall
   is cached in ``DIR/scores.json`` (rerunning skips what is there).
3. Prints a markdown table: mean Overall per level, average, its 95 % stratified bootstrap
   interval, and the paired difference to the proposer (``packlab.bench.intervals``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from packlab.bench.intervals import bootstrap_interval, paired_difference, point_estimate
from packlab.cli.train_rl import demos_from_states
from packlab.datagen import generate_cases
from packlab.policies import make_policy
from packlab.rl.config import ImitationConfig
from packlab.rl.features import FeatureSpec
from packlab.rl.imitation import imitation_samples
from packlab.rl.imitation_fit import imitate
from packlab.sim.episode import run_episode

LEVELS = ("easy", "medium", "hard")
SHIPPED = ("proposer", "irbpp", "tapnet", "plan-fast")


def train_models(states: Path, work: Path, seeds: list[int], epochs: int) -> dict[str, Path]:
    demos = demos_from_states(states)
    out = {}
    for agent in ("irbpp", "tapnet"):
        samples = imitation_samples(demos, FeatureSpec.default(agent))  # type: ignore[arg-type]
        for seed in seeds:
            d = work / f"{agent}-imit-s{seed}"
            if not (d / "model.zip").is_file():
                cfg = ImitationConfig(agent=agent, out=str(d), epochs=epochs, seed=seed)  # type: ignore[arg-type]
                r = imitate(samples, cfg, str(states))
                print(
                    f"{d.name}: {len(samples)} samples, loss {r.losses[0]:.3f} -> "
                    f"{r.losses[-1]:.3f}, first-ranked {r.accuracy:.1%}, {r.wall_time_s:.0f} s"
                )
            out[f"{agent}-imit-s{seed}"] = d
    return out


def policy_of(name: str, models: dict[str, Path]):
    if name in models:
        return make_policy(name.split("-")[0], model=str(models[name]))
    return make_policy(name)


def score_all(names, models, cases, path: Path) -> dict[str, dict[str, dict[str, float]]]:
    scores = json.loads(path.read_text()) if path.is_file() else {}
    for name in names:
        if name in scores and len(scores[name]) == len(cases):
            continue
        started, row = time.perf_counter(), {}
        policy = policy_of(name, models)
        for case in cases:
            row[f"{case.difficulty}/{case.episode_id}"] = run_episode(
                case, policy, seed=0, backend="geometric"
            ).metrics.overall
        scores[name] = row
        path.write_text(json.dumps(scores, indent=1))
        print(f"scored {name} in {time.perf_counter() - started:.0f} s", flush=True)
    return scores


def strata(row: dict[str, float]):
    return [{k: {"0": v} for k, v in row.items() if k.startswith(level + "/")} for level in LEVELS]


def table(scores, names) -> str:
    lines = [
        "| Policy | Easy | Medium | Hard | **Avg** [95 %] | vs proposer [95 %, paired] |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    base = strata(scores["proposer"])
    for name in names:
        st = strata(scores[name])
        levels = [point_estimate([s]) for s in st]
        avg, ci = point_estimate(st), bootstrap_interval(st, over_seeds=False)
        diff = paired_difference(st, base, over_seeds=False)
        d = (
            ""
            if name == "proposer"
            else f"{diff.estimate:+.3f} [{diff.interval.low:+.3f}, {diff.interval.high:+.3f}]"
        )
        cells = " | ".join(f"{v:.3f}" for v in levels)
        lines.append(f"| {name} | {cells} | {avg:.3f} [{ci.low:.3f}, {ci.high:.3f}] | {d} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--states", type=Path, required=True)
    p.add_argument("--work", type=Path, required=True)
    p.add_argument("--seeds", default="0,1")
    p.add_argument("--epochs", type=int, default=30)
    p.add_argument("--per-level", type=int, default=12)
    p.add_argument("--case-seed", type=int, default=7411)
    p.add_argument("--extra", action="append", default=[], help="NAME=MODEL_DIR (irbpp-*/tapnet-*)")
    p.add_argument("--only", default="", help="comma list of policies to score now")
    args = p.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    seeds = [int(s) for s in args.seeds.split(",")]
    models = train_models(args.states, args.work, seeds, args.epochs)
    models |= {k: Path(v) for k, v in (e.split("=", 1) for e in args.extra)}
    cases = [
        c
        for lv in LEVELS
        for c in generate_cases(lv, args.per_level, args.case_seed, False, domain="train")
    ]
    names = list(SHIPPED) + sorted(models)
    todo = args.only.split(",") if args.only else names
    scores = score_all(todo, models, cases, args.work / "scores.json")
    print(table(scores, [n for n in names if n in scores]))


if __name__ == "__main__":
    main()
