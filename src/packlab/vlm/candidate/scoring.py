"""Scoring one observation's listed placements with a pointer model (inference, no grad).
Imports torch: only the vlm extra may import this module."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from packlab.core.types import Observation
from packlab.policies.candidates import Candidate
from packlab.vlm.candidate.compose import Instructions
from packlab.vlm.candidate.pointer import PointerModel, collate, encode
from packlab.vlm.candidate.states import make_state


@dataclass(frozen=True, slots=True)
class PromptSettings:
    """How the model was trained to read a state (from its ``packlab_model.json``)."""

    instructions: Instructions = "short"
    blank_map: bool = False


def score_listed(
    model: PointerModel,
    observation: Observation,
    listed: Sequence[Candidate],
    settings: PromptSettings,
) -> np.ndarray:
    """One score per listed placement (higher is better)."""
    state = make_state("-", "-", observation, listed, "-", -1, "inference")
    enc = encode(model.vlm.tokenizer, state, settings.instructions, settings.blank_map)
    batch = collate([enc], model.vlm.tokenizer.pad_token_id)
    with torch.inference_mode():
        scores = model(batch["ids"], batch["mask"], batch["ends"], batch["valid"])
    return scores[0].float().numpy()


def set_threads(threads: int | None) -> None:
    if threads is not None:
        torch.set_num_threads(threads)
