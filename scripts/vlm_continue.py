"""Continue a candidate-mode model on more labelled states (a DAgger round from states on disk).

Usage:
    python scripts/vlm_continue.py --model runs/student/vlm/r0/train/final \
        --states runs/student/vlm/r0/states.jsonl runs/student/vlm/r1/states.jsonl \
        --cases runs/student/train-cases.jsonl --states-cases runs/student/r1-cases.jsonl \
        --out runs/student/vlm/r1/train \
        --steps 700 --lr 5e-4 --minutes 18

``packlab train candidate`` collects each DAgger round with the model itself acting. This script
trains on states collected otherwise (e.g. the states the line-vector MLP student of
``benchmarks/maintainers/student_probe.py dagger`` reached, or ``scripts/collect_states.py``'s,
labelled by the planner), warm-starting from a pointer directory with its own settings (map,
line vectors, K); ``--model tiny:qwen3_vl:mini --map text`` starts from random weights instead,
with the line vectors, K = 16 and a shuffled listing, as ``train candidate`` does. The
closed-loop evaluation uses the last five cases per level of ``--cases`` (as the recipe does).
Resumable like any training.
"""

from __future__ import annotations

import argparse
from typing import Any

from packlab.cases import cases_sha256, load_cases
from packlab.core.choices import AutocastDType, PointerMap, choices
from packlab.datagen.guard import require_training_cases
from packlab.policies.candidates import STUDENT_K
from packlab.policies.provenance import cases_record
from packlab.vlm.candidate.dagger_split import split_cases
from packlab.vlm.candidate.saved import load_pointer
from packlab.vlm.candidate.states_guard import require_training_states
from packlab.vlm.candidate.train import PointerTrainConfig, train_pointer


def _start_settings(model: str, map_: str) -> dict[str, Any]:
    """The settings a model is trained with: a pointer directory's own, or the student
    defaults (K = 16, line vectors, shuffled listing) for a model from random weights."""
    if model.startswith("tiny:"):
        return {"map": map_, "line_vectors": True, "proposer": {"k": STUDENT_K}, "shuffle": True,
                "teacher": "plan"}  # fmt: skip
    return load_pointer(model).vlm.meta


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", required=True)
    p.add_argument("--states", nargs="+", required=True)
    p.add_argument("--cases", required=True)
    p.add_argument(
        "--states-cases",
        nargs="*",
        default=[],
        help="more case files the states were collected on (e.g. a DAgger round's own cases); "
        "every state row must be of a case of --cases or of these, by id and content",
    )
    p.add_argument("--out", required=True)
    p.add_argument("--steps", type=int, default=700)
    p.add_argument("--lr", type=float, default=5e-4)
    p.add_argument("--minutes", type=float, default=None)
    p.add_argument(
        "--stop-after",
        type=int,
        default=None,
        help="stop after this many updates; --steps alone sets the schedule, so a run stopped "
        "here is the same model a longer run had at that update",
    )
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--note", default="", help="recorded in the model card")
    p.add_argument(
        "--map",
        choices=choices(PointerMap),
        default="image",
        help="how a model from random weights (--model tiny:...) sees the heightmap",
    )
    p.add_argument("--threads", type=int, default=1)
    p.add_argument(
        "--device",
        default="cpu",
        help="where the updates and evaluations run: auto, cpu, cuda or cuda:<index>",
    )
    p.add_argument(
        "--dtype",
        choices=choices(AutocastDType),
        default="fp32",
        help="bf16: forward passes under bf16 autocast on a GPU (weights stay fp32)",
    )
    p.add_argument("--batch", type=int, default=16, help="states per update")
    p.add_argument("--eval-every", type=int, default=350, help="updates between evaluations")
    a = p.parse_args()
    cases = require_training_cases(load_cases(a.cases), a.cases)
    # The states are checked too, row by row, by their cases' content: not a suite's, and each
    # the case of --cases with its id (states of other cases under the same ids are refused).
    by_file = {f: require_training_cases(load_cases(f), f) for f in a.states_cases}
    more = [c for cs in by_file.values() for c in cs]
    require_training_states(a.states, cases + more)
    _, evals = split_cases(cases, 3, 0, 5)
    meta = _start_settings(a.model, a.map)
    cfg = PointerTrainConfig(
        states=tuple(a.states), out=a.out, model=a.model, map=meta["map"],
        line_vectors=bool(meta.get("line_vectors", False)), k=meta["proposer"]["k"],
        shuffle=bool(meta.get("shuffle", False)), steps=a.steps, lr=a.lr,
        warmup=100 if a.model.startswith("tiny:") else 20,
        seed=a.seed, threads=a.threads, minutes=a.minutes, eval_every=a.eval_every,
        stop_after=a.stop_after,
        device=a.device, dtype=a.dtype, batch=a.batch,
        # The card records the model continued from as "init" (name + sha256) and the cases
        # by name and content digest: no scratch path (packlab.policies.provenance).
        meta={"teacher": meta.get("teacher", ""), "note": a.note,
              "cases": cases_record(a.cases, cases_sha256(cases), a.out),
              # The cases the other states were collected on, so the card names every input.
              "states_cases": [cases_record(f, cases_sha256(cs), a.out)
                               for f, cs in by_file.items()]},
    )  # fmt: skip
    print(train_pointer(cfg, evals))


if __name__ == "__main__":
    main()
