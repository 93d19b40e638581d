"""Qwen-VL-family models: build a tiny random-weight one offline, or load a checkpoint from disk.

A :class:`VLM` bundles what every consumer (trainer, inference policy) needs together: the
transformers model, its tokenizer, and an image processor that works without torchvision (the
PIL implementation of the Qwen2-VL image processor, which all three families share: Qwen3-VL
and Qwen3.5 with 16 px patches merged 2x2, i.e. 32 px per visual token; Qwen2.5-VL with 14 px
patches, 28 px per token).

Tiny models are the same classes as the real backbones with small dimensions, so tests and CPU
runs exercise the real code paths (M-RoPE, the vision tower, Qwen3.5's gated-delta-net layers).
Imports torch/transformers: only the vlm extra may import this module.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from transformers import AutoModelForImageTextToText, AutoTokenizer, PreTrainedTokenizerFast
from transformers.models.qwen2_vl.image_processing_pil_qwen2_vl import Qwen2VLImageProcessorPil

from packlab.vlm.tokenizer import TOKENIZER_NAME, build_tokenizer, special_token_ids

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


@dataclass(frozen=True, slots=True)
class TinySize:
    """Dimensions of a tiny model. head_dim is fixed at 32 so that M-RoPE has room for 3 sections
    even under Qwen3.5's partial rotary factor of 0.25 (32 * 0.25 / 2 = 4 frequencies)."""

    hidden: int
    layers: int
    heads: int
    kv_heads: int
    intermediate: int
    vision_hidden: int
    vision_depth: int
    vision_heads: int
    vision_intermediate: int
    head_dim: int = 32


SIZES: dict[str, TinySize] = {
    # Unit tests: forward + generate in well under a second on CPU.
    "tiny": TinySize(
        hidden=64,
        layers=2,
        heads=2,
        kv_heads=1,
        intermediate=128,
        vision_hidden=32,
        vision_depth=1,
        vision_heads=2,
        vision_intermediate=64,
    ),
    # CPU training runs (a few M parameters).
    "small": TinySize(
        hidden=256,
        layers=4,
        heads=8,
        kv_heads=2,
        intermediate=768,
        vision_hidden=128,
        vision_depth=2,
        vision_heads=4,
        vision_intermediate=384,
    ),
    "base": TinySize(
        hidden=512,
        layers=8,
        heads=16,
        kv_heads=4,
        intermediate=1536,
        vision_hidden=256,
        vision_depth=4,
        vision_heads=8,
        vision_intermediate=768,
    ),
}


@dataclass
class VLM:
    """A model with its tokenizer and image processor (mutable: it holds weights)."""

    model: Any  # a transformers *ForConditionalGeneration
    tokenizer: Any
    image_processor: Qwen2VLImageProcessorPil
    family: str
    meta: dict[str, Any]


def mrope_sections(half_rotary_dim: int, reference: tuple[int, int, int]) -> list[int]:
    """Split the rotary frequencies into (t, h, w) sections in the real model's proportions.

    The sections must add up to head_dim * partial_rotary_factor / 2 (one entry per frequency).
    """
    total = sum(reference)
    raw = [half_rotary_dim * r / total for r in reference]
    out = [int(v) for v in raw]
    # Hand out the rounding remainder by largest fractional part; every axis gets at least one.
    for i in sorted(range(3), key=lambda i: raw[i] - out[i], reverse=True)[
        : half_rotary_dim - sum(out)
    ]:
        out[i] += 1
    if min(out) < 1:
        raise ValueError(f"{half_rotary_dim} rotary frequencies cannot feed 3 M-RoPE sections")
    return out


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


