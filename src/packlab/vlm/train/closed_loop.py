"""Closed-loop evaluation during SFT: the model being trained plays generated validation cases
through the bench's own episode loop, and its Overall is logged beside the losses.

The validation loss says how well the model imitates the teacher's next answer; only playing
says whether its own answers pack. Cases are generated in the training seed domain with their
own user seed (never bench cases); ``packlab train sft`` makes them
(:func:`packlab.cli.train_run.play_cases`) and passes them in.

Imports torch: only the vlm extra may import this module.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import torch

from packlab.core.types import Case
from packlab.sim.episode import run_episode
from packlab.vlm.infer.policy import VLMPolicy
from packlab.vlm.model.checkpoint import VLM
from packlab.vlm.prompt.render import PromptOptions


@dataclass(frozen=True)
class PlayResult:
    """Mean metrics over the played cases (and per level)."""

    overall: float
    success_ratio: float
    compactness: float
    parsed: float  # share of answers that parsed as an action
    per_level: dict[str, float]
    episodes: int
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "play_overall": round(self.overall, 4),
            "play_success_ratio": round(self.success_ratio, 4),
            "play_compactness": round(self.compactness, 4),
            "play_parsed": round(self.parsed, 4),
            **{f"play_overall_{k}": round(v, 4) for k, v in self.per_level.items()},
            "play_episodes": self.episodes,
            "play_s": round(self.seconds, 1),
        }


def _mean(xs: list[float]) -> float:
    return math.fsum(xs) / len(xs) if xs else float("nan")


def play(
    model: Any,
    vlm: VLM,
    cases: list[Case],
    options: PromptOptions,
    image_size: int,
    backend: str,
    template_kwargs: dict[str, Any],
) -> PlayResult:
    """Play ``cases`` greedily with ``model`` (the trained weights, possibly under LoRA), then
    put it back in training mode."""
    t0 = time.perf_counter()
    was_training = model.training
    model.eval()
    # Under LoRA the adapters sit inside the base model's layers: the base model plays them.
    base = model.get_base_model() if hasattr(model, "get_base_model") else model
    bundle = VLM(base, vlm.tokenizer, vlm.image_processor, vlm.family, vlm.meta)
    policy = VLMPolicy.from_vlm(
        bundle, options, image_size=image_size, template_kwargs=template_kwargs, name="sft-play"
    )
    metrics, parsed = [], []
    levels: dict[str, list[float]] = {}
    try:
        with torch.no_grad():
            for case in cases:
                result = run_episode(case, policy, seed=0, backend=backend)
                metrics.append(result.metrics)
                log = policy.step_log
                parsed.append(sum(s["parsed"] for s in log) / max(1, len(log)))
                levels.setdefault(case.difficulty, []).append(result.metrics.overall)
    finally:
        model.train(was_training)
    return PlayResult(
        overall=_mean([m.overall for m in metrics]),
        success_ratio=_mean([m.success_ratio for m in metrics]),
        compactness=_mean([m.compactness for m in metrics]),
        parsed=_mean(parsed),
        per_level={k: _mean(v) for k, v in levels.items()},
        episodes=len(metrics),
        seconds=time.perf_counter() - t0,
    )
