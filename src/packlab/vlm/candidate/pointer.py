"""The pointer model: a Qwen-VL-family language model that scores the listed placements.

The state's text (:mod:`.compose`, encoded by :mod:`.encoding`) runs through the model once;
each listed placement's line ends on a token whose last hidden state has read the whole context
up to and including that line. With the digit text map only (``map`` = text) the text stack
alone runs; with an image (``map`` = image, both, blank) the prompt's ``<|image_pad|>`` is
repeated once per merged visual token (:mod:`.image`) and the whole Qwen-VL model runs: its
vision tower encodes the heightmap image, the visual tokens take the pads' places, and M-RoPE
gives them 2-D positions. A linear head maps each listed line's state to a score, and the pick
is the highest score over the listed lines (a softmax over them in training, against the
teacher's soft targets when a state has them, :func:`soft_loss`). The answer is therefore
always one of the listed placements: nothing is decoded that could fail to parse or to fit.
The same model also plays as ONNX graphs without torch (:mod:`.onnx_graphs`), except with
footprint pooling (``footprint``), which plays under torch only.

**Footprint pooling** (``footprint``, ``packlab train candidate --footprint-pool``): for each
listed line the last hidden states of the visual tokens that lie under its footprint are
mean-pooled and joined to the line's own state before the head (:class:`LineHead`, an MLP, so
the two can interact). This is learned reading of the image, not hand geometry: which tokens
are pooled follows only from what the line itself names (its cell, and its box's size at its
rotation, from the ``Boxes`` line) and from where the image draws each cell; nothing of the
container's surface (heights, support, gaps, flushness) is computed. What those tokens hold is
whatever the vision tower and the decoder learned to put there from the pixels, and a blank
image gives the same pooling over tokens that carry no surface. It only lets a line's score
look at its own part of the image in one step, instead of having to learn to attend there.

**Footprint context** (``context``, ``packlab train candidate --footprint-context``, with
footprint pooling): the head also reads the max of the same tokens' states (so the network can
form the resting level, the highest point under the box, itself) and the mean over the
one-token ring around the footprint (the neighbouring columns and walls a box there would be
flush with; :func:`.image.ring_tokens`). Both are chosen the same way as the footprint's
tokens, from the line's own fields and the image's layout, never from a height
(:func:`footprint_context_pool`).

Why not train the index digit as a generated answer: from random weights, the loss on the digit
alone stays at chance for hundreds of steps (measured on a prototype), while the pointer loss reads
each placement's own hidden state and learns within minutes.
Imports torch: only the vlm extra may import this module.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from packlab.core.choices import PointerMap
from packlab.policies.line_vector import LINE_VECTOR_SIZE
from packlab.vlm.candidate.compose import IMAGE_MAPS
from packlab.vlm.candidate.encoding import (  # noqa: F401 (the encoding's names, as before)
    QWEN3_GRID,
    Encoded,
    ImageGrid,
    answer_tokens,
    encode,
    encode_observation,
    line_chars,
    map_image,
    prompt_text,
    soft_of,
)
from packlab.vlm.model.checkpoint import VLM


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
    offer), so a line's score can depend on how it compares with the rest of the list.
    ``vector_size`` 0: an MLP over the line's state alone (footprint pooling without line
    vectors)."""

    def __init__(
        self, hidden_size: int, width: int = LINE_HEAD_WIDTH, vector_size: int = LINE_VECTOR_SIZE
    ) -> None:
        super().__init__()
        self.mlp = nn.Sequential(
            nn.Linear(hidden_size + 2 * vector_size, width),
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
    ``lines`` the head also reads each line's numeric vector (:class:`LineHead`); with
    ``footprint`` it also reads the mean final state of the visual tokens under each line's
    footprint, and with ``context`` their max and the mean over the ring around them (module
    docstring; an image ``map`` only)."""

    def __init__(
        self,
        vlm: VLM,
        pool: str = "last",
        map: PointerMap = "text",
        lines: bool = False,
        footprint: bool = False,
        context: bool = False,
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
        if footprint and map not in IMAGE_MAPS:
            raise ValueError(f"footprint pooling needs an image map, not map = {map!r}")
        if context and not footprint:
            raise ValueError("footprint context needs footprint pooling (footprint = True)")
        self.lines = lines
        self.footprint = footprint
        self.context = context
        hidden_size = self.text.config.hidden_size
        self.head: nn.Module
        if footprint:
            vector_size = LINE_VECTOR_SIZE if lines else 0
            # The line's state, the footprint's mean, and (context) its max and the ring's mean.
            parts = 4 if context else 2
            self.head = LineHead(parts * hidden_size, vector_size=vector_size)
        else:
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
        if self.context:
            picked = torch.cat([picked, footprint_context_pool(hidden, batch)], -1)
        elif self.footprint:
            picked = torch.cat([picked, footprint_pool(hidden, batch)], -1)
        if isinstance(self.head, LineHead):
            vectors = batch["vectors"] if self.lines else picked[..., :0]
            scores = self.head(picked, vectors, valid)
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

    @property
    def device(self) -> torch.device:
        """Where the parameters are (the batches go there: :func:`to_device`)."""
        return next(self.parameters()).device


def footprint_pool(hidden: torch.Tensor, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """(B, K, H): for each listed line, the mean of the hidden states (B, T, H) of the visual
    tokens its footprint covers (``footprint`` (B, K, V) 0/1 over the V visual tokens, whose
    positions in the sequence are ``visual_at`` (B, V)); zeros for a line that covers none."""
    if "footprint" not in batch:
        raise ValueError("a footprint-pooling model needs states encoded with their footprints")
    visual = _gather(hidden, batch["visual_at"])  # (B, V, H)
    weights = batch["footprint"].to(visual.dtype)
    return torch.bmm(weights, visual) / weights.sum(-1, keepdim=True).clamp(min=1)


def footprint_context_pool(hidden: torch.Tensor, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """(B, K, 3H): for each listed line, [the mean (:func:`footprint_pool`), the elementwise
    max of the hidden states of the visual tokens its footprint covers, the mean over the
    tokens of its ring (``ring`` (B, K, V) 0/1)]; zeros where a line covers no token or its
    ring is empty (a footprint over the whole image, or a padded line)."""
    if "ring" not in batch:
        raise ValueError("a footprint-context model needs states encoded with their rings")
    visual = _gather(hidden, batch["visual_at"])  # (B, V, H)
    under = batch["footprint"] > 0  # (B, K, V)
    mean = footprint_pool(hidden, batch)
    filled = visual.unsqueeze(1).masked_fill(~under.unsqueeze(-1), float("-inf"))  # (B,K,V,H)
    top = filled.amax(2)
    top = torch.where(under.any(-1, keepdim=True), top, torch.zeros_like(top))
    ring = batch["ring"].to(visual.dtype)
    around = torch.bmm(ring, visual) / ring.sum(-1, keepdim=True).clamp(min=1)
    return torch.cat([mean, top, around], -1)


def to_device(batch: dict[str, torch.Tensor], device: torch.device | str) -> dict:
    """A :func:`collate` batch on ``device`` (collate builds it on the CPU)."""
    return {k: v.to(device) for k, v in batch.items()}


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
    pixels, thw = grid.pixels(images)
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
        **_images(batch, ids, mask), **_vectors(batch, k), **_footprints(batch, k),
    }  # fmt: skip


def _footprints(batch: Sequence[Encoded], k: int) -> dict[str, torch.Tensor]:
    """``footprint`` (B, K, V) 0/1 and ``visual_at`` (B, V), the positions of each state's V
    visual tokens, when the states carry footprints (:func:`footprint_pool`)."""
    if not any(e.footprint.size for e in batch):
        return {}
    v = batch[0].footprint.shape[1]
    out = torch.zeros((len(batch), k, v), dtype=torch.float32)
    at = torch.zeros((len(batch), v), dtype=torch.long)
    rings = any(e.ring.size for e in batch)
    ring = torch.zeros((len(batch), k, v), dtype=torch.float32)
    for n, e in enumerate(batch):
        places = np.flatnonzero(e.ids == e.image_token)
        if e.footprint.shape[1] != v or len(places) != v:
            raise ValueError(f"footprints over {e.footprint.shape[1]} tokens, {len(places)} shown")
        out[n, : len(e.footprint)] = torch.from_numpy(e.footprint.astype(np.float32))
        at[n] = torch.from_numpy(places)
        if rings:
            if e.ring.shape != e.footprint.shape:
                raise ValueError(f"rings {e.ring.shape} for footprints {e.footprint.shape}")
            ring[n, : len(e.ring)] = torch.from_numpy(e.ring.astype(np.float32))
    return {"footprint": out, "visual_at": at, **({"ring": ring} if rings else {})}


def _vectors(batch: Sequence[Encoded], k: int) -> dict[str, torch.Tensor]:
    """``vectors`` (B, K, LINE_VECTOR_SIZE), zero-padded, when the states carry line vectors."""
    if not any(len(e.vectors) for e in batch):
        return {}
    out = torch.zeros((len(batch), k, LINE_VECTOR_SIZE), dtype=torch.float32)
    for n, e in enumerate(batch):
        out[n, : len(e.vectors)] = torch.from_numpy(e.vectors)
    return {"vectors": out}