def tiny_config(family: str, size: str, token_ids: dict[str, int], vocab_size: int):
    """A transformers config of the family's real class with :data:`SIZES` dimensions."""
    if size not in SIZES:
        raise ValueError(f"unknown size {size!r}; expected one of {tuple(SIZES)}")
    s = SIZES[size]
    ids = {
        k: token_ids[k]
        for k in (
            "image_token_id",
            "video_token_id",
            "vision_start_token_id",
            "vision_end_token_id",
        )
    }
    text_common = dict(
        vocab_size=vocab_size,
        hidden_size=s.hidden,
        intermediate_size=s.intermediate,
        num_hidden_layers=s.layers,
        num_attention_heads=s.heads,
        num_key_value_heads=s.kv_heads,
        max_position_embeddings=32768,
        pad_token_id=token_ids["pad_token_id"],
        eos_token_id=token_ids["eos_token_id"],
    )
    vision_common = dict(
        depth=s.vision_depth,
        hidden_size=s.vision_hidden,
        num_heads=s.vision_heads,
        intermediate_size=s.vision_intermediate,
        out_hidden_size=s.hidden,
        spatial_merge_size=2,
        temporal_patch_size=2,
    )
    if family == "qwen3_5":
        from transformers import Qwen3_5Config

        partial = 0.25
        text = dict(
            text_common,
            head_dim=s.head_dim,
            # Qwen3.5 interleaves 3 gated-delta-net (linear attention) layers per full one; tiny
            # models keep both kinds so that both code paths run.
            layer_types=[
                "linear_attention" if (i + 1) % min(4, s.layers) else "full_attention"
                for i in range(s.layers)
            ],
            linear_key_head_dim=s.head_dim // 2,
            linear_value_head_dim=s.head_dim // 2,
            linear_num_key_heads=max(1, s.heads // 2),
            linear_num_value_heads=s.heads,
            rope_parameters={
                "rope_type": "default",
                "rope_theta": 10_000_000.0,
                "partial_rotary_factor": partial,
                "mrope_interleaved": True,
                "mrope_section": mrope_sections(int(s.head_dim * partial) // 2, (11, 11, 10)),
            },
        )
        vision = dict(vision_common, patch_size=16, num_position_embeddings=256)
        return Qwen3_5Config(text_config=text, vision_config=vision, **ids)
    if family == "qwen3_vl":
        from transformers import Qwen3VLConfig

        text = dict(
            text_common,
            head_dim=s.head_dim,
            rope_parameters={
                "rope_type": "default",
                "rope_theta": 5_000_000.0,
                "mrope_interleaved": True,
                "mrope_section": mrope_sections(s.head_dim // 2, (24, 20, 20)),
            },
        )
        # Deepstack injects features of the listed vision blocks into the first LLM layers.
        vision = dict(
            vision_common,
            patch_size=16,
            num_position_embeddings=256,
            deepstack_visual_indexes=[s.vision_depth - 1],
        )
        return Qwen3VLConfig(text_config=text, vision_config=vision, **ids)
    if family == "qwen2_5_vl":
        from transformers import Qwen2_5_VLConfig

        if s.hidden // s.heads != s.head_dim:
            raise ValueError("Qwen2.5-VL derives head_dim from hidden/heads; sizes must agree")
        text = dict(
            text_common,
            bos_token_id=None,  # the class default is the real vocabulary's id
            rope_parameters={
                "rope_type": "default",
                "rope_theta": 1_000_000.0,
                "mrope_section": mrope_sections(s.head_dim // 2, (16, 24, 24)),
            },
        )
        vision = dict(
            vision_common,
            patch_size=14,
            window_size=112,
            fullatt_block_indexes=[s.vision_depth - 1],
        )
        return Qwen2_5_VLConfig(text_config=text, vision_config=vision, **ids)
    raise ValueError(f"unknown family {family!r}; expected one of {FAMILIES}")


def build_tiny_model(family: str = "qwen3_5", size: str = "tiny", seed: int = 0) -> VLM:
    """A random-weight model of the family's real class, with the project's own tokenizer.

    Fully offline and deterministic for (family, size, seed).
    """
    tokenizer = build_tokenizer(seed=seed)
    ids = special_token_ids(tokenizer)
    vocab = -(-len(tokenizer) // 64) * 64  # pad the embedding to a multiple of 64 rows
    config = tiny_config(family, size, ids, vocab)
    torch.manual_seed(seed)
    model_cls = AutoModelForImageTextToText._model_mapping[type(config)]
    model = model_cls(config)
    model.generation_config.eos_token_id = ids["eos_token_id"]
    model.generation_config.pad_token_id = ids["pad_token_id"]
    model.eval()
    meta = {
        "family": family,
        "size": size,
        "seed": seed,
        "tiny": asdict(SIZES[size]),
        "tokenizer": TOKENIZER_NAME,
    }
    return VLM(model, tokenizer, image_processor_for(family), family, meta)


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
    from packlab.vlm.prompt import PROMPT_VERSION

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
