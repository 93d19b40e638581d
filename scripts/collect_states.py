"""Planner-labelled states for the students (a DAgger round's data step), from the command line.

Usage:
    python scripts/collect_states.py CASES OUT.jsonl SOURCE
        [--actor irbpp --actor-opts '{"model": DIR}'] [--robot structured-light|stereo]
        [--skip N] [--first N] [--workers 2] [--teacher plan|mc [--mc-base proposer]]

Without ``--actor`` the planner plays its own trajectories (round 0); with one, the named policy
acts and the planner labels every state it reaches (a DAgger round: the states a student's own
mistakes lead to). ``--robot`` plays on the honest robot path (MuJoCo, perceived + noisy under
that preset), so the rows hold what a robot cell is shown. The cases are checked by content
against every bundled suite and the reference's benchmark before anything is played; a rerun
skips the cases already in OUT (resumable).

``--teacher mc`` labels with the Monte-Carlo rollout teacher instead
(:mod:`packlab.vlm.candidate.rollout_teacher`: each listed line played to the episode's end on
the case's true future, a privileged training-time label; exact episodes only). The shipped
pointer LM is not trained on it: on random-box states its students scored lower than the
planner's (docs/history/vlm.md).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from packlab.cases.load import load_cases
from packlab.core.errors import ConfigError
from packlab.datagen.guard import require_training_cases
from packlab.vlm.candidate.collect import RobotPath, collect
from packlab.vlm.candidate.rollout_teacher import (
    DEFAULT_BASE,
    DEFAULT_TEMPERATURE,
    collect_rollout_labels,
)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("cases", help="generated training cases (JSONL)")
    p.add_argument("out", help="labelled states (JSONL), appended to")
    p.add_argument("source", help="the rows' source tag, e.g. r0, r1-irbpp")
    p.add_argument("--actor", help="policy that acts (a student); default: the planner itself")
    p.add_argument("--actor-opts", default="{}", help="the actor's options as JSON")
    p.add_argument("--robot", choices=["structured-light", "stereo"])
    p.add_argument("--skip", type=int, default=0, help="leave out the first N cases")
    p.add_argument("--first", type=int, default=None, help="then play at most N cases")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument(
        "--teacher",
        choices=["plan", "mc"],
        default="plan",
        help="plan: the planner labels (default); mc: each listed line played to the end on the "
        "case's true future (privileged, training-time only; exact geometric episodes)",
    )
    p.add_argument(
        "--mc-base", default=DEFAULT_BASE, help="mc: the policy that plays each line out"
    )
    p.add_argument("--temperature", type=float, default=DEFAULT_TEMPERATURE,
                   help="mc: the soft target's temperature (Overall units)")  # fmt: skip
    a = p.parse_args()
    cases = require_training_cases(load_cases(a.cases), a.cases)[a.skip :]
    cases = cases[: a.first] if a.first is not None else cases
    actor = (a.actor, json.loads(a.actor_opts)) if a.actor else None
    robot = RobotPath(a.robot) if a.robot else None
    start = time.monotonic()
    if a.teacher == "mc":
        if robot is not None:
            raise ConfigError("--teacher mc plays exact geometric episodes: drop --robot")
        n = collect_rollout_labels(cases, Path(a.out), a.source, actor=actor, base=a.mc_base,
                                   temperature=a.temperature, workers=a.workers)  # fmt: skip
    else:
        n = collect(cases, Path(a.out), "plan", a.source, actor=actor, workers=a.workers,
                    robot=robot)  # fmt: skip
    print(f"{n} states appended to {a.out} in {time.monotonic() - start:.0f} s", flush=True)


if __name__ == "__main__":
    try:
        main()
    except ConfigError as exc:  # bad input: one line naming the file and the case, exit 2
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
