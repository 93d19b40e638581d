"""The transformers processor of a :class:`~packlab.vlm.model.checkpoint.VLM`, for training.

Trainers outside packlab (TRL's ``SFTTrainer``) take a ``ProcessorMixin``: it renders the chat
template, expands each image placeholder to the image's visual tokens, runs the image processor
and returns the mask of assistant tokens. A checkpoint directory that carries a full processor
(``processor_config.json`` or a chat template beside a tokenizer) is read with ``AutoProcessor``.
Otherwise, and wherever the family's video processor cannot be built (it needs torchvision,
which packlab does not install), the family's own processor class is used with the image
processor and tokenizer only: packing data has no video.

Imports torch/transformers: only the vlm extra may import this module.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from transformers import AutoProcessor, Qwen2_5_VLProcessor, Qwen3VLProcessor

from packlab.vlm.model.chatml import TRAINING_CHAT_TEMPLATE, is_project_template
from packlab.vlm.model.checkpoint import VLM


class _ImageOnly:
    """A processor with the image processor and tokenizer as its only parts (no video
    processor). Mixed into each family's class below; module-level so that it pickles (DataLoader
    workers started by spawn)."""

    @classmethod
    def get_attributes(cls) -> list[str]:
        return ["image_processor", "tokenizer"]


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


def processor_for(vlm: VLM, checkpoint: str | Path | None = None) -> Any:
    """A processor for ``vlm``: the checkpoint's own where it loads, else the image-only one."""
    if checkpoint is not None and vlm.meta.get("tokenizer") is None:
        try:
            processor = AutoProcessor.from_pretrained(checkpoint, local_files_only=True)
            return processor
        except (ImportError, OSError, ValueError, AttributeError, TypeError):
            pass  # no processor files, or a video processor needing torchvision: build one
    cls = _PROCESSOR_CLASSES[vlm.family]
    template = training_chat_template(vlm) or getattr(vlm.tokenizer, "chat_template", None)
    return cls(vlm.image_processor, vlm.tokenizer, chat_template=template)
