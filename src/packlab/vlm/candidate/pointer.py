"""The pointer model: a Qwen-VL-family language model that scores the listed placements.

The state's text (:mod:`.compose`) runs through the model once; each listed placement's line
ends on a token whose last hidden state has read the whole context up to and including that
line. With the digit text map only (``map`` = text) the text stack alone runs; with an image
(``map`` = image, both, blank) the prompt's ``<|image_pad|>`` is repeated once per merged visual
token (:mod:`.image`) and the whole Qwen-VL model runs: its vision tower encodes the heightmap
image, the visual tokens take the pads' places, and M-RoPE gives them 2-D positions. A linear
head maps each listed line's state to a score, and the pick is the highest score over the
listed lines (a softmax over them in training, against the teacher's soft targets when a state
has them, :func:`soft_loss`). The answer is therefore
always one of the listed placements: nothing is decoded that could fail to parse or to fit.

Why not train the index digit as a generated answer: from random weights, the loss on the digit
alone stays at chance for hundreds of steps (issue 12's prototype), while the pointer loss reads
each placement's own hidden state and learns within minutes.
Imports torch: only the vlm extra may import this module.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch
from torch import nn

from packlab.core.choices import PointerMap
from packlab.core.types import Observation
from packlab.policies.candidates import Candidate
from packlab.policies.line_vector import LINE_VECTOR_SIZE, line_vectors
from packlab.vlm.candidate.compose import (
    IMAGE_MAPS,
    Answer,
    Instructions,
    answer_text,
    observation_messages,
    state_messages,
)
from packlab.vlm.candidate.image import (
    blank_image,
    heightmap_image,
    image_side,
    patchify,
    visual_tokens,
)
from packlab.vlm.candidate.states import LabelledState, listed_of, observation_of
from packlab.vlm.model.checkpoint import VLM
from packlab.vlm.model.tokenizer import IM_END, IMAGE_PAD
from packlab.vlm.prompt.compact import candidate_line
from packlab.vlm.prompt.parse import ACTION_KEYS


@dataclass(frozen=True, slots=True)
class ImageGrid:
    """A vision tower's patch geometry (from its config): pixels per patch side, patches per
    merged token side, frames per patch."""

    patch: int = 16
    merge: int = 2
    temporal: int = 2

    @classmethod
    def of(cls, vlm: VLM) -> ImageGrid:
        v = vlm.model.config.vision_config
        return cls(int(v.patch_size), int(v.spatial_merge_size), int(v.temporal_patch_size))

    @property
    def side(self) -> int:
        return image_side(self.patch, self.merge)

    @property
    def tokens(self) -> int:
        return visual_tokens(self.side, self.patch, self.merge)


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


def _encode_text(tokenizer: Any, text: str, listed: Sequence[Candidate], label: int) -> Encoded:
    """Token ids of a prompt text and the tokens holding each listed line's first and last
    character."""
    enc = tokenizer(text, add_special_tokens=False, return_offsets_mapping=True)
    owner = np.full(len(text), -1, dtype=np.int64)
    for t, (a, b) in enumerate(enc["offset_mapping"]):
        owner[a:b] = t
    firsts, lasts = line_chars(text, [candidate_line(c) for c in listed])
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
) -> Encoded:
    """:func:`_encode_text` of the messages' prompt; with an image, its one ``<|image_pad|>``
    repeated once per merged visual token first."""
    text = prompt_text(tokenizer, messages)
    if image is None:
        return _encode_text(tokenizer, text, listed, label)
    if text.count(IMAGE_PAD) != 1:
        raise ValueError(f"expected one image placeholder, found {text.count(IMAGE_PAD)}")
    enc = _encode_text(tokenizer, text.replace(IMAGE_PAD, IMAGE_PAD * grid.tokens), listed, label)
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


def encode(
    tokenizer: Any,
    state: LabelledState,
    instructions: Instructions,
    blank_map: bool = False,
    answer: Answer = "index",
    map: PointerMap = "text",
    grid: ImageGrid = QWEN3_GRID,
    lines: bool = False,
) -> Encoded:
    """Tokens of a state's prompt (the same text as the export for ``map`` = text), its listed
    lines' ends, its soft target, (``map`` with an image) its heightmap image and (``lines``)
    each listed line's numeric vector."""
    messages = state_messages(state, instructions, blank_map=blank_map, map=map)
    observation, listed = observation_of(state), listed_of(state)
    image = map_image(observation, map, grid, blank_map)
    try:
        enc = _encode_prompt(tokenizer, messages, listed, state.label, image, grid)
    except ValueError as exc:
        raise ValueError(f"{state.case_id} step {state.step}: {exc}") from None
    enc = replace(enc, soft=soft_of(state))
    if lines:
        enc = replace(enc, vectors=line_vectors(observation, listed))
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
) -> Encoded:
    """:func:`encode` of a live step (inference): the same prompt, unlabelled."""
    messages = observation_messages(observation, listed, instructions, blank_map=blank_map,
                                    map=map)  # fmt: skip
    image = map_image(observation, map, grid, blank_map)
    enc = _encode_prompt(tokenizer, messages, listed, -1, image, grid)
    return replace(enc, vectors=line_vectors(observation, listed)) if lines else enc


