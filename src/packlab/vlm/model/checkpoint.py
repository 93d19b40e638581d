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

from packlab.core.choices import ModelDType, require_choice
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

#: :data:`~packlab.core.choices.ModelDType` name -> torch dtype.
TORCH_DTYPES: dict[str, torch.dtype] = {
    "fp32": torch.float32,
    "bf16": torch.bfloat16,
    "fp16": torch.float16,
}

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


def torch_dtype(name: ModelDType | str) -> torch.dtype:
    """The torch dtype of a :data:`~packlab.core.choices.ModelDType` name (``bf16``...).

    Raises ``ConfigError`` naming any other value.
    """
    require_choice(name, ModelDType, "dtype")
    return TORCH_DTYPES[name]


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


def config_file(path: str | Path) -> Path:
    """The config.json of a checkpoint directory, or ``path`` itself when it names a file."""
    path = Path(path)
    return path if path.is_file() else path / "config.json"


def family_of(path: str | Path) -> str:
    """The family of a checkpoint directory (or of a config.json), from its model_type."""
    cfg = json.loads(config_file(path).read_text())
    mt = cfg.get("model_type", "")
    if mt not in MODEL_TYPE_FAMILY:
        raise ValueError(
            f"{path}: model_type {mt!r} is not a supported Qwen-VL family "
            f"({', '.join(sorted(MODEL_TYPE_FAMILY))})"
        )
    return MODEL_TYPE_FAMILY[mt]


def saved_meta(path: str | Path) -> dict[str, Any]:
    """The packlab metadata saved in a checkpoint directory ({} when packlab did not save it)."""
    meta_path = Path(path) / PACKLAB_META
    return json.loads(meta_path.read_text()) if meta_path.is_file() else {}


def has_tokenizer(path: str | Path) -> bool:
    """Whether a directory holds a saved tokenizer."""
    path = Path(path)
    return (path / "tokenizer.json").is_file() or (path / "tokenizer_config.json").is_file()


def load_tokenizer(path: str | Path) -> Any:
    """The tokenizer saved in a directory."""
    if saved_meta(path).get("tokenizer") == TOKENIZER_NAME:
        # Our tokenizer.json is complete; read it as is rather than through the family's class.
        return PreTrainedTokenizerFast.from_pretrained(path, local_files_only=True)
    return AutoTokenizer.from_pretrained(path, local_files_only=True)


def load_image_processor(path: str | Path, family: str) -> Qwen2VLImageProcessorPil:
    """The image processor saved in a directory, else the family's default one."""
    if (Path(path) / "preprocessor_config.json").is_file():
        return Qwen2VLImageProcessorPil.from_pretrained(path, local_files_only=True)
    return image_processor_for(family)


def load_model(
    path: str | Path,
    dtype: torch.dtype | ModelDType = torch.float32,
    device: str = "cpu",
    quantization_config: Any = None,
) -> VLM:
    """Load any Qwen-VL-family checkpoint from a local directory (never from a hub).

    The weights are materialised straight in ``dtype`` (transformers reads each tensor from the
    memory-mapped safetensors and casts it as it goes), so a bf16 load never holds an fp32 copy.
    ``quantization_config`` (a transformers ``BitsAndBytesConfig``, QLoRA) loads the weights
    quantized, placed on ``device`` by transformers itself.
    """
    path = Path(path)
    if not (path / "config.json").is_file():
        raise FileNotFoundError(f"{path}: no config.json (expected a local checkpoint directory)")
    if not isinstance(dtype, torch.dtype):
        dtype = torch_dtype(dtype)
    family = family_of(path)
    extra = {} if quantization_config is None else {"quantization_config": quantization_config}
    if quantization_config is not None:
        extra["device_map"] = {"": device}  # a quantized model cannot be moved after loading
    model = AutoModelForImageTextToText.from_pretrained(
        path, dtype=dtype, local_files_only=True, **extra
    )
    if quantization_config is None and device != "cpu":
        # (On the CPU there is nothing to move; under FSDP's cpu-RAM-efficient loading the other
        # ranks hold meta tensors, which cannot be copied.)
        model.to(device)
    model.eval()
    meta = saved_meta(path) or {"family": family}
    return VLM(model, load_tokenizer(path), load_image_processor(path, family), family, meta)


def save_model(
    vlm: VLM,
    path: str | Path,
    extra_meta: dict[str, Any] | None = None,
    state_dict: dict[str, Any] | None = None,
    weights: bool = True,
) -> Path:
    """Write model, tokenizer, image processor and packlab metadata for :func:`load_model`.

    ``state_dict`` overrides the model's own (a gathered one under FSDP). ``weights=False``
    writes everything but the weights and config, for a trainer that saved those itself
    (gathered from every process).
    """
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    if weights:
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
