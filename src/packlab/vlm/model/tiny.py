"""Random-weight Qwen-VL-family models, built offline: tiny ones (tests, CPU runs, latency
checks) and ones of a given config.json (memory and speed checks of real dimensions).

Tiny models are the same classes as the real backbones with small dimensions, so tests and CPU
runs exercise the real code paths (M-RoPE, the vision tower, Qwen3.5's gated-delta-net layers).
They carry the project's own tokenizer (:mod:`packlab.vlm.model.tokenizer`), as does a config's
model unless the config's directory holds a tokenizer.
Both are built directly in the requested dtype: a 2B model in bf16 never holds an fp32 copy.
Imports torch/transformers: only the vlm extra may import this module.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from transformers import (
    AutoConfig,
    AutoModelForImageTextToText,
    Qwen2_5_VLConfig,
    Qwen3_5Config,
    Qwen3VLConfig,
)

from packlab.core.choices import ModelDType
from packlab.core.errors import ConfigError
from packlab.vlm.model.checkpoint import (
    FAMILIES,
    VLM,
    config_file,
    family_of,
    has_tokenizer,
    image_processor_for,
    load_image_processor,
    load_tokenizer,
    saved_meta,
    torch_dtype,
)
from packlab.vlm.model.tokenizer import TOKENIZER_NAME, build_tokenizer, special_token_ids


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
    # Candidate-mode pointer models trained on 2 CPU cores (about 1 M parameters).
    "mini": TinySize(
        hidden=128,
        layers=4,
        heads=4,
        kv_heads=2,
        intermediate=512,
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

#: Token ids a Qwen-VL config takes at its top level.
_VISION_TOKEN_IDS = (
    "image_token_id",
    "video_token_id",
    "vision_start_token_id",
    "vision_end_token_id",
)


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


def _text_common(s: TinySize, token_ids: dict[str, int], vocab_size: int) -> dict[str, Any]:
    return {
        "vocab_size": vocab_size,
        "hidden_size": s.hidden,
        "intermediate_size": s.intermediate,
        "num_hidden_layers": s.layers,
        "num_attention_heads": s.heads,
        "num_key_value_heads": s.kv_heads,
        "max_position_embeddings": 32768,
        "pad_token_id": token_ids["pad_token_id"],
        "eos_token_id": token_ids["eos_token_id"],
    }


def _vision_common(s: TinySize) -> dict[str, Any]:
    return {
        "depth": s.vision_depth,
        "hidden_size": s.vision_hidden,
        "num_heads": s.vision_heads,
        "intermediate_size": s.vision_intermediate,
        "out_hidden_size": s.hidden,
        "spatial_merge_size": 2,
        "temporal_patch_size": 2,
    }


def _qwen3_5(s: TinySize, text: dict[str, Any], vision: dict[str, Any], ids: dict[str, int]):
    partial = 0.25
    text = {
        **text,
        "head_dim": s.head_dim,
        # Qwen3.5 interleaves 3 gated-delta-net (linear attention) layers per full one; tiny
        # models keep both kinds so that both code paths run.
        "layer_types": [
            "linear_attention" if (i + 1) % min(4, s.layers) else "full_attention"
            for i in range(s.layers)
        ],
        "linear_key_head_dim": s.head_dim // 2,
        "linear_value_head_dim": s.head_dim // 2,
        "linear_num_key_heads": max(1, s.heads // 2),
        "linear_num_value_heads": s.heads,
        "rope_parameters": {
            "rope_type": "default",
            "rope_theta": 10_000_000.0,
            "partial_rotary_factor": partial,
            "mrope_interleaved": True,
            "mrope_section": mrope_sections(int(s.head_dim * partial) // 2, (11, 11, 10)),
        },
    }
    vision = {**vision, "patch_size": 16, "num_position_embeddings": 256}
    return Qwen3_5Config(text_config=text, vision_config=vision, **ids)


def _qwen3_vl(s: TinySize, text: dict[str, Any], vision: dict[str, Any], ids: dict[str, int]):
    text = {
        **text,
        "head_dim": s.head_dim,
        "rope_parameters": {
            "rope_type": "default",
            "rope_theta": 5_000_000.0,
            "mrope_interleaved": True,
            "mrope_section": mrope_sections(s.head_dim // 2, (24, 20, 20)),
        },
    }
    # Deepstack injects features of the listed vision blocks into the first LLM layers.
    vision = {
        **vision,
        "patch_size": 16,
        "num_position_embeddings": 256,
        "deepstack_visual_indexes": [s.vision_depth - 1],
    }
    return Qwen3VLConfig(text_config=text, vision_config=vision, **ids)


def _qwen2_5_vl(s: TinySize, text: dict[str, Any], vision: dict[str, Any], ids: dict[str, int]):
    if s.hidden // s.heads != s.head_dim:
        raise ValueError("Qwen2.5-VL derives head_dim from hidden/heads; sizes must agree")
    text = {
        **text,
        "bos_token_id": None,  # the class default is the real vocabulary's id
        "rope_parameters": {
            "rope_type": "default",
            "rope_theta": 1_000_000.0,
            "mrope_section": mrope_sections(s.head_dim // 2, (16, 24, 24)),
        },
    }
    vision = {
        **vision,
        "patch_size": 14,
        "window_size": 112,
        "fullatt_block_indexes": [s.vision_depth - 1],
    }
    return Qwen2_5_VLConfig(text_config=text, vision_config=vision, **ids)


#: family -> the builder of its transformers config.
_CONFIG_BUILDERS = {"qwen3_5": _qwen3_5, "qwen3_vl": _qwen3_vl, "qwen2_5_vl": _qwen2_5_vl}


def tiny_config(family: str, size: str, token_ids: dict[str, int], vocab_size: int):
    """A transformers config of the family's real class with :data:`SIZES` dimensions."""
    if size not in SIZES:
        raise ValueError(f"unknown size {size!r}; expected one of {tuple(SIZES)}")
    if family not in _CONFIG_BUILDERS:
        raise ValueError(f"unknown family {family!r}; expected one of {FAMILIES}")
    s = SIZES[size]
    ids = {k: token_ids[k] for k in _VISION_TOKEN_IDS}
    text = _text_common(s, token_ids, vocab_size)
    return _CONFIG_BUILDERS[family](s, text, _vision_common(s), ids)


