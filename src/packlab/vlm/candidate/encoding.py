"""A state as the pointer model reads it: prompt text, token ids, the tokens of each listed
line, the heightmap image, the line vectors and each line's footprint on the image's token grid
(:class:`Encoded`), for training and for both runtimes (torch and ONNX).

Torch-free: the tokenizer is anything with the transformers tokenizer's calls used here
(``__call__`` with offsets, ``convert_tokens_to_ids``, ``apply_chat_template``): the
transformers tokenizer of a loaded checkpoint (:mod:`.pointer`, training) or
:class:`packlab.vlm.candidate.json_tokenizer.JsonTokenizer` (the ONNX runtime), so both runtimes
build their inputs with this one code.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from packlab.core.choices import LineFields, PointerMap
from packlab.core.types import Observation
from packlab.policies.candidates import Candidate
from packlab.policies.line_vector import LINE_VECTOR_SIZE, line_vectors
from packlab.vlm.candidate.compose import (
    IMAGE_MAPS,
    Answer,
    Instructions,
    answer_text,
    line_text,
    observation_messages,
    state_messages,
)
from packlab.vlm.candidate.image import (
    QWEN3_MEAN,
    QWEN3_STD,
    TOKENS_PER_SIDE,
    blank_image,
    footprint_tokens,
    heightmap_image,
    image_side,
    patchify,
    ring_tokens,
    visual_tokens,
)
from packlab.vlm.candidate.states import LabelledState, listed_of, observation_of
from packlab.vlm.model.chatml import IM_END, IMAGE_PAD
from packlab.vlm.prompt.parse import ACTION_KEYS


@dataclass(frozen=True, slots=True)
class PromptSettings:
    """How the model was trained to read a state (from its ``packlab_model.json``)."""

    instructions: Instructions = "short"
    blank_map: bool = False
    answer: Answer = "index"
    map: PointerMap = "text"
    line_vectors: bool = False
    #: What each listed line names (:mod:`.compose`): the full geometry, or its cell only.
    line_fields: LineFields = "full"
    #: Merged visual tokens per image side (:mod:`.image`).
    image_tokens: int = TOKENS_PER_SIDE
    #: Each line's footprint on the visual token grid is encoded (the head pools there).
    footprint_pool: bool = False
    #: With ``footprint_pool``: the head also reads the max over the footprint's tokens and the
    #: mean over the one-token ring around it (:func:`rings`).
    footprint_context: bool = False

    @classmethod
    def of(cls, meta: dict[str, Any], blank_map: bool = False) -> PromptSettings:
        """The settings of a model card; ``blank_map`` forces the blank-map ablation on. A card
        written before line fields, image tokens and footprint pooling (or its context) has
        their defaults."""
        return cls(
            meta["instructions"],
            bool(meta.get("blank_map", False)) or blank_map,
            meta.get("answer", "index"),
            meta.get("map", "text"),  # a model card written before maps: the text map
            bool(meta.get("line_vectors", False)),  # a card before line vectors: text only
            meta.get("line_fields", "full"),
            int(meta.get("image_tokens", TOKENS_PER_SIDE)),
            bool(meta.get("footprint_pool", False)),
            bool(meta.get("footprint_context", False)),
        )


#: A model card's record of the normalisation its pointer model was trained with (the image
#: processor's names), written by :func:`packlab.vlm.candidate.saved.save_pointer`.
NORM_KEYS = ("image_mean", "image_std")


def _triple(values: Any) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


def image_norm(vlm: Any) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(mean, std) per RGB channel a loaded model's images are normalised with: its model
    card's record (what a saved pointer model was trained with), else its image processor's
    (the checkpoint's ``preprocessor_config.json``, or its family's), else Qwen3-VL's."""
    meta = getattr(vlm, "meta", None) or {}
    if all(meta.get(k) is not None for k in NORM_KEYS):
        return _triple(meta["image_mean"]), _triple(meta["image_std"])
    processor = getattr(vlm, "image_processor", None)
    mean = getattr(processor, "image_mean", None)
    std = getattr(processor, "image_std", None)
    if mean is None or std is None:
        return QWEN3_MEAN, QWEN3_STD
    return _triple(mean), _triple(std)


