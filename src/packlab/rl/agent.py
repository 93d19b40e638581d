"""A trained agent on disk and its decisions under torch (rl extra).

A model directory holds ``model.zip`` (sb3-contrib's MaskablePPO save: network weights and
optimiser state), ``card.json`` (:class:`~packlab.rl.card.AgentCard`: the action space, how and
on what it was trained, its held-out scores) and, once exported, ``policy.onnx`` + ``onnx.json``
(:mod:`packlab.rl.onnx_export`; the bench plays those without torch). :func:`load_agent` reads
the card and the weights; :func:`row_logits` is the torch runtime's network call, and the
decision itself is :func:`packlab.rl.decision.decide`, shared with the ONNX runtime.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from sb3_contrib import MaskablePPO

from packlab.core.errors import ConfigError
from packlab.core.types import Action, Observation
from packlab.rl.card import CARD_FILE, CARD_FORMAT, MODEL_FILE, AgentCard, read_card, write_card
from packlab.rl.decision import decide, pick_row
from packlab.rl.features import Encoded, FeatureSpec, encode
from packlab.rl.networks import ActorLogits

__all__ = [
    "CARD_FILE",
    "CARD_FORMAT",
    "MODEL_FILE",
    "AgentCard",
    "LoadedAgent",
    "choose_row",
    "greedy_action",
    "load_agent",
    "read_card",
    "row_logits",
    "set_threads",
    "write_card",
]


@dataclass(frozen=True, slots=True)
class LoadedAgent:
    card: AgentCard
    model: Any  # MaskablePPO


def load_agent(directory: str | Path) -> LoadedAgent:
    """The card and the MaskablePPO model of a model directory (on the CPU)."""
    directory = Path(directory)
    card = read_card(directory)
    if not (directory / MODEL_FILE).is_file():
        raise ConfigError(f"model = {str(directory)!r}: no {MODEL_FILE}")
    return LoadedAgent(card, MaskablePPO.load(directory / MODEL_FILE, device="cpu"))


def set_threads(threads: int) -> None:
    """Torch threads for inference (1 in bench workers: episodes already run in parallel)."""
    torch.set_num_threads(threads)


def row_logits(model: Any, arrays: dict[str, np.ndarray]) -> np.ndarray:
    """(N,) float32: the model's raw logits of one encoded observation (no batch axis)."""
    # As MaskablePPO.predict does: evaluation mode, no autograd.
    model.policy.set_training_mode(False)
    with torch.no_grad():
        logits = ActorLogits(model.policy)(
            *(torch.as_tensor(arrays[k])[None] for k in ("heightmap", "globals", "items"))
        )
    return logits[0].numpy()


def choose_row(model: Any, encoded: Encoded, deterministic: bool = True) -> int:
    """The item row the model picks for one encoded observation (which lists something):
    greedily by the shared rule (:func:`~packlab.rl.decision.pick_row`), or sampled."""
    if deterministic:
        return pick_row(row_logits(model, encoded.arrays), encoded.mask)
    action, _ = model.predict(encoded.arrays, action_masks=encoded.mask, deterministic=False)
    return int(np.asarray(action).reshape(-1)[0])


def greedy_action(model: Any, spec: FeatureSpec, observation: Observation) -> Action:
    """The packing action the model takes greedily; the box is set aside when nothing fits."""
    return decide(encode(observation, spec), lambda arrays: row_logits(model, arrays))
