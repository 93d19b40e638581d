r"""Candidate-mode ablations, each trained with the same budget: what the model reads and learns.

Usage:
    python benchmarks/vlm_ablations.py --states RUN/r0/states.jsonl --cases TRAIN_CASES \
        --out runs/vlm-ablations [--steps 500] [--variants plan,blank,sdf,oracle-canonical,first]

Every variant trains a fresh pointer model (tiny:qwen3_vl:mini, same seed, batch, steps) on the
same states (round 0's: the planner's own trajectories); only one thing changes per variant:

- ``plan``: the planner's labels, the map shown (the reference);
- ``blank``: the planner's labels, the map shows an empty container (boxes and listed
  placements with their geometry still shown);
- ``shuffle``, ``shuffle-blank``: the planner's labels with the listed placements in a random
  order per state (so position says nothing; only a line's content does), map shown / blank;
- ``json``: the planner's labels, the map shown, but the answer is the chosen placement as free
  JSON (rotation first) generated token by token with the language model's own head, instead of
  the pointer over the listed lines (the answer-format ablation; its policy may answer an
  unparsable or invalid action);
- ``sdf``, ``mta``, ``oracle``, ``oracle-canonical``: the same states labelled by another
  teacher (:mod:`packlab.vlm.candidate.relabel`; states the raw oracle's action is not listed
  in are dropped, as in training).

Each model then plays held-out generated cases (``--backend``, default geometric; seed 0) and
the table gives held-out match/NLL (from the last training log line) and Overall per level. The
variants are choices (what to train on, what to show), so they are never scored on the bench:
the scoring cases are generated here in the ``train`` seed domain (user seed ``--eval-seed``,
default 2612, ``--eval-cases`` per level, default 20), minus any case whose seed is among the
``--cases`` the states came from; ``--cases`` and the scoring cases both pass
``packlab.datagen.guard.require_training_cases`` (bench cases are refused by their seeds).
Results are appended to OUT/results.jsonl as each variant finishes; a rerun skips finished
variants (a rerun with other scoring cases needs a new OUT).
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from packlab.bench.suites import resolve_cases
from packlab.core.types import Case
from packlab.datagen import generate_cases
from packlab.datagen.guard import require_training_cases
from packlab.policies.registry import make_policy
from packlab.sim.episode import run_episode
from packlab.vlm.candidate.relabel import relabel
from packlab.vlm.candidate.states import STATES_FILE, append_states
from packlab.vlm.candidate.states_guard import checked_states
from packlab.vlm.candidate.train import LOG, PointerTrainConfig, train_pointer

TEACHER_OF = {"plan": "plan", "blank": "plan", "json": "plan", "shuffle": "plan",
              "shuffle-blank": "plan"}  # fmt: skip
LEVELS = ("easy", "medium", "hard")


def training_cases(spec: str) -> list[Case]:
    """The cases the states were collected on (``--cases``); bench cases are refused."""
    source = resolve_cases(spec)
    return require_training_cases(source.cases, source.origin, "training")


def heldout_cases(train: list[Case], seed: int, per_level: int) -> list[Case]:
    """Generated scoring cases (train seed domain), none of them a training case."""
    seen = {c.seed for c in train}
    cases = [
        c
        for level in LEVELS
        for c in generate_cases(level, per_level, seed, False, domain="train")
        if c.seed not in seen
    ]
    label = f"held-out generated cases (seed {seed}, {per_level} per level)"
    return require_training_cases(cases, label, "tuning")


def _states_for(variant: str, args: argparse.Namespace, out: Path) -> Path:
    teacher = TEACHER_OF.get(variant, variant)
    if teacher == "plan":
        return Path(args.states)
    path = out / STATES_FILE
    if not path.is_file():
        given = training_cases(args.cases)
        cases = {c.episode_id: c for c in given}
        # Each row must be the given case with its id, by content (states_guard).
        append_states(path, relabel(checked_states(Path(args.states), given), teacher, cases))
    return path


def _score(model: Path, cases: list[Case], backend: str) -> dict[str, float]:
    policy = make_policy("vlm", model=str(model), threads=1)
    by: dict[str, list[float]] = defaultdict(list)
    for case in cases:
        by[case.difficulty].append(run_episode(case, policy, 0, backend).metrics.overall)
    row = {d: round(float(np.mean(v)), 3) for d, v in by.items()}
    row["average"] = round(float(np.mean(list(row.values()))), 3)
    return row


def run_variant(variant: str, args: argparse.Namespace, scoring: list[Case]) -> dict:
    out = Path(args.out) / variant
    out.mkdir(parents=True, exist_ok=True)
    cfg = PointerTrainConfig(
        states=(str(_states_for(variant, args, out)),),
        out=str(out / "train"),
        blank_map=variant in ("blank", "shuffle-blank"),
        shuffle=variant.startswith("shuffle"),
        answer="json" if variant == "json" else "index",
        steps=args.steps,
        eval_every=args.steps,
        threads=args.threads,
        meta={"teacher": TEACHER_OF.get(variant, variant), "ablation": variant},
    )
    t0 = time.perf_counter()
    final = train_pointer(cfg)
    trained = time.perf_counter() - t0
    with open(out / "train" / LOG) as f:
        last = list(csv.DictReader(f))[-1]
    row = {"variant": variant, "train_s": round(trained), **last}
    row["heldout"] = _score(final, scoring, args.backend)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--states", required=True)
    ap.add_argument("--cases", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--backend", default="geometric")
    ap.add_argument("--variants", default="plan,blank,sdf,oracle-canonical")
    ap.add_argument("--eval-seed", type=int, default=2612, help="user seed of the scoring cases")
    ap.add_argument("--eval-cases", type=int, default=20, help="scoring cases per level")
    args = ap.parse_args()
    scoring = heldout_cases(training_cases(args.cases), args.eval_seed, args.eval_cases)
    results = Path(args.out) / "results.jsonl"
    Path(args.out).mkdir(parents=True, exist_ok=True)
    done = (
        {json.loads(x)["variant"] for x in results.read_text().splitlines()}
        if results.is_file()
        else set()
    )
    for variant in args.variants.split(","):
        if variant not in done:
            row = run_variant(variant, args, scoring)
            with open(results, "a") as f:
                f.write(json.dumps(row) + "\n")
    rows = [json.loads(x) for x in results.read_text().splitlines()]
    print("| variant | held-out match | held-out NLL | marginal NLL | easy | medium | hard | avg |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        if "heldout" not in r:  # a row of the old script, scored on the bench: not a result
            print(f"| {r['variant']} | scored on the bench (superseded): rerun in a new --out |")
            continue
        b = r["heldout"]
        print(
            f"| {r['variant']} | {r.get('heldout_match', '-')} | {r.get('heldout_nll', '-')} "
            f"| {r.get('marginal_nll', '-')} "
            f"| {b['easy']} | {b['medium']} | {b['hard']} | {b['average']} |"
        )


if __name__ == "__main__":
    main()
