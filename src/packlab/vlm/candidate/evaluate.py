"""Evaluation while training: held-out answer NLL and exact match beside two baselines, and a
short closed-loop bench on held-out generated cases (geometric backend, seed 0).
Imports torch: only the vlm extra may import this module."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from packlab.core.types import Case
from packlab.sim.episode import run_episode
from packlab.vlm.candidate.pointer import Encoded, PointerModel, collate, to_device
from packlab.vlm.candidate.policy import IN_MEMORY, CandidateVLMPolicy
from packlab.vlm.prompt.render import PROMPT_VERSION

#: Held-out states scored per evaluation (the first ones, in file order: the same every time).
MAX_HELDOUT = 1000
EVAL_BATCH = 32


@dataclass(frozen=True)
class Heldout:
    states: tuple[Encoded, ...]
    marginal: np.ndarray  # label frequency by list position in the training states (smoothed)

    @classmethod
    def of(cls, held: Sequence[Encoded], train: Sequence[Encoded]) -> Heldout:
        k = max(len(e.ends) for e in (*train, *held))  # a held-out list may be the longest
        counts = np.bincount([e.label for e in train], minlength=k).astype(float) + 1.0
        return cls(tuple(held[:MAX_HELDOUT]), counts / counts.sum())


def _baselines(held: Heldout) -> dict[str, float]:
    nll = []
    for e in held.states:
        p = held.marginal[: len(e.ends)]
        nll.append(-np.log(p[e.label] / p.sum()))
    return {
        "marginal_nll": round(float(np.mean(nll)), 4),
        "first_match": round(float(np.mean([e.label == 0 for e in held.states])), 4),
    }


def _pointer_rows(model: PointerModel, b: dict) -> tuple[list[float], list[bool]]:
    scores = model.score(b)
    logp = torch.log_softmax(scores, dim=-1)
    nll = (-logp.gather(1, b["labels"][:, None]).squeeze(1)).tolist()
    return nll, (scores.argmax(-1) == b["labels"]).tolist()


def _json_rows(model: PointerModel, b: dict, states: Sequence[Encoded], fields: dict) -> tuple:
    """Answer NLL per example (summed over its tokens), teacher-forced exact match, and the
    per-field sums added to ``fields``."""
    nll, right = model.answer_nll(b)
    for n, e in enumerate(states):
        start = len(e.ids) - 1  # the logit at position p predicts token p + 1
        for j, name in enumerate(e.answer_fields):
            fields[name].append((n, float(nll[n, start + j])))
    return nll.sum(1).tolist(), right.all(1).tolist()


def heldout_metrics(model: PointerModel, held: Heldout, answer: str = "index") -> dict:
    """Mean answer NLL (nats per answer) and exact match on the held-out states; for free-JSON
    answers also the NLL of each field (object, rotation, x, y and the JSON syntax)."""
    if not held.states:
        return {}
    pad = model.vlm.tokenizer.pad_token_id
    nll, hit, fields = [], [], defaultdict(list)
    with torch.inference_mode():
        for i in range(0, len(held.states), EVAL_BATCH):
            part = held.states[i : i + EVAL_BATCH]
            b = to_device(collate(part, pad), model.device)
            seen: dict = defaultdict(list)
            rows = _json_rows(model, b, part, seen) if answer == "json" else _pointer_rows(model, b)
            nll.extend(rows[0])
            hit.extend(rows[1])
            for name, vals in seen.items():
                fields[name].append(sum(v for _, v in vals) / len(part))
    out = {"heldout_nll": round(float(np.mean(nll)), 4), "heldout_match": round(np.mean(hit), 4)}
    out.update({f"nll_{k}": round(float(np.mean(v)), 4) for k, v in sorted(fields.items())})
    return {**out, **_baselines(held)}


def closed_loop(model: PointerModel, cases: Sequence[Case], card: dict[str, Any]) -> dict:
    """Mean Overall of the model per level and their mean, on ``cases`` (geometric, seed 0)."""
    if not cases:
        return {}
    policy = CandidateVLMPolicy(IN_MEMORY, threads=None)
    policy.use_model(model, {**model.vlm.meta, **card, "prompt_version": PROMPT_VERSION})
    by_level: dict[str, list[float]] = defaultdict(list)
    for case in cases:
        result = run_episode(case, policy, seed=0, backend="geometric")
        by_level[case.difficulty].append(result.metrics.overall)
    row = {f"loop_{d}": round(float(np.mean(v)), 4) for d, v in sorted(by_level.items())}
    row["loop_avg"] = round(float(np.mean(list(row.values()))), 4)
    return row
