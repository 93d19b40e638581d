"""The transformers processor of a :class:`~packlab.vlm.model.checkpoint.VLM`, for training.

Trainers outside packlab (TRL's ``SFTTrainer``) take a ``ProcessorMixin``: it renders the chat
template, expands each image placeholder to the image's visual tokens, runs the image processor
and returns the mask of assistant tokens. packlab builds the family's own processor class over
the model's tokenizer and image processor, without the video processor: packing data has no
video, and the family's video processor needs torchvision, which packlab does not install.

Imports torch/transformers: only the vlm extra may import this module.
"""

from __future__ import annotations

import bisect
from typing import Any

import numpy as np
from transformers import Qwen2_5_VLProcessor, Qwen3VLProcessor

from packlab.vlm.model.chatml import TRAINING_CHAT_TEMPLATE, is_project_template
from packlab.vlm.model.checkpoint import VLM


class _ImageOnly:
    """A processor with the image processor and tokenizer as its only parts (no video
    processor). Mixed into each family's class below; module-level so that it pickles (DataLoader
    workers started by spawn)."""

    @classmethod
    def get_attributes(cls) -> list[str]:
        return ["image_processor", "tokenizer"]

    def _adjust_assistant_masks_indices(
        self, processed_dict: dict[str, Any], generation_indices: list[list[Any]]
    ) -> dict[str, Any]:
        """transformers' assistant mask (every token overlapping an assistant span, the spans
        shifted past expanded image placeholders), computed with array operations. The library
        walks every token of the sequence in Python once per assistant turn, which costs seconds
        per batch on the long multi-turn conversations of whole episodes (about 3 s for a
        9,000-token, 32-turn episode here). Same result: a test compares the labels token by
        token with the chat template."""
        offset_mapping = processed_dict.pop("offset_mapping")
        input_ids = processed_dict["input_ids"]
        replacements = processed_dict.pop("text_replacement_offsets", None) or [[]] * len(input_ids)
        masks = []
        for i in range(len(input_ids)):
            offsets = np.asarray(offset_mapping[i], dtype=np.int64).reshape(-1, 2)
            token_start, token_end = offsets[:, 0], offsets[:, 1]
            placeholder_ends = [r["span"][1] for r in replacements[i]]
            gained = [0] + [r["new_span"][1] - r["span"][1] for r in replacements[i]]
            mask = np.zeros(len(input_ids[i]), dtype=bool)
            for span in generation_indices[i]:
                start, end = (c + gained[bisect.bisect_right(placeholder_ends, c)] for c in span)
                mask |= (token_start < end) & (token_end > start)
            masks.append(mask.astype(np.int64).tolist())
        processed_dict["assistant_masks"] = masks
        return processed_dict


class ImageOnlyQwen3VLProcessor(_ImageOnly, Qwen3VLProcessor):
    """Qwen3-VL's and Qwen3.5's processor without a video processor."""


class ImageOnlyQwen2_5_VLProcessor(_ImageOnly, Qwen2_5_VLProcessor):
    """Qwen2.5-VL's processor without a video processor."""


#: family -> the image-only processor class of its checkpoints' processor.
_PROCESSOR_CLASSES: dict[str, type] = {
    "qwen3_5": ImageOnlyQwen3VLProcessor,
    "qwen3_vl": ImageOnlyQwen3VLProcessor,
    "qwen2_5_vl": ImageOnlyQwen2_5_VLProcessor,
}


def training_chat_template(vlm: VLM) -> str | None:
    """The template to train with: the project's own with generation markers for models that
    carry the project's tokenizer; None (keep the checkpoint's, which TRL swaps for its training
    version of the known Qwen templates) otherwise."""
    template = getattr(vlm.tokenizer, "chat_template", None)
    if isinstance(template, str) and is_project_template(template):
        return TRAINING_CHAT_TEMPLATE
    return None


def processor_for(vlm: VLM) -> Any:
    """The family's processor over ``vlm``'s tokenizer and image processor, image-only, with
    the template to train with (the checkpoint's own where it is not the project's)."""
    cls = _PROCESSOR_CLASSES[vlm.family]
    template = training_chat_template(vlm) or getattr(vlm.tokenizer, "chat_template", None)
    return cls(vlm.image_processor, vlm.tokenizer, chat_template=template)
