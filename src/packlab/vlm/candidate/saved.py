"""Saving and loading a pointer model: a Qwen-VL checkpoint directory plus the pointer head.

The directory is an ordinary checkpoint (:func:`packlab.vlm.model.checkpoint.save_model`) with
``pointer_head.safetensors`` beside it and ``packlab_model.json`` saying
``"action_format": "candidate"`` with the proposer, the instructions and the teacher it was
trained with, so the policy rebuilds exactly the training-time prompt. Its ``map`` says how the
model sees the heightmap (:data:`packlab.core.choices.PointerMap`); a directory written before
that field existed holds a text-map model and loads with ``map`` = ``"text"``. Its
``image_mean`` and ``image_std`` are the normalisation the model was trained with
(:func:`.encoding.image_norm`); a directory written before they were recorded was trained with
Qwen3-VL's (0.5), whatever its family's processor says, and loads with those. Its
``line_fields``, ``image_tokens``, ``footprint_pool`` and ``footprint_context`` (absent:
``"full"``, 4, off and off) say what the listed lines name, the image's tokens per side,
whether the head pools the image under each line and whether it also reads the max there and
the ring around it (:mod:`.encoding`, :mod:`.pointer`).
Imports torch: only the vlm extra may import this module.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

from packlab.core.errors import ConfigError
from packlab.vlm.candidate.encoding import image_norm
from packlab.vlm.candidate.files import CANDIDATE_FORMAT, HEAD_FILE, is_pointer_dir
from packlab.vlm.candidate.image import QWEN3_MEAN, QWEN3_STD
from packlab.vlm.candidate.pointer import PointerModel
from packlab.vlm.model.checkpoint import PACKLAB_META, load_model, save_model

#: The map of a pointer directory saved before ``map`` was recorded: the digit text map.
LEGACY_MAP = "text"


def save_pointer(model: PointerModel, path: Path, meta: dict[str, Any]) -> Path:
    mean, std = image_norm(model.vlm)
    norm = {"image_mean": list(mean), "image_std": list(std)}
    save_model(model.vlm, path, extra_meta={**meta, **norm, "action_format": CANDIDATE_FORMAT})
    # On the CPU, so that a head trained on a GPU loads anywhere.
    save_file({k: v.detach().cpu().contiguous() for k, v in model.head.state_dict().items()},
              str(path / HEAD_FILE))  # fmt: skip
    return path


def load_pointer(path: str | Path, device: str = "cpu") -> PointerModel:
    path = Path(path)
    if not is_pointer_dir(path):
        raise ConfigError(f"{path}: no {HEAD_FILE} (not a candidate-mode checkpoint)")
    vlm = load_model(path, dtype=torch.float32, device=device)
    if vlm.meta.get("action_format") != CANDIDATE_FORMAT:
        raise ConfigError(
            f"{path / PACKLAB_META}: action_format = {vlm.meta.get('action_format')!r}: "
            f"expected {CANDIDATE_FORMAT!r}"
        )
    vlm.meta.setdefault("map", LEGACY_MAP)
    vlm.meta.setdefault("image_mean", list(QWEN3_MEAN))  # saved before it was recorded
    vlm.meta.setdefault("image_std", list(QWEN3_STD))
    lines = bool(vlm.meta.get("line_vectors", False))  # a card before line vectors: text only
    footprint = bool(vlm.meta.get("footprint_pool", False))  # a card before it: none
    context = footprint and bool(vlm.meta.get("footprint_context", False))  # likewise
    model = PointerModel(
        vlm, vlm.meta.get("pool", "last"), vlm.meta["map"], lines, footprint, context
    )
    model.head.load_state_dict(load_file(str(path / HEAD_FILE)))
    return model.to(device).eval()
