"""Scoring one observation's listed placements with a pointer model (inference, no grad); the
ONNX runtime's twin is :mod:`.onnx_scoring`. Imports torch: only the vlm extra may import this
module."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from packlab.core.types import Observation
from packlab.policies.candidates import Candidate
from packlab.vlm.candidate.encoding import PromptSettings, encode_settings
from packlab.vlm.candidate.pointer import (
    IMAGE_KEYS,
    Encoded,
    ImageGrid,
    PointerModel,
    collate,
    to_device,
)
from packlab.vlm.model.chatml import IM_END


def _encode(
    model: PointerModel,
    observation: Observation,
    listed: Sequence[Candidate],
    settings: PromptSettings,
) -> Encoded:
    return encode_settings(model.vlm.tokenizer, observation, listed, settings,
                           ImageGrid.of(model.vlm))  # fmt: skip


def score_listed(
    model: PointerModel,
    observation: Observation,
    listed: Sequence[Candidate],
    settings: PromptSettings,
) -> np.ndarray:
    """One score per listed placement (higher is better), on the model's device."""
    batch = _batch(model, observation, listed, settings)
    with torch.inference_mode():
        scores = model.score(batch)
    return scores[0].float().cpu().numpy()


def _batch(
    model: PointerModel,
    observation: Observation,
    listed: Sequence[Candidate],
    settings: PromptSettings,
) -> dict[str, torch.Tensor]:
    """The step as a batch of one on the model's device (a model in training may be on a GPU)."""
    pad = model.vlm.tokenizer.pad_token_id
    return to_device(collate([_encode(model, observation, listed, settings)], pad), model.device)


#: Longest free-JSON answer generated (an action is about 20 tokens).
MAX_ANSWER_TOKENS = 32


def generate_answer(
    model: PointerModel,
    observation: Observation,
    listed: Sequence[Candidate],
    settings: PromptSettings,
) -> str:
    """The model's greedy free-JSON answer text (the format ablation's policy)."""
    batch = _batch(model, observation, listed, settings)
    ids = batch["ids"]
    images = {k: batch[k] for k in IMAGE_KEYS if k in batch}
    end = model.vlm.tokenizer.convert_tokens_to_ids(IM_END)
    with torch.inference_mode():
        out = model.vlm.model.generate(
            input_ids=ids,
            attention_mask=torch.ones_like(ids),
            **images,
            max_new_tokens=MAX_ANSWER_TOKENS,
            do_sample=False,
            eos_token_id=end,
            pad_token_id=model.vlm.tokenizer.pad_token_id,
        )
    return model.vlm.tokenizer.decode(out[0, ids.shape[1] :].cpu(), skip_special_tokens=True)


def set_threads(threads: int | None) -> None:
    if threads is not None:
        torch.set_num_threads(threads)
