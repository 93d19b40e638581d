"""Token lengths of SFT examples, and the check that no example is cut silently.

A conversation cut at ``max_length`` would lose its last steps' answers without a word, or, cut
inside an image's tokens, fail in the model. So every example is measured before training: the
chat template's text tokenized, plus each image's visual tokens (from its size, through the
model's image processor). ``max_length`` None takes the longest example; an example longer than
a given one is refused (``error``, the default, as the reference's ``truncation=error``) or
dropped and counted (``drop``).
"""

from __future__ import annotations

import io
from dataclasses import dataclass, replace
from typing import Any

from PIL import Image

from packlab.core.errors import ConfigError
from packlab.vlm.data.sft_dataset import SFTData
from packlab.vlm.data.sft_tokens import TokenCounter


@dataclass(frozen=True)
class FittedLengths:
    data: SFTData
    max_length: int
    dropped: int  # examples over max_length, dropped (truncation="drop")
    longest: int  # tokens of the longest example before dropping


def _image_size(image: dict[str, Any]) -> tuple[int, int]:
    """Width and height from the PNG header (no decoding)."""
    with Image.open(io.BytesIO(image["bytes"])) as im:
        return im.size


def example_lengths(dataset: Any, processor: Any, template_kwargs: dict[str, Any]) -> list[int]:
    """Tokens of every example of ``dataset`` as the trainer's collator will encode it."""
    from datasets import Image as ImageFeature
    from datasets import List

    raw = dataset.cast_column("images", List(ImageFeature(decode=False)))
    # The template is the processor's (the training one); only the visual-token count is shared.
    visual = TokenCounter(processor.tokenizer, processor.image_processor, "", "").visual_tokens
    tokenizer = processor.tokenizer
    lengths = []
    for row in raw.select_columns(["messages", "images"]):
        text = processor.apply_chat_template(
            row["messages"], tokenize=False, add_generation_prompt=False, **template_kwargs
        )
        n = len(tokenizer(text, add_special_tokens=False)["input_ids"])
        # Each image's one placeholder token becomes its visual tokens.
        n += sum(visual(_image_size(im)) - 1 for im in row["images"])
        lengths.append(n)
    return lengths


def _over(dataset: Any, lengths: list[int], limit: int) -> list[int]:
    return [i for i, n in enumerate(lengths) if n > limit]


def fit_lengths(
    data: SFTData,
    processor: Any,
    max_length: int | None,
    truncation: str,
    template_kwargs: dict[str, Any],
) -> FittedLengths:
    """``data`` checked (or trimmed) against ``max_length``; see the module docstring."""
    train_len = example_lengths(data.train, processor, template_kwargs)
    val_len = example_lengths(data.val, processor, template_kwargs) if data.val is not None else []
    longest = max(train_len + val_len)
    limit = longest if max_length is None else max_length
    over_train, over_val = _over(data.train, train_len, limit), _over(data.val, val_len, limit)
    dropped = len(over_train) + len(over_val)
    if dropped and truncation == "error":
        ds: Any = data.train if over_train else data.val
        idx = over_train[0] if over_train else over_val[0]
        row = ds[idx]
        n = (train_len if over_train else val_len)[idx]
        raise ConfigError(
            f"max_length = {limit}: {dropped} example(s) are longer, e.g. episode "
            f"{row['episode_id']!r} window {row['window']} ({n} tokens; the longest has "
            f"{longest}). Raise --max-length, cut episodes into windows (packlab export sft "
            f"DIR --window N), or drop them with --truncation drop"
        )
    if dropped:
        keep_train = sorted(set(range(len(train_len))) - set(over_train))
        if not keep_train:
            raise ConfigError(f"max_length = {limit}: every training example is longer")
        train = data.train.select(keep_train)
        val = data.val
        if val is not None:
            keep_val = sorted(set(range(len(val_len))) - set(over_val))
            val = val.select(keep_val) if keep_val else None
        data = replace(data, train=train, val=val)
    return FittedLengths(data, limit, dropped, longest)