def random_model(config: Any, seed: int, dtype: torch.dtype) -> Any:
    """The config's model class with seeded random weights, allocated directly in ``dtype``.

    ``_from_config`` makes ``dtype`` torch's default while the modules are built, so no fp32
    copy of the weights ever exists (casting afterwards would hold both for a moment).
    """
    torch.manual_seed(seed)
    model_cls = AutoModelForImageTextToText._model_mapping[type(config)]
    return model_cls._from_config(config, dtype=dtype).eval()


def _generate_with(model: Any, ids: dict[str, int]) -> None:
    """Make generation stop and pad at the tokenizer's ids."""
    model.generation_config.eos_token_id = ids["eos_token_id"]
    model.generation_config.pad_token_id = ids["pad_token_id"]


def build_tiny_model(
    family: str = "qwen3_5", size: str = "tiny", seed: int = 0, dtype: ModelDType = "fp32"
) -> VLM:
    """A random-weight model of the family's real class, with the project's own tokenizer.

    Fully offline and deterministic for (family, size, seed, dtype).
    """
    weights_dtype = torch_dtype(dtype)
    tokenizer = build_tokenizer(seed=seed)
    ids = special_token_ids(tokenizer)
    vocab = -(-len(tokenizer) // 64) * 64  # pad the embedding to a multiple of 64 rows
    config = tiny_config(family, size, ids, vocab)
    model = random_model(config, seed, weights_dtype)
    _generate_with(model, ids)
    meta = {
        "family": family,
        "size": size,
        "seed": seed,
        "tiny": asdict(SIZES[size]),
        "tokenizer": TOKENIZER_NAME,
    }
    return VLM(model, tokenizer, image_processor_for(family), family, meta)


def _use_token_ids(config: Any, ids: dict[str, int]) -> None:
    """Point the config's special token ids at the project tokenizer's: a real model's config
    names ids of the real vocabulary, where the project tokenizer has other tokens or none."""
    for key in _VISION_TOKEN_IDS:
        setattr(config, key, ids[key])
    text = config.get_text_config()
    text.pad_token_id = ids["pad_token_id"]
    text.eos_token_id = ids["eos_token_id"]
    text.bos_token_id = None  # the project tokenizer has no BOS token


def _check_vocab(config: Any, tokenizer: Any, file: Path) -> None:
    """Every token id must have an embedding row; a larger vocabulary (padding) is fine."""
    text = config.get_text_config()
    field = "vocab_size" if text is config else "text_config.vocab_size"
    if text.vocab_size < len(tokenizer):
        raise ConfigError(
            f"{file}: {field} = {text.vocab_size}: smaller than the tokenizer "
            f"({len(tokenizer)} tokens); every token id needs an embedding row"
        )


def build_config_model(path: str | Path, seed: int = 0, dtype: ModelDType = "fp32") -> VLM:
    """A model of a config.json (or of a directory's) with seeded random weights.

    The tokenizer and image processor are the directory's when it holds them, else the
    project's own tokenizer (the config's special token ids are then replaced by its ids) and
    the family's image processor. Raises ``ConfigError`` when the config's vocabulary is smaller
    than the tokenizer.
    """
    weights_dtype = torch_dtype(dtype)
    file = config_file(path)
    if not file.is_file():
        raise ConfigError(f"model = config:{path}: no config.json there")
    try:
        family = family_of(file)
    except ValueError as exc:  # a model_type of no supported family
        raise ConfigError(str(exc)) from None
    config = AutoConfig.from_pretrained(file)
    folder = file.parent
    meta: dict[str, Any] = {"family": family, "seed": seed, "config": str(file)}
    ids = None
    if has_tokenizer(folder):
        tokenizer = load_tokenizer(folder)
        # Saving this model must mark the tokenizer as load_model's reading of it needs.
        if "tokenizer" in (folder_meta := saved_meta(folder)):
            meta["tokenizer"] = folder_meta["tokenizer"]
    else:
        # Seeded as tiny models' are, so config and tiny models of one seed share a tokenizer.
        tokenizer = build_tokenizer(seed=seed)
        ids = special_token_ids(tokenizer)
        _use_token_ids(config, ids)
        meta["tokenizer"] = TOKENIZER_NAME
    _check_vocab(config, tokenizer, file)
    model = random_model(config, seed, weights_dtype)
    if ids is not None:
        _generate_with(model, ids)
    return VLM(model, tokenizer, load_image_processor(folder, family), family, meta)