def text_stack(vlm: VLM) -> nn.Module:
    """The language model inside a Qwen-VL-family model."""
    return vlm.model.model.language_model


#: Hidden width of :class:`LineHead` (the probe that chose the line vector's columns used 128).
LINE_HEAD_WIDTH = 128
#: How a listed line becomes one vector: its last token's hidden state, or the mean over its
#: tokens (every field's own state reaches the head in one step).
POOLS = ("last", "mean")
#: :func:`collate`'s image inputs, passed on to the Qwen-VL model as they are.
IMAGE_KEYS = ("pixel_values", "image_grid_thw", "mm_token_type_ids")


def _gather(hidden: torch.Tensor, at: torch.Tensor) -> torch.Tensor:
    return hidden.gather(1, at.unsqueeze(-1).expand(-1, -1, hidden.shape[-1]))


class LineHead(nn.Module):
    """The pointer head of a model that reads line vectors: an MLP over each line's pooled
    hidden state, its numeric vector and the mean vector of the listed lines (what the others
    offer), so a line's score can depend on how it compares with the rest of the list."""

    def __init__(self, hidden_size: int, width: int = LINE_HEAD_WIDTH) -> None:
        super().__init__()
        self.mlp = nn.Sequential(
            nn.Linear(hidden_size + 2 * LINE_VECTOR_SIZE, width),
            nn.ReLU(),
            nn.Linear(width, width),
            nn.ReLU(),
            nn.Linear(width, 1),
        )

    def forward(
        self, picked: torch.Tensor, vectors: torch.Tensor, valid: torch.Tensor
    ) -> torch.Tensor:
        weights = valid.unsqueeze(-1).float()
        mean = (vectors * weights).sum(1, keepdim=True) / weights.sum(1, keepdim=True).clamp(min=1)
        return self.mlp(torch.cat([picked, vectors, mean.expand_as(vectors)], -1))


