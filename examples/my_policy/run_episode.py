"""Play my-policy step by step on packlab's demo cases, before installing it, and compare it
with the DBLF heuristic on the same cases.

    python examples/my_policy/run_episode.py                  # the three demo cases
    python examples/my_policy/run_episode.py --limit 1 --quiet
    python examples/my_policy/run_episode.py --cases-file CASES.jsonl --limit 5 --quiet

The geometric backend (exact drops, no physics) keeps it to a second or two.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from packlab.cases import load_cases
from packlab.core.types import Case
from packlab.metrics import EpisodeMetrics
from packlab.policies import make_policy
from packlab.sim.env import demo_cases_path
from packlab.sim.episode import Episode, policy_start, run_episode

# The package beside this script, importable without `pip install`.
sys.path.insert(0, str(Path(__file__).resolve().parent))
from my_policy import LowestFirstPolicy


def play(policy: LowestFirstPolicy, case: Case, seed: int, quiet: bool) -> EpisodeMetrics:
    """One episode, one decision at a time: observe, act, step (what run_episode does)."""
    episode = Episode(backend="geometric")
    observation = episode.reset(case, seed)
    policy.reset(policy_start(policy, case, seed), seed)  # what a cell knows, not the case
    while not episode.done:
        action = policy.act(observation)
        step = episode.step(action)
        if not quiet:
            where = f"at {step.drop_mm} mm" if step.valid else f"not placed ({step.reason})"
            box = f"box {step.internal_id}, rotation {action.rotation}"
            print(f"  step {step.step_index}: {box}, {where}")
        if not episode.done:
            observation = episode.observe()
    return episode.metrics()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--cases-file", default=demo_cases_path(), help="a case file (default: the demo cases)"
    )
    parser.add_argument("--limit", type=int, default=3, help="play the first N cases (default 3)")
    parser.add_argument("--prefer", default="area", help="tie rule: area or scan (default area)")
    parser.add_argument("--seed", type=int, default=0, help="run seed (default 0)")
    parser.add_argument("--quiet", action="store_true", help="no line per step")
    args = parser.parse_args(argv)

    policy = LowestFirstPolicy(prefer=args.prefer)
    print(f"{'case':<18}{'my-policy':>10}{'dblf':>10}   (Overall = Success Ratio x Compactness)")
    for case in load_cases(args.cases_file)[: args.limit]:
        if not args.quiet:
            print(f"{case.episode_id}: {len(case.objects)} boxes, buffer {case.buffer_size}")
        mine = play(policy, case, args.seed, args.quiet)
        dblf = run_episode(case, make_policy("dblf"), args.seed, backend="geometric").metrics
        print(f"{case.episode_id:<18}{mine.overall:>10.3f}{dblf.overall:>10.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