@dataclass(frozen=True, slots=True)
class ImageGrid:
    """A vision tower's patch geometry (from its config): pixels per patch side, patches per
    merged token side, frames per patch; the normalisation of its pixels (mean and std per
    RGB channel); and the merged tokens per image side (``per_side``, a model card's
    ``image_tokens``). The ONNX card stores it whole (``extra.grid``), so both runtimes patchify
    and normalise alike; a card without ``mean`` and ``std`` was exported with Qwen3-VL's, one
    without ``per_side`` with :data:`.image.TOKENS_PER_SIDE`."""

    patch: int = 16
    merge: int = 2
    temporal: int = 2
    mean: tuple[float, ...] = QWEN3_MEAN
    std: tuple[float, ...] = QWEN3_STD
    per_side: int = TOKENS_PER_SIDE

    def __post_init__(self) -> None:
        # A card read from JSON gives lists: tuples compare equal to the torch side's grid.
        object.__setattr__(self, "mean", _triple(self.mean))
        object.__setattr__(self, "std", _triple(self.std))
        if len(self.mean) != 3 or len(self.std) != 3 or min(self.std) <= 0:
            raise ValueError(f"image mean {self.mean} / std {self.std}: expected 3 each, std > 0")

    @classmethod
    def of(cls, vlm: Any) -> ImageGrid:
        """The grid of a loaded :class:`~packlab.vlm.model.checkpoint.VLM` (:func:`image_norm`;
        tokens per side: its model card's ``image_tokens``, else the default)."""
        v = vlm.model.config.vision_config
        mean, std = image_norm(vlm)
        per_side = int((getattr(vlm, "meta", None) or {}).get("image_tokens", TOKENS_PER_SIDE))
        return cls(int(v.patch_size), int(v.spatial_merge_size), int(v.temporal_patch_size),
                   mean, std, per_side)  # fmt: skip

    @classmethod
    def from_config(
        cls, config: dict[str, Any], preprocessor: dict[str, Any] | None = None
    ) -> ImageGrid:
        """The grid of a checkpoint's ``config.json`` and ``preprocessor_config.json`` (read
        without transformers; no preprocessor config: Qwen3-VL's normalisation)."""
        v, pre = config["vision_config"], preprocessor or {}
        return cls(int(v["patch_size"]), int(v["spatial_merge_size"]),
                   int(v["temporal_patch_size"]), pre.get("image_mean") or QWEN3_MEAN,
                   pre.get("image_std") or QWEN3_STD)  # fmt: skip

    @property
    def thw(self) -> tuple[int, int, int]:
        """``image_grid_thw`` of the one image: (frames, patch rows, patch columns)."""
        per_side = self.side // self.patch
        return (1, per_side, per_side)

    @property
    def side(self) -> int:
        return image_side(self.patch, self.merge, self.per_side)

    @property
    def token_px(self) -> int:
        """Pixels per merged visual token side."""
        return self.patch * self.merge

    @property
    def tokens(self) -> int:
        return visual_tokens(self.side, self.patch, self.merge)

    def pixels(self, images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:func:`.image.patchify` of (B, side, side) uint8 images with this grid's geometry and
        normalisation: ``pixel_values`` and ``image_grid_thw``."""
        return patchify(images, self.patch, self.merge, self.temporal, self.mean, self.std)


#: Qwen3-VL's grid (the tiny models' too); :meth:`ImageGrid.of` reads a model's own.
QWEN3_GRID = ImageGrid()


@dataclass(frozen=True, slots=True)
class Encoded:
    """One state as token ids, the token ending each listed line, and the label (-1: none)."""

    ids: np.ndarray  # int64 (T,)
    ends: np.ndarray  # int64 (K,)
    starts: np.ndarray  # int64 (K,): the token holding each listed line's first character
    label: int
    #: The answer's tokens (free-JSON answers only; empty for the index answer, which is scored
    #: by the pointer) and the answer field each one belongs to.
    answer_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    answer_fields: tuple[str, ...] = ()
    #: The teacher's preference over the listed lines (float32, sums to 1); empty: the label.
    soft: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.float32))
    #: The heightmap image (uint8 (side, side), :mod:`.image`) with its grid; None: text only.
    image: np.ndarray | None = None
    grid: ImageGrid | None = None
    image_token: int = -1  # the id of <|image_pad|> (the visual tokens' places)
    #: Each listed line's numeric vector (float32 (K, LINE_VECTOR_SIZE),
    #: :mod:`packlab.policies.line_vector`); empty: the head reads the hidden states alone.
    vectors: np.ndarray = field(
        default_factory=lambda: np.zeros((0, LINE_VECTOR_SIZE), dtype=np.float32)
    )
    #: Which visual tokens lie under each listed line's footprint (bool (K, visual tokens),
    #: :func:`footprints`); empty: the head does not pool the image.
    footprint: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))
    #: Which visual tokens form the one-token ring around each listed line's footprint (bool
    #: (K, visual tokens), :func:`rings`); empty: the head reads no context.
    ring: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))


def prompt_text(tokenizer: Any, messages: list[dict[str, Any]]) -> str:
    return tokenizer.apply_chat_template(messages, tokenize=False, add_generation_prompt=True)


def line_chars(text: str, lines: Sequence[str]) -> tuple[list[int], list[int]]:
    """(first, last) character index of each line, found in order after the user turn's
    ``Places:`` header (so a map row can never be taken for a placement)."""
    pos = text.rindex("Places:")
    firsts, lasts = [], []
    for line in lines:
        pos = text.index("\n" + line, pos) + 1
        firsts.append(pos)
        lasts.append(pos + len(line) - 1)
    return firsts, lasts


_KEY = re.compile(r'"(\w+)"\s*:')


def answer_tokens(tokenizer: Any, text: str) -> tuple[np.ndarray, tuple[str, ...]]:
    """Token ids of an answer followed by the end-of-turn token, and for each token the JSON key
    whose value it writes (``"syntax"`` for braces, keys and separators, ``"end"`` for the
    end-of-turn token), for per-field NLL."""
    enc = tokenizer(text, add_special_tokens=False, return_offsets_mapping=True)
    fields = []
    for a, b in enc["offset_mapping"]:
        keys = _KEY.findall(text[:a])
        is_value = bool(keys) and text[a:b].strip().lstrip("-").isdigit()
        fields.append(keys[-1] if is_value and keys[-1] in ACTION_KEYS else "syntax")
    ids = [*enc["input_ids"], tokenizer.convert_tokens_to_ids(IM_END)]
    return np.asarray(ids, dtype=np.int64), (*fields, "end")


def _encode_text(
    tokenizer: Any,
    text: str,
    listed: Sequence[Candidate],
    label: int,
    line_fields: LineFields = "full",
) -> Encoded:
    """Token ids of a prompt text and the tokens holding each listed line's first and last
    character."""
    enc = tokenizer(text, add_special_tokens=False, return_offsets_mapping=True)
    owner = np.full(len(text), -1, dtype=np.int64)
    for t, (a, b) in enumerate(enc["offset_mapping"]):
        owner[a:b] = t
    firsts, lasts = line_chars(text, [line_text(c, line_fields) for c in listed])
    ends = owner[np.array(lasts, dtype=np.int64)]
    starts = owner[np.array(firsts, dtype=np.int64)]
    if (ends < 0).any() or (starts < 0).any():
        raise ValueError("a placement line has no token")
    return Encoded(np.asarray(enc["input_ids"], dtype=np.int64), ends, starts, label)


def _encode_prompt(
    tokenizer: Any,
    messages: list[dict[str, Any]],
    listed: Sequence[Candidate],
    label: int,
    image: np.ndarray | None,
    grid: ImageGrid,
    line_fields: LineFields = "full",
) -> Encoded:
    """:func:`_encode_text` of the messages' prompt; with an image, its one ``<|image_pad|>``
    repeated once per merged visual token first."""
    text = prompt_text(tokenizer, messages)
    if image is None:
        return _encode_text(tokenizer, text, listed, label, line_fields)
    if text.count(IMAGE_PAD) != 1:
        raise ValueError(f"expected one image placeholder, found {text.count(IMAGE_PAD)}")
    text = text.replace(IMAGE_PAD, IMAGE_PAD * grid.tokens)
    enc = _encode_text(tokenizer, text, listed, label, line_fields)
    pad_id = int(tokenizer.convert_tokens_to_ids(IMAGE_PAD))
    pads = int((enc.ids == pad_id).sum())
    if pads != grid.tokens:
        raise ValueError(f"{pads} image tokens for an image of {grid.tokens} (split pads?)")
    return replace(enc, image=image, grid=grid, image_token=pad_id)


def map_image(
    observation: Observation, map: PointerMap, grid: ImageGrid, blank_map: bool = False
) -> np.ndarray | None:
    """The image a step shows (:mod:`.image`), or None for the text map only."""
    if map not in IMAGE_MAPS:
        return None
    if map == "blank":
        return blank_image(grid.side)
    hm = np.zeros_like(observation.heightmap) if blank_map else observation.heightmap
    return heightmap_image(hm, observation.container, grid.side)


def soft_of(state: LabelledState) -> np.ndarray:
    """The state's soft target (empty: one-hot at its label); ``getattr`` so that states of a
    packlab without the field still encode."""
    return np.asarray(getattr(state, "soft", ()), dtype=np.float32)


def footprints(
    observation: Observation, listed: Sequence[Candidate], grid: ImageGrid
) -> np.ndarray:
    """bool (K, visual tokens): the merged visual tokens under each listed line's footprint
    (:func:`.image.footprint_tokens`): its cell and its box's size at its rotation, both named
    by the line, placed on the image's layout; no height of the container is read."""
    out = np.zeros((len(listed), grid.tokens), dtype=bool)
    cells = tuple(observation.heightmap.shape)
    for n, c in enumerate(listed):
        out[n, footprint_tokens(cells, c.x, c.y, c.fx, c.fy, grid.side, grid.token_px)] = True
    return out


def rings(observation: Observation, listed: Sequence[Candidate], grid: ImageGrid) -> np.ndarray:
    """bool (K, visual tokens): the one-token ring around each listed line's footprint
    (:func:`.image.ring_tokens`), from the same line fields and layout as :func:`footprints`;
    no height of the container is read."""
    out = np.zeros((len(listed), grid.tokens), dtype=bool)
    cells = tuple(observation.heightmap.shape)
    for n, c in enumerate(listed):
        out[n, ring_tokens(cells, c.x, c.y, c.fx, c.fy, grid.side, grid.token_px)] = True
    return out


@dataclass(frozen=True, slots=True)
class Extras:
    """What :func:`encode` adds beside the prompt: line vectors, the lines' fields and the
    footprints on the image (``footprint`` needs an image ``map``; ``context`` adds the rings
    around them)."""

    lines: bool = False
    line_fields: LineFields = "full"
    footprint: bool = False
    context: bool = False

    @classmethod
    def of(cls, settings: PromptSettings) -> Extras:
        return cls(settings.line_vectors, settings.line_fields, settings.footprint_pool,
                   settings.footprint_pool and settings.footprint_context)  # fmt: skip


NO_EXTRAS = Extras()


def _with_extras(
    enc: Encoded, observation: Observation, listed: Sequence[Candidate], extras: Extras
) -> Encoded:
    if extras.lines:
        enc = replace(enc, vectors=line_vectors(observation, listed))
    if extras.footprint:
        grid = enc.grid
        if grid is None:
            raise ValueError("footprint pooling needs an image map")
        enc = replace(enc, footprint=footprints(observation, listed, grid))
        if extras.context:
            enc = replace(enc, ring=rings(observation, listed, grid))
    return enc


def encode(
    tokenizer: Any,
    state: LabelledState,
    instructions: Instructions,
    blank_map: bool = False,
    answer: Answer = "index",
    map: PointerMap = "text",
    grid: ImageGrid = QWEN3_GRID,
    lines: bool = False,
    extras: Extras | None = None,
) -> Encoded:
    """Tokens of a state's prompt (the same text as the export for ``map`` = text), its listed
    lines' ends, its soft target, (``map`` with an image) its heightmap image and (``lines``)
    each listed line's numeric vector; ``extras``, when given, replaces ``lines`` and adds the
    lines' fields and footprints (:class:`Extras`)."""
    extras = Extras(lines=lines) if extras is None else extras
    messages = state_messages(state, instructions, blank_map=blank_map, map=map,
                              line_fields=extras.line_fields)  # fmt: skip
    observation, listed = observation_of(state), listed_of(state)
    image = map_image(observation, map, grid, blank_map)
    try:
        enc = _encode_prompt(tokenizer, messages, listed, state.label, image, grid,
                             extras.line_fields)  # fmt: skip
        enc = _with_extras(enc, observation, listed, extras)
    except ValueError as exc:
        raise ValueError(f"{state.case_id} step {state.step}: {exc}") from None
    enc = replace(enc, soft=soft_of(state))
    if answer == "json" and state.label >= 0:
        answer_ids, fields = answer_tokens(tokenizer, answer_text(state, "json"))
        return replace(enc, answer_ids=answer_ids, answer_fields=fields)
    return enc


def encode_observation(
    tokenizer: Any,
    observation: Observation,
    listed: Sequence[Candidate],
    instructions: Instructions,
    blank_map: bool = False,
    map: PointerMap = "text",
    grid: ImageGrid = QWEN3_GRID,
    lines: bool = False,
    extras: Extras | None = None,
) -> Encoded:
    """:func:`encode` of a live step (inference): the same prompt, unlabelled."""
    extras = Extras(lines=lines) if extras is None else extras
    messages = observation_messages(observation, listed, instructions, blank_map=blank_map,
                                    map=map, line_fields=extras.line_fields)  # fmt: skip
    image = map_image(observation, map, grid, blank_map)
    enc = _encode_prompt(tokenizer, messages, listed, -1, image, grid, extras.line_fields)
    return _with_extras(enc, observation, listed, extras)


def settings_grid(grid: ImageGrid, settings: PromptSettings) -> ImageGrid:
    """A model's grid with the tokens per side its settings name (a model in training has no
    card yet: its settings carry them)."""
    return replace(grid, per_side=settings.image_tokens)


def encode_settings(
    tokenizer: Any,
    observation: Observation,
    listed: Sequence[Candidate],
    settings: PromptSettings,
    grid: ImageGrid,
) -> Encoded:
    """:func:`encode_observation` under a model card's settings (both runtimes)."""
    return encode_observation(
        tokenizer, observation, listed, settings.instructions, settings.blank_map, settings.map,
        settings_grid(grid, settings), extras=Extras.of(settings),
    )  # fmt: skip