class PointerModel(nn.Module):
    """``scores = head(pooled hidden states of each listed line)``, -inf where padded; with
    ``lines`` the head also reads each line's numeric vector (:class:`LineHead`)."""

    def __init__(
        self, vlm: VLM, pool: str = "last", map: PointerMap = "text", lines: bool = False
    ) -> None:
        super().__init__()
        if pool not in POOLS:
            raise ValueError(f"pool = {pool!r}: expected one of {POOLS}")
        self.vlm = vlm
        self.pool = pool
        self.text = text_stack(vlm)
        if map in IMAGE_MAPS:
            # A submodule, so that the optimizer trains it and checkpoints hold it (``vlm`` is
            # not a module); text-map models leave it out and keep their state dict's keys.
            self.visual = vlm.model.model.visual
        self.lines = lines
        hidden_size = self.text.config.hidden_size
        self.head = LineHead(hidden_size) if lines else nn.Linear(hidden_size, 1)

    def hidden(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """Last hidden states (B, T, H): the text stack alone for text-only batches, the whole
        Qwen-VL model (vision tower, visual tokens in place of the pads, M-RoPE) with images."""
        ids, mask = batch["ids"], batch["mask"]
        if "pixel_values" not in batch:
            return self.text(input_ids=ids, attention_mask=mask).last_hidden_state
        images = {k: batch[k] for k in IMAGE_KEYS}
        return self.vlm.model.model(input_ids=ids, attention_mask=mask, **images).last_hidden_state

    def forward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        hidden = self.hidden(batch)
        ends, starts, valid = batch["ends"], batch["starts"], batch["valid"]
        if self.pool == "mean":
            # Sum over [start, end] from a running sum: sum(0..end) - sum(0..start-1).
            total = torch.cumsum(hidden, dim=1)
            before = _gather(total, (starts - 1).clamp(min=0)) * (starts > 0).unsqueeze(-1)
            picked = (_gather(total, ends) - before) / (ends - starts + 1).unsqueeze(-1)
        else:
            picked = _gather(hidden, ends)
        if self.lines:
            scores = self.head(picked, batch["vectors"], valid)
        else:
            scores = self.head(picked)
        return scores.squeeze(-1).masked_fill(~valid, float("-inf"))

    def answer_nll(self, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-token NLL of the free-JSON answers (B, T-1; 0 outside them) and whether the greedy
        token is the target (True outside them): the language model's own head reads the hidden
        state before each answer token (teacher forcing)."""
        hidden = self.hidden(batch)
        logits = self.vlm.model.lm_head(hidden[:, :-1]).float()
        target = batch["answer"][:, 1:]
        nll = torch.nn.functional.cross_entropy(
            logits.transpose(1, 2), target.clamp(min=0), reduction="none"
        )
        return nll * (target >= 0), (logits.argmax(-1) == target) | (target < 0)

    def score(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """Scores of a :func:`collate` batch."""
        return self(batch)


def soft_loss(scores: torch.Tensor, targets: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Mean cross-entropy of the scores' softmax over the listed lines against target
    distributions (B, K): ``-(target * log_softmax(scores)).sum()``; padded lines (-inf scores,
    target 0) add nothing. Equals ``cross_entropy(scores, labels)`` for one-hot targets."""
    logp = torch.log_softmax(scores, dim=-1).masked_fill(~valid, 0.0)
    return -(targets * logp).sum(-1).mean()


def _targets(batch: Sequence[Encoded], k: int) -> torch.Tensor:
    """(B, K) target distributions: the soft target when a state has one, else one-hot at its
    label (all zeros for an unlabelled state)."""
    out = torch.zeros((len(batch), k), dtype=torch.float32)
    for n, e in enumerate(batch):
        if len(e.soft):
            out[n, : len(e.soft)] = torch.from_numpy(e.soft)
        elif e.label >= 0:
            out[n, e.label] = 1.0
    return out


def _images(batch: Sequence[Encoded], ids: torch.Tensor, mask: torch.Tensor) -> dict:
    """The Qwen-VL image inputs of a batch whose states all show an image (else none)."""
    shown = [e.image is not None for e in batch]
    if not any(shown):
        return {}
    grid = batch[0].grid
    if not all(shown) or any(e.grid != grid for e in batch) or grid is None:
        raise ValueError("a batch mixes states with and without (or with different) images")
    images = np.stack([e.image for e in batch])  # type: ignore[misc]
    pixels, thw = patchify(images, grid.patch, grid.merge, grid.temporal)
    pads = torch.zeros_like(ids)
    for n, e in enumerate(batch):
        pads[n, : len(e.ids)] = torch.from_numpy(e.ids == e.image_token)
    return {"pixel_values": torch.from_numpy(pixels), "image_grid_thw": torch.from_numpy(thw),
            "mm_token_type_ids": pads * mask}  # fmt: skip


def collate(batch: Sequence[Encoded], pad_id: int) -> dict[str, torch.Tensor]:
    """Right-padded tensors for :meth:`PointerModel.forward` plus ``labels`` and ``targets``
    (B, K; :func:`soft_loss`), and the image inputs when the states show an image."""
    t = max(len(e.ids) + len(e.answer_ids) for e in batch)
    k = max(len(e.ends) for e in batch)
    ids = torch.full((len(batch), t), pad_id, dtype=torch.long)
    mask = torch.zeros((len(batch), t), dtype=torch.long)
    ends = torch.zeros((len(batch), k), dtype=torch.long)
    starts = torch.zeros((len(batch), k), dtype=torch.long)
    valid = torch.zeros((len(batch), k), dtype=torch.bool)
    answer = torch.full((len(batch), t), -1, dtype=torch.long)
    for n, e in enumerate(batch):
        whole = np.concatenate([e.ids, e.answer_ids])
        ids[n, : len(whole)] = torch.from_numpy(whole)
        mask[n, : len(whole)] = 1
        answer[n, len(e.ids) : len(whole)] = torch.from_numpy(e.answer_ids)
        ends[n, : len(e.ends)] = torch.from_numpy(e.ends)
        starts[n, : len(e.ends)] = torch.from_numpy(e.starts)
        valid[n, : len(e.ends)] = True
    labels = torch.tensor([e.label for e in batch], dtype=torch.long)
    return {
        "ids": ids, "mask": mask, "ends": ends, "starts": starts, "valid": valid,
        "labels": labels, "targets": _targets(batch, k), "answer": answer,
        **_images(batch, ids, mask), **_vectors(batch, k),
    }  # fmt: skip


def _vectors(batch: Sequence[Encoded], k: int) -> dict[str, torch.Tensor]:
    """``vectors`` (B, K, LINE_VECTOR_SIZE), zero-padded, when the states carry line vectors."""
    if not any(len(e.vectors) for e in batch):
        return {}
    out = torch.zeros((len(batch), k, LINE_VECTOR_SIZE), dtype=torch.float32)
    for n, e in enumerate(batch):
        out[n, : len(e.vectors)] = torch.from_numpy(e.vectors)
    return {"vectors": out}
