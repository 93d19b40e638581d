"""Reference policies on an RL run's held-out cases, and its learning curve with them drawn in.

Usage:
    python benchmarks/rl_heldout_baselines.py RUN [RUN ...] [--policies dblf,sdf,...]

For each run directory of ``packlab train rl`` (its ``config.json`` names the cases and the
held-out count), rebuilds the held-out cases the trainer scored, plays each reference policy on
them exactly as the trainer evaluates (geometric backend, seed 0, mean Overall per level, then
the mean of the levels), prints a table, and redraws ``RUN/curves_with_baselines.png``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from packlab.cli.train_rl import training_cases
from packlab.policies import make_policy
from packlab.rl.split import hold_out
from packlab.sim.episode import run_episode
from packlab.viz.rl_curves import write_rl_curves

DEFAULT = "dblf,sdf,proposer,irbpp-random,tapnet-random"


def held_out_score(name: str, cases) -> dict[str, float]:
    policy = make_policy(name)
    by_level: dict[str, list[float]] = {}
    for case in cases:
        result = run_episode(case, policy, seed=0, backend="geometric")
        by_level.setdefault(case.difficulty, []).append(result.metrics.overall)
    scores = {level: float(np.mean(v)) for level, v in sorted(by_level.items())}
    scores["avg"] = float(np.mean(list(scores.values())))
    return scores


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--policies", default=DEFAULT)
    args = ap.parse_args()
    cache: dict[tuple[str, int], dict[str, dict[str, float]]] = {}
    print("| run | policy | easy | medium | hard | avg |\n|---|---|---:|---:|---:|---:|")
    for run in map(Path, args.runs):
        saved = json.loads((run / "config.json").read_text())
        cfg = saved["config"]
        key = (saved["cases"], cfg["eval_cases_per_level"])
        if key not in cache:
            spec = saved["cases"].removeprefix("recipe:")
            _, held = hold_out(training_cases(spec)[0], cfg["eval_cases_per_level"])
            cache[key] = {p: held_out_score(p, held) for p in args.policies.split(",")}
        for name, s in cache[key].items():
            print(f"| {run.name} | {name} | {s['easy']:.3f} | {s['medium']:.3f} | "
                  f"{s['hard']:.3f} | {s['avg']:.3f} |")  # fmt: skip
        references = {name: s["avg"] for name, s in cache[key].items()}
        write_rl_curves(
            run / "log.csv", run / "curves_with_baselines.png", cfg["agent"], references
        )


if __name__ == "__main__":
    main()
