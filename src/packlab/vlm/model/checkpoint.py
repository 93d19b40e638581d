"""Qwen-VL-family models: the :class:`VLM` bundle, and checkpoint directories (load and save).

A :class:`VLM` bundles what every consumer (trainer, inference policy) needs together: the
transformers model, its tokenizer, and an image processor that works without torchvision (the
PIL implementation of the Qwen2-VL image processor, which all three families share: Qwen3-VL
and Qwen3.5 with 16 px patches merged 2x2, i.e. 32 px per visual token; Qwen2.5-VL with 14 px
patches, 28 px per token).

Tiny random-weight models of the same classes are built by :mod:`packlab.vlm.model.tiny`.
Imports torch/transformers: only the vlm extra may import this module.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from transformers import AutoModelForImageTextToText, AutoTokenizer, PreTrainedTokenizerFast
from transformers.models.qwen2_vl.image_processing_pil_qwen2_vl import Qwen2VLImageProcessorPil

from packlab.vlm.model.tokenizer import TOKENIZER_NAME
from packlab.vlm.prompt.render import PROMPT_VERSION

FAMILIES: tuple[str, ...] = ("qwen3_5", "qwen3_vl", "qwen2_5_vl")
#: model_type in a checkpoint's config.json -> family (MoE variants share the processing).
MODEL_TYPE_FAMILY = {
    "qwen3_5": "qwen3_5",
    "qwen3_5_moe": "qwen3_5",
    "qwen3_vl": "qwen3_vl",
    "qwen3_vl_moe": "qwen3_vl",
    "qwen2_5_vl": "qwen2_5_vl",
    "qwen2_vl": "qwen2_5_vl",
}
#: Written beside a checkpoint that packlab saved: family, size, prompt version, training config.
PACKLAB_META = "packlab_model.json"

_CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
_CLIP_STD = (0.26862954, 0.26130258, 0.27577711)


@dataclass
class VLM:
    """A model with its tokenizer and image processor (mutable: it holds weights)."""

    model: Any  # a transformers *ForConditionalGeneration
    tokenizer: Any
    image_processor: Qwen2VLImageProcessorPil
    family: str
    meta: dict[str, Any]


def image_processor_for(family: str, max_pixels: int = 1024 * 1024) -> Qwen2VLImageProcessorPil:
    """The family's image preprocessing (patch size, merge size, normalisation)."""
    if family not in FAMILIES:
        raise ValueError(f"unknown family {family!r}; expected one of {FAMILIES}")
    patch = 14 if family == "qwen2_5_vl" else 16
    mean, std = (_CLIP_MEAN, _CLIP_STD) if family == "qwen2_5_vl" else ((0.5,) * 3, (0.5,) * 3)
    factor = patch * 2
    return Qwen2VLImageProcessorPil(
        patch_size=patch,
        merge_size=2,
        temporal_patch_size=2,
        image_mean=list(mean),
        image_std=list(std),
        size={"shortest_edge": factor * factor, "longest_edge": max_pixels},
    )


def family_of(path: str | Path) -> str:
    """The family of a checkpoint directory, from its config.json model_type."""
    cfg = json.loads((Path(path) / "config.json").read_text())
    mt = cfg.get("model_type", "")
    if mt not in MODEL_TYPE_FAMILY:
        raise ValueError(
            f"{path}: model_type {mt!r} is not a supported Qwen-VL family "
            f"({', '.join(sorted(MODEL_TYPE_FAMILY))})"
        )
    return MODEL_TYPE_FAMILY[mt]


def load_model(
    path: str | Path, dtype: torch.dtype | str = torch.float32, device: str = "cpu"
) -> VLM:
    """Load any Qwen-VL-family checkpoint from a local directory (never from a hub)."""
    path = Path(path)
    if not (path / "config.json").is_file():
        raise FileNotFoundError(f"{path}: no config.json (expected a local checkpoint directory)")
    family = family_of(path)
    model = AutoModelForImageTextToText.from_pretrained(path, dtype=dtype, local_files_only=True)
    model.to(device).eval()
    meta_path = path / PACKLAB_META
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {"family": family}
    if meta.get("tokenizer") == TOKENIZER_NAME:
        # Our tokenizer.json is complete; read it as is rather than through the family's class.
        tokenizer = PreTrainedTokenizerFast.from_pretrained(path, local_files_only=True)
    else:
        tokenizer = AutoTokenizer.from_pretrained(path, local_files_only=True)
    if (path / "preprocessor_config.json").is_file():
        image_processor = Qwen2VLImageProcessorPil.from_pretrained(path, local_files_only=True)
    else:
        image_processor = image_processor_for(family)
    return VLM(model, tokenizer, image_processor, family, meta)


def save_model(
    vlm: VLM,
    path: str | Path,
    extra_meta: dict[str, Any] | None = None,
    state_dict: dict[str, Any] | None = None,
) -> Path:
    """Write model, tokenizer, image processor and packlab metadata for :func:`load_model`.

    ``state_dict`` overrides the model's own (a gathered one under FSDP).
    """
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    vlm.model.save_pretrained(path, state_dict=state_dict)
    vlm.tokenizer.save_pretrained(path)
    vlm.image_processor.save_pretrained(path)
    meta = {
        **vlm.meta,
        "family": vlm.family,
        "prompt_version": PROMPT_VERSION,
        **(extra_meta or {}),
    }
    (path / PACKLAB_META).write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    return path


def count_parameters(model) -> int:
    return sum(p.numel() for p in model.parameters())
