"""Reading the SFT export (:mod:`packlab.datagen.sft_export`, ``hf`` format) for training.

``datasets`` reads the Parquet files as they are (PIL images, chat messages). This module adds
what packlab's trainer needs on top: the version check, the paper's data controls (recipe and
fraction, by whole episodes), a validation split by episode, and the prompt ablations. An
ablation that removes history (``current_only``, ``no_actions``) cannot keep one conversation
per episode (each step would see a different context), so it expands an episode into one
example per step, each with the loss on its last answer only.

Needs the ``datasets`` package (the data or vlm extras); no torch.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from packlab.core.errors import ConfigError
from packlab.vlm.prompt.render import PROMPT_VERSION, PromptOptions, ablate

#: --recipe choices (the paper's data ablation) -> difficulties kept.
RECIPES: dict[str, frozenset[str]] = {
    "easy": frozenset({"easy"}),
    "easy+medium": frozenset({"easy", "medium"}),
    "mixed": frozenset({"easy", "medium", "hard"}),
}
#: Column of the export that says which prompt the text was rendered with.
_VERSION_COLUMN = "prompt_version"


@dataclass(frozen=True)
class SFTData:
    """The training and validation examples of a run, and what they hold."""

    train: Any  # datasets.Dataset with messages and images
    val: Any | None
    files: tuple[Path, ...]

    @staticmethod
    def labelled_actions(dataset: Any) -> int:
        """Assistant turns (each one a labelled action) in ``dataset``."""
        return sum(sum(m["role"] == "assistant" for m in msgs) for msgs in dataset["messages"])


def sft_files(path: str | Path) -> list[Path]:
    """The export's Parquet files: a dataset directory (its ``sft/``), an export directory, or
    one file. A JSONL export (an older packlab's) is refused with the command that rewrites it."""
    p = Path(path)
    if p.is_file():
        files = [p]
    elif p.is_dir():
        files = sorted((p / "sft").glob("*.parquet")) or sorted(p.glob("*.parquet"))
        if not files and (sorted((p / "sft").glob("*.jsonl")) or sorted(p.glob("*.jsonl"))):
            raise ConfigError(
                f"data = {str(p)!r}: holds a per-step JSONL export, which this packlab no longer "
                f"trains on; rewrite it: packlab export sft {p}"
            )
    else:
        raise ConfigError(f"data = {str(p)!r}: no such file or directory")
    if not files or any(f.suffix != ".parquet" for f in files):
        raise ConfigError(f"data = {str(p)!r}: no SFT .parquet files (looked in sft/ and {p})")
    return files


def _check_version(dataset: Any, files: Sequence[Path]) -> None:
    if _VERSION_COLUMN not in dataset.column_names:
        raise ConfigError(f"{files[0]}: no '{_VERSION_COLUMN}' column; not a packlab SFT export")
    versions = set(dataset.unique(_VERSION_COLUMN))
    if versions != {PROMPT_VERSION}:
        raise ConfigError(
            f"{files[0]}: field '{_VERSION_COLUMN}' = {sorted(versions)!r}, this packlab renders "
            f"{PROMPT_VERSION!r}; re-export the data (packlab export sft DIR)"
        )


def select_episodes(
    dataset: Any, recipe: str = "mixed", data_fraction: float = 1.0, seed: int = 0
) -> Any:
    """The paper's data controls: difficulties by recipe, then a seeded fraction of episodes
    (whole episodes: every window of a kept episode stays)."""
    if recipe not in RECIPES:
        raise ConfigError(f"recipe = {recipe!r}: choose from {', '.join(RECIPES)}")
    if not 0.0 < data_fraction <= 1.0:
        raise ConfigError(f"data_fraction = {data_fraction}: must be in (0, 1]")
    kept = RECIPES[recipe]
    dataset = dataset.filter(
        lambda d: d in kept or (recipe == "mixed" and not d), input_columns="difficulty"
    )
    if data_fraction < 1.0 and len(dataset):
        episodes = sorted(set(dataset["episode_id"]))
        n = max(1, round(len(episodes) * data_fraction))
        chosen = set(np.random.default_rng(seed).choice(episodes, size=n, replace=False).tolist())
        dataset = dataset.filter(lambda e: e in chosen, input_columns="episode_id")
    return dataset


def split_validation(dataset: Any, fraction: float, seed: int) -> tuple[Any, Any | None]:
    """(train, validation): a seeded ``fraction`` of the episodes held out, at least one when
    the fraction is > 0 and there are two episodes or more."""
    if fraction <= 0.0:
        return dataset, None
    episodes = sorted(set(dataset["episode_id"]))
    n = min(len(episodes) - 1, max(1, round(len(episodes) * fraction)))
    if n < 1:
        return dataset, None
    held = set(np.random.default_rng(seed + 1).choice(episodes, size=n, replace=False).tolist())
    val = dataset.filter(lambda e: e in held, input_columns="episode_id")
    train = dataset.filter(lambda e: e not in held, input_columns="episode_id")
    return train, val


def _with_images(messages: list[dict[str, Any]], images: Sequence[Any]) -> list[dict[str, Any]]:
    """Messages whose image placeholders hold their images (for :func:`ablate`)."""
    it = iter(images)
    return [
        dict(
            m,
            content=[dict(c, image=next(it)) if c["type"] == "image" else c for c in m["content"]],
        )
        for m in messages
    ]


def _split_images(messages: list[dict[str, Any]]) -> dict[str, Any]:
    """Back to the export's layout: placeholders in the messages, images in their own list."""
    images = []
    out = []
    for m in messages:
        content = []
        for c in m["content"]:
            if c["type"] == "image":
                images.append(c["image"])
                content.append({"type": "image", "text": None})
            else:
                content.append({"type": "text", "text": c["text"]})
        out.append({"role": m["role"], "content": content})
    return {"messages": out, "images": images}


def _blank(image: Any) -> Any:
    return Image.new(image.mode, image.size)


def ablate_conversation(
    messages: list[dict[str, Any]], images: Sequence[Any], options: PromptOptions
) -> list[dict[str, Any]]:
    """The examples one exported conversation gives under ``options``: itself with its images
    blanked or removed, or, where history is cut, one example per step (its context as
    :func:`packlab.vlm.prompt.render.ablate` renders it, then its answer)."""
    full = _with_images(messages, images)
    blank = None
    if options.image == "blank" and images:
        blank = _blank(images[0])
    if options.history == "full":
        ends = [len(full)]
    else:
        ends = [i + 1 for i, m in enumerate(full) if m["role"] == "assistant"]
    out = []
    for end in ends:
        context, answer = full[: end - 1], full[end - 1]
        out.append(_split_images([*ablate(context, options, blank=blank), answer]))
    return out


def apply_options(dataset: Any, options: PromptOptions) -> Any:
    """``dataset`` under the prompt ablation ``options`` (unchanged under the defaults)."""
    if options == PromptOptions():
        return dataset

    def expand(batch: dict[str, list[Any]]) -> dict[str, list[Any]]:
        out: dict[str, list[Any]] = {k: [] for k in batch}
        for i, (msgs, imgs) in enumerate(zip(batch["messages"], batch["images"])):
            for ex in ablate_conversation(msgs, imgs, options):
                for k in batch:
                    out[k].append(ex[k] if k in ex else batch[k][i])
        return out

    return dataset.map(expand, batched=True, batch_size=8, features=dataset.features)


def load_sft_data(
    path: str | Path,
    options: PromptOptions | None = None,
    recipe: str = "mixed",
    data_fraction: float = 1.0,
    val_fraction: float = 0.0,
    seed: int = 0,
) -> SFTData:
    """The examples of an export, selected, split by episode and ablated."""
    import datasets

    # Bars for each filter and map would bury the trainer's own progress (and a one-line error).
    datasets.disable_progress_bars()
    options = options or PromptOptions()
    files = sft_files(path)
    dataset = datasets.load_dataset("parquet", data_files=[str(f) for f in files], split="train")
    _check_version(dataset, files)
    dataset = select_episodes(dataset, recipe, data_fraction, seed)
    if not len(dataset):
        raise ConfigError(
            f"data = {str(path)!r}: no episodes left after recipe={recipe!r}, "
            f"data_fraction={data_fraction}"
        )
    train, val = split_validation(dataset, val_fraction, seed)
    train = apply_options(train, options)
    val = apply_options(val, options) if val is not None else None
    return SFTData(train, val, tuple(files))
