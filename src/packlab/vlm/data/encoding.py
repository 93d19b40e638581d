"""Chat messages (from :mod:`packlab.vlm.prompt.render`) -> model tensors, for inference.

A context is encoded as the model sees it at inference: the chat template renders it with the
generation prompt (``<|im_start|>assistant\\n``), and each image placeholder is expanded to one
``<|image_pad|>`` per merged visual token. Training batches are built by TRL's collator from the
model's processor (:mod:`packlab.vlm.train.sft`); a test checks that both encode a context to
the same tokens.

A context that ends with an assistant turn is a prefill: the template renders it open, without
the generation prompt, and the model continues it (``continue_final_message``).

Step after step: a closed-loop episode encodes a context that repeats most of the previous one.
An :class:`EncodeMemo` (one per episode, at inference) keeps what repeats: each image entry
resolved once, and the tokens of each text segment between images. The tokens are the same:
the tokenizer splits its input at special tokens such as ``<|image_pad|>`` before anything else,
so tokenising the segments between image tokens one by one gives what tokenising the whole text
gives (checked on the memo's first context, and the whole text is tokenised where it does not).

Long histories: :func:`encode_fitting` drops the oldest past step (its user turn and its answer)
until the sequence fits ``max_length``; the system prompt and the current turn are never cut.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image

from packlab.vlm.prompt.render import BLANK_IMAGE, drop_oldest_step

IMAGE_PAD = "<|image_pad|>"
END_OF_TURN = "<|im_end|>"


@dataclass(frozen=True, slots=True)
class ProcessingConfig:
    """How messages become tensors."""

    image_size: int = 224  # side of the blank image that replaces the BLANK_IMAGE marker
    image_root: str | None = None  # base directory of relative image paths (a dataset's root)
    max_length: int | None = None  # token limit; see encode_fitting
    # Extra chat-template variables, e.g. {"enable_thinking": False} for Qwen3.5 checkpoints.
    template_kwargs: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Encoded:
    """One example. Token tensors are 1-D (seq,); pixel_values (patches, C*T*P*P) float32."""

    input_ids: torch.Tensor  # (seq,) int64
    mm_token_type_ids: torch.Tensor  # (seq,) int64: 0 text, 1 image token
    pixel_values: torch.Tensor | None  # (sum of patches over images, patch_dim) float32
    image_grid_thw: torch.Tensor | None  # (n_images, 3) int64: temporal, height, width patches

    @property
    def length(self) -> int:
        return int(self.input_ids.shape[0])


def resolve_image(image: Any, config: ProcessingConfig) -> Image.Image:
    """An RGB PIL image from a message entry: PIL image, numpy array, path, or BLANK_IMAGE."""
    if isinstance(image, str) and image == BLANK_IMAGE:
        return Image.new("RGB", (config.image_size, config.image_size))
    if isinstance(image, (str, Path)):
        p = Path(image)
        if not p.is_absolute() and config.image_root is not None:
            p = Path(config.image_root) / p
        with Image.open(p) as im:
            return im.convert("RGB")
    if isinstance(image, np.ndarray):
        return Image.fromarray(image).convert("RGB")
    if isinstance(image, Image.Image):
        return image.convert("RGB")
    raise TypeError(f"cannot use {type(image).__name__} as an image")


def message_images(messages: Sequence[dict[str, Any]]) -> list[Any]:
    """Image entries in the order the chat template emits their placeholders."""
    return [
        c["image"]
        for m in messages
        if not isinstance(m["content"], str)
        for c in m["content"]
        if c.get("type") == "image"
    ]


class EncodeMemo:
    """What one episode's successive contexts repeat (module docstring): image entries resolved
    once, and each text segment's tokens. Entries are recognised by identity (the prompt
    renderer hands the same image object for the same heightmap; the memo holds a reference, so
    an identity is never reused while remembered) or, for markers and paths, by value. Arrays
    are resolved every time: they can change in place. ``clear`` at the start of an episode."""

    def __init__(self, max_items: int = 4096) -> None:
        self.max_items = max_items
        self._images: dict[Any, tuple[Any, Image.Image]] = {}
        self._segments: dict[str, list[int]] = {}
        self._segmentwise: bool | None = None  # None: not checked yet against the whole text

    def clear(self) -> None:
        self._images.clear()
        self._segments.clear()

    def image(self, entry: Any, config: ProcessingConfig) -> Image.Image:
        if isinstance(entry, np.ndarray):
            return resolve_image(entry, config)
        key = (entry, config.image_size) if isinstance(entry, (str, Path)) else id(entry)
        hit = self._images.get(key)
        if hit is not None and hit[0] is entry:
            return hit[1]
        if len(self._images) >= self.max_items:
            self._images.clear()
        image = resolve_image(entry, config)
        self._images[key] = (entry, image)
        return image

    def token_ids(self, parts: Sequence[str], counts: Sequence[int], tokenizer) -> list[int]:
        """The ids of ``parts`` joined by ``counts[i]`` image tokens, segment by segment."""
        if self._segmentwise is False:
            return _whole_text_ids(parts, counts, tokenizer)
        pad = tokenizer.convert_tokens_to_ids(IMAGE_PAD)
        ids = self._segment(parts[0], tokenizer)
        for n, part in zip(counts, parts[1:], strict=True):
            ids = ids + [pad] * n + self._segment(part, tokenizer)
        if self._segmentwise is None:
            self._segmentwise = ids == _whole_text_ids(parts, counts, tokenizer)
            if not self._segmentwise:
                return _whole_text_ids(parts, counts, tokenizer)
        return ids

    def _segment(self, text: str, tokenizer) -> list[int]:
        ids = self._segments.get(text)
        if ids is None:
            if len(self._segments) >= self.max_items:
                self._segments.clear()
            ids = tokenizer(text, add_special_tokens=False)["input_ids"] if text else []
            self._segments[text] = ids
        return ids


def _whole_text_ids(parts: Sequence[str], counts: Sequence[int], tokenizer) -> list[int]:
    text = parts[0] + "".join(IMAGE_PAD * n + rest for n, rest in zip(counts, parts[1:]))
    return tokenizer(text, add_special_tokens=False)["input_ids"]


def encode(
    messages: Sequence[dict[str, Any]],
    tokenizer,
    image_processor,
    config: ProcessingConfig = ProcessingConfig(),
    memo: EncodeMemo | None = None,
) -> Encoded:
    """Encode one context (ending with the user turn to answer, or with an assistant prefill to
    continue) into model inputs. ``memo``: the episode's :class:`EncodeMemo` (same result)."""
    entries = message_images(messages)
    if memo is None:
        images = [resolve_image(im, config) for im in entries]
    else:
        images = [memo.image(im, config) for im in entries]
    prefill = bool(messages) and messages[-1]["role"] == "assistant"
    text = tokenizer.apply_chat_template(
        list(messages),
        tokenize=False,
        add_generation_prompt=not prefill,
        **({"continue_final_message": True} if prefill else {}),
        **config.template_kwargs,
    )
    parts = text.split(IMAGE_PAD)
    if len(parts) - 1 != len(images):
        raise ValueError(
            f"chat template emitted {len(parts) - 1} image placeholders for {len(images)} images"
        )
    pixel_values = grid = None
    counts: list[int] = []
    if images:
        vis = image_processor(images=images, return_tensors="pt")
        pixel_values, grid = vis["pixel_values"].float(), vis["image_grid_thw"].long()
        merge = int(image_processor.merge_size) ** 2
        counts = [int(g.prod()) // merge for g in grid]
    if memo is None:
        ids = _whole_text_ids(parts, counts, tokenizer)
    else:
        ids = memo.token_ids(parts, counts, tokenizer)
    input_ids = torch.tensor(ids, dtype=torch.long)
    image_token = tokenizer.convert_tokens_to_ids(IMAGE_PAD)
    mm = (input_ids == image_token).long()
    if grid is not None and int(mm.sum()) != sum(counts):
        raise ValueError(
            "image tokens in the sequence do not match the image grids "
            "(does the tokenizer split <|image_pad|>?)"
        )
    return Encoded(input_ids, mm, pixel_values, grid)


def encode_fitting(
    messages: Sequence[dict[str, Any]],
    tokenizer,
    image_processor,
    config: ProcessingConfig = ProcessingConfig(),
    memo: EncodeMemo | None = None,
) -> tuple[Encoded, int]:
    """:func:`encode`, dropping the oldest past steps until ``config.max_length`` holds.

    Returns (encoded, number of past steps dropped). Raises ValueError when even the context
    without any past step is too long.
    """
    dropped = 0
    msgs: list[dict[str, Any]] | None = list(messages)
    # A prefill is part of the current turn: kept, and kept out of the step dropping.
    tail = [msgs.pop()] if msgs and msgs[-1]["role"] == "assistant" else []
    while True:
        enc = encode([*msgs, *tail], tokenizer, image_processor, config, memo)  # type: ignore[misc]
        if config.max_length is None or enc.length <= config.max_length:
            return enc, dropped
        msgs = drop_oldest_step(msgs)  # type: ignore[arg-type]
        if msgs is None:
            raise ValueError(
                f"{enc.length} tokens without any history exceed max_length={config.max_length}"
            )
        dropped += 1


def collate(
    examples: Sequence[Encoded], pad_id: int, padding_side: str = "left"
) -> dict[str, torch.Tensor]:
    """Pad a batch of prompts (left padding for batched generation)."""
    if padding_side not in ("left", "right"):
        raise ValueError(f"padding_side must be 'left' or 'right', got {padding_side!r}")
    n = max(e.length for e in examples)

    def pad(t: torch.Tensor, value: int) -> torch.Tensor:
        fill = torch.full((n - t.shape[0],), value, dtype=t.dtype)
        return torch.cat([fill, t] if padding_side == "left" else [t, fill])

    out = {
        "input_ids": torch.stack([pad(e.input_ids, pad_id) for e in examples]),
        "attention_mask": torch.stack([pad(torch.ones_like(e.input_ids), 0) for e in examples]),
        "mm_token_type_ids": torch.stack([pad(e.mm_token_type_ids, 0) for e in examples]),
    }
    pv = [e.pixel_values for e in examples if e.pixel_values is not None]
    if pv:
        # The Qwen-VL models take the patches of all images of the batch as one flat sequence.
        out["pixel_values"] = torch.cat(pv)
        out["image_grid_thw"] = torch.cat(
            [e.image_grid_thw for e in examples if e.image_grid_thw is not None]
        )
    return out
