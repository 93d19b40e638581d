"""The pointer model: a Qwen-VL-family language model that scores the listed placements.

The state's text (:mod:`.compose`) runs through the model's text stack once; each listed
placement's line ends on a token whose last hidden state has read the whole context up to and
including that line. A linear head maps each of those states to a score, and the pick is the
highest score over the listed lines (a softmax over them in training). The answer is therefore
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

from packlab.core.types import Observation
from packlab.policies.candidates import Candidate
from packlab.vlm.candidate.compose import (
    Answer,
    Instructions,
    answer_text,
    observation_messages,
    state_messages,
)
from packlab.vlm.candidate.states import LabelledState, listed_of
from packlab.vlm.model.checkpoint import VLM
from packlab.vlm.model.tokenizer import IM_END
from packlab.vlm.prompt.compact import candidate_line
from packlab.vlm.prompt.parse import ACTION_KEYS


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


def encode(
    tokenizer: Any,
    state: LabelledState,
    instructions: Instructions,
    blank_map: bool = False,
    answer: Answer = "index",
) -> Encoded:
    """Tokens of a state's prompt (the same text as the export) and its listed lines' ends."""
    text = prompt_text(tokenizer, state_messages(state, instructions, blank_map=blank_map))
    try:
        enc = _encode_text(tokenizer, text, listed_of(state), state.label)
    except ValueError as exc:
        raise ValueError(f"{state.case_id} step {state.step}: {exc}") from None
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
) -> Encoded:
    """:func:`encode` of a live step (inference): the same text, unlabelled."""
    messages = observation_messages(observation, listed, instructions, blank_map=blank_map)
    return _encode_text(tokenizer, prompt_text(tokenizer, messages), listed, -1)


def text_stack(vlm: VLM) -> nn.Module:
    """The language model inside a Qwen-VL-family model (its vision tower is not used)."""
    return vlm.model.model.language_model


#: How a listed line becomes one vector: its last token's hidden state, or the mean over its
#: tokens (every field's own state reaches the head in one step).
POOLS = ("last", "mean")


def _gather(hidden: torch.Tensor, at: torch.Tensor) -> torch.Tensor:
    return hidden.gather(1, at.unsqueeze(-1).expand(-1, -1, hidden.shape[-1]))


class PointerModel(nn.Module):
    """``scores = head(pooled hidden states of each listed line)``, -inf where padded."""

    def __init__(self, vlm: VLM, pool: str = "last") -> None:
        super().__init__()
        if pool not in POOLS:
            raise ValueError(f"pool = {pool!r}: expected one of {POOLS}")
        self.vlm = vlm
        self.pool = pool
        self.text = text_stack(vlm)
        self.head = nn.Linear(self.text.config.hidden_size, 1)

    def forward(self, ids, mask, ends, valid, starts=None) -> torch.Tensor:
        hidden = self.text(input_ids=ids, attention_mask=mask).last_hidden_state
        if self.pool == "mean":
            # Sum over [start, end] from a running sum: sum(0..end) - sum(0..start-1).
            total = torch.cumsum(hidden, dim=1)
            before = _gather(total, (starts - 1).clamp(min=0)) * (starts > 0).unsqueeze(-1)
            picked = (_gather(total, ends) - before) / (ends - starts + 1).unsqueeze(-1)
        else:
            picked = _gather(hidden, ends)
        return self.head(picked).squeeze(-1).masked_fill(~valid, float("-inf"))

    def answer_nll(self, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-token NLL of the free-JSON answers (B, T-1; 0 outside them) and whether the greedy
        token is the target (True outside them): the language model's own head reads the hidden
        state before each answer token (teacher forcing)."""
        hidden = self.text(input_ids=batch["ids"], attention_mask=batch["mask"]).last_hidden_state
        logits = self.vlm.model.lm_head(hidden[:, :-1]).float()
        target = batch["answer"][:, 1:]
        nll = torch.nn.functional.cross_entropy(
            logits.transpose(1, 2), target.clamp(min=0), reduction="none"
        )
        return nll * (target >= 0), (logits.argmax(-1) == target) | (target < 0)

    def score(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """Scores of a :func:`collate` batch."""
        return self(batch["ids"], batch["mask"], batch["ends"], batch["valid"], batch["starts"])


def collate(batch: Sequence[Encoded], pad_id: int) -> dict[str, torch.Tensor]:
    """Right-padded tensors for :meth:`PointerModel.forward` plus ``labels``."""
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
        "labels": labels, "answer": answer,
    }  # fmt: skip
