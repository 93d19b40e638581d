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

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from packlab.vlm.candidate.compose import Instructions, state_messages
from packlab.vlm.candidate.states import LabelledState, listed_of
from packlab.vlm.model.checkpoint import VLM
from packlab.vlm.prompt.compact import candidate_line


@dataclass(frozen=True, slots=True)
class Encoded:
    """One state as token ids, the token ending each listed line, and the label (-1: none)."""

    ids: np.ndarray  # int64 (T,)
    ends: np.ndarray  # int64 (K,)
    label: int


def prompt_text(tokenizer: Any, messages: list[dict[str, Any]]) -> str:
    return tokenizer.apply_chat_template(messages, tokenize=False, add_generation_prompt=True)


def line_end_chars(text: str, lines: Sequence[str]) -> list[int]:
    """The character index of the last character of each line, found in order after the user
    turn's ``Places:`` header (so a map row can never be taken for a placement)."""
    pos = text.rindex("Places:")
    out = []
    for line in lines:
        pos = text.index("\n" + line, pos) + 1
        out.append(pos + len(line) - 1)
    return out


def encode(
    tokenizer: Any, state: LabelledState, instructions: Instructions, blank_map: bool = False
) -> Encoded:
    """Tokens of a state's prompt (the same text as the export) and its listed lines' ends."""
    text = prompt_text(tokenizer, state_messages(state, instructions, blank_map=blank_map))
    enc = tokenizer(text, add_special_tokens=False, return_offsets_mapping=True)
    owner = np.full(len(text), -1, dtype=np.int64)
    for t, (a, b) in enumerate(enc["offset_mapping"]):
        owner[a:b] = t
    chars = line_end_chars(text, [candidate_line(c) for c in listed_of(state)])
    ends = owner[np.array(chars, dtype=np.int64)]
    if (ends < 0).any():
        raise ValueError(f"{state.case_id} step {state.step}: a placement line has no token")
    return Encoded(np.asarray(enc["input_ids"], dtype=np.int64), ends, state.label)


def text_stack(vlm: VLM) -> nn.Module:
    """The language model inside a Qwen-VL-family model (its vision tower is not used)."""
    return vlm.model.model.language_model


class PointerModel(nn.Module):
    """``scores = head(hidden state at each listed line's last token)``, -inf where padded."""

    def __init__(self, vlm: VLM) -> None:
        super().__init__()
        self.vlm = vlm
        self.text = text_stack(vlm)
        self.head = nn.Linear(self.text.config.hidden_size, 1)

    def forward(
        self, ids: torch.Tensor, mask: torch.Tensor, ends: torch.Tensor, valid: torch.Tensor
    ) -> torch.Tensor:
        hidden = self.text(input_ids=ids, attention_mask=mask).last_hidden_state
        picked = hidden.gather(1, ends.unsqueeze(-1).expand(-1, -1, hidden.shape[-1]))
        return self.head(picked).squeeze(-1).masked_fill(~valid, float("-inf"))


def collate(batch: Sequence[Encoded], pad_id: int) -> dict[str, torch.Tensor]:
    """Right-padded tensors for :meth:`PointerModel.forward` plus ``labels``."""
    t = max(len(e.ids) for e in batch)
    k = max(len(e.ends) for e in batch)
    ids = torch.full((len(batch), t), pad_id, dtype=torch.long)
    mask = torch.zeros((len(batch), t), dtype=torch.long)
    ends = torch.zeros((len(batch), k), dtype=torch.long)
    valid = torch.zeros((len(batch), k), dtype=torch.bool)
    for n, e in enumerate(batch):
        ids[n, : len(e.ids)] = torch.from_numpy(e.ids)
        mask[n, : len(e.ids)] = 1
        ends[n, : len(e.ends)] = torch.from_numpy(e.ends)
        valid[n, : len(e.ends)] = True
    labels = torch.tensor([e.label for e in batch], dtype=torch.long)
    return {"ids": ids, "mask": mask, "ends": ends, "valid": valid, "labels": labels}
