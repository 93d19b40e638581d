"""Token figures of the SFT export (:mod:`packlab.datagen.sft_export`, ``hf`` format): what one
pass of training over it encodes, per labelled action.

A conversation's tokens are counted as the trainer's length check counts them
(:mod:`packlab.vlm.train.lengths`): the tokenizer's chat template rendered and tokenized, then
each image's one placeholder token replaced by its visual tokens (the family's image processor
on an image of that size: 49 for a 224 px image at the Qwen3 families' 32 px per merged token).

*Encoding passes* is the tokens encoded divided by the tokens of every episode's conversation
rendered once: 1.0 for an export of whole episodes, slightly more for windows (each window
repeats the system turn). :func:`turn_end_tokens` also gives, from one encoding, the tokens of
every prefix of a conversation that ends on an assistant turn, which is what an older
one-example-per-step export encoded for that step.

Only the counts columns of the export are read in full; the messages and images of a seeded
sample of whole episodes are read for the token counts (:func:`measure`).

Imports the project tokenizer (``tokenizers``, ``transformers``) and the image processor
(torch): only the vlm extra may import this module.
"""

from __future__ import annotations

import io
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
from PIL import Image

from packlab.core.errors import ConfigError
from packlab.vlm.model.chatml import IM_START
from packlab.vlm.model.checkpoint import (
    family_of,
    image_processor_for,
    load_image_processor,
    load_tokenizer,
)
from packlab.vlm.model.tokenizer import TOKENIZER_NAME, build_tokenizer

#: Image processor family when the tokenizer comes from no checkpoint (the default model's).
DEFAULT_FAMILY = "qwen3_5"
#: Conversations whose messages are read and tokenized (whole episodes, seeded).
DEFAULT_SAMPLE = 200
#: The label of the whole export in :attr:`TokenReport.groups`.
ALL = "all"
_INDEX_COLUMNS = ["episode_id", "difficulty", "window", "n_steps"]


@dataclass(frozen=True)
class Conversation:
    """One exported row, as far as counting its tokens needs."""

    episode_id: str
    difficulty: str
    window: int
    messages: list[dict[str, Any]]
    image_sizes: list[tuple[int, int]]  # (width, height) of its images, in order


@dataclass(frozen=True)
class GroupFigures:
    """The figures of one difficulty (or of the whole export)."""

    conversations: int  # in the export
    labelled_actions: int  # assistant turns in the export
    sampled_conversations: int
    sampled_actions: int
    tokens: int  # encoded by the sampled conversations
    episode_tokens: int  # the sampled episodes, each rendered once as one conversation

    @property
    def tokens_per_action(self) -> float | None:
        return self.tokens / self.sampled_actions if self.sampled_actions else None

    @property
    def passes(self) -> float | None:
        return self.tokens / self.episode_tokens if self.episode_tokens else None

    @property
    def estimated_tokens(self) -> int | None:
        """Tokens of one pass over the whole export: the sample's rate times every action."""
        rate = self.tokens_per_action
        return None if rate is None else round(rate * self.labelled_actions)

    def to_dict(self) -> dict[str, Any]:
        return {
            "conversations": self.conversations,
            "labelled_actions": self.labelled_actions,
            "sampled_conversations": self.sampled_conversations,
            "sampled_actions": self.sampled_actions,
            "tokens": self.tokens,
            "episode_tokens": self.episode_tokens,
            "tokens_per_action": self.tokens_per_action,
            "passes": self.passes,
            "estimated_tokens": self.estimated_tokens,
        }


@dataclass(frozen=True)
class TokenReport:
    """What :func:`measure` found: figures per difficulty and :data:`ALL`, and how."""

    groups: dict[str, GroupFigures]
    tokenizer: str
    family: str
    image_tokens: dict[tuple[int, int], int]  # visual tokens per image size seen
    sample: int  # the --token-sample asked for
    seed: int

    @property
    def sampled(self) -> bool:
        whole = self.groups[ALL]
        return whole.sampled_conversations < whole.conversations

    def to_dict(self) -> dict[str, Any]:
        return {
            "tokenizer": self.tokenizer,
            "image_family": self.family,
            "image_tokens": {f"{w}x{h}": n for (w, h), n in sorted(self.image_tokens.items())},
            "sample": self.sample,
            "seed": self.seed,
            "sampled": self.sampled,
            "groups": {k: g.to_dict() for k, g in self.groups.items()},
        }


class TokenCounter:
    """Counts a conversation's tokens with a tokenizer's chat template and an image processor."""

    def __init__(self, tokenizer: Any, image_processor: Any, name: str, family: str) -> None:
        self.tokenizer, self.image_processor = tokenizer, image_processor
        self.name, self.family = name, family
        self.image_tokens: dict[tuple[int, int], int] = {}
        self.im_start = tokenizer.convert_tokens_to_ids(IM_START)

    def visual_tokens(self, size: tuple[int, int]) -> int:
        """Merged visual tokens of an image of ``size`` (the processor's grid over merge**2)."""
        if size not in self.image_tokens:
            grid = self.image_processor(images=[Image.new("RGB", size)], return_tensors="pt")
            merge = int(getattr(self.image_processor, "merge_size", 2)) ** 2
            self.image_tokens[size] = int(grid["image_grid_thw"][0].prod()) // merge
        return self.image_tokens[size]

    def _ids(self, messages: Sequence[dict[str, Any]]) -> list[int]:
        try:
            text = self.tokenizer.apply_chat_template(
                list(messages), tokenize=False, add_generation_prompt=False
            )
        except ValueError as exc:  # no chat template
            raise ConfigError(f"tokenizer {self.name}: cannot render a chat ({exc})") from None
        return list(self.tokenizer(text, add_special_tokens=False)["input_ids"])

    def count(self, conversation: Conversation) -> int:
        """Tokens of the conversation as the trainer encodes it."""
        n = len(self._ids(conversation.messages))
        return n + sum(self.visual_tokens(s) - 1 for s in conversation.image_sizes)

    def turn_end_tokens(self, conversation: Conversation) -> list[int]:
        """Tokens of the conversation's prefix through each assistant turn, in order.

        From one encoding: a ChatML message starts at an ``<|im_start|>`` token, so the prefix
        through message k ends where message k + 1 starts (the whole encoding for the last one);
        the images of the messages in the prefix add their visual tokens.
        """
        ids = self._ids(conversation.messages)
        starts = [i for i, t in enumerate(ids) if t == self.im_start]
        messages = conversation.messages
        if len(starts) != len(messages):
            raise ConfigError(
                f"tokenizer {self.name}: {len(starts)} {IM_START} tokens for {len(messages)} "
                "messages; its chat template is not plain ChatML"
            )
        ends = [*starts[1:], len(ids)]
        sizes = iter(conversation.image_sizes)
        extra, out = 0, []
        for message, end in zip(messages, ends):
            extra += sum(self.visual_tokens(next(sizes)) - 1 for _ in range(_n_images(message)))
            if message["role"] == "assistant":
                out.append(end + extra)
        return out


def _n_images(message: dict[str, Any]) -> int:
    content = message["content"]
    return 0 if isinstance(content, str) else sum(c["type"] == "image" for c in content)


def project_counter(family: str = DEFAULT_FAMILY) -> TokenCounter:
    """The project's own tokenizer (what tiny models train with) and ``family``'s images."""
    return TokenCounter(build_tokenizer(), image_processor_for(family), TOKENIZER_NAME, family)


def checkpoint_counter(path: str | Path) -> TokenCounter:
    """The tokenizer and image processor saved in a checkpoint directory (the family from its
    config.json, else :data:`DEFAULT_FAMILY`)."""
    path = Path(path)
    if not path.is_dir():
        raise ConfigError(f"tokenizer = {str(path)!r}: not a checkpoint directory")
    family = family_of(path) if (path / "config.json").is_file() else DEFAULT_FAMILY
    try:
        tokenizer = load_tokenizer(path)
    except (OSError, ValueError) as exc:
        raise ConfigError(
            f"tokenizer = {str(path)!r}: no tokenizer loads from it ({exc})"
        ) from None
    return TokenCounter(tokenizer, load_image_processor(path, family), str(path), family)


def export_files(root: str | Path) -> list[Path]:
    """The ``hf`` export's Parquet files of a dataset directory (``sft/*.parquet``)."""
    return sorted((Path(root) / "sft").glob("*.parquet"))


def read_index(files: Iterable[Path]) -> list[dict[str, Any]]:
    """Episode, difficulty, window and step count of every exported row (no messages, no
    images: cheap on a large export)."""
    rows: list[dict[str, Any]] = []
    for path in files:
        rows += pq.read_table(path, columns=_INDEX_COLUMNS).to_pylist()
    return rows


def sample_episodes(index: Sequence[dict[str, Any]], n: int, seed: int) -> set[str]:
    """Whole episodes in a seeded random order, as many as fit in ``n`` conversations (at least
    one): an episode's windows are measured together, so its passes are exact."""
    windows: dict[str, int] = {}
    for row in index:
        windows[row["episode_id"]] = windows.get(row["episode_id"], 0) + 1
    names = sorted(windows)
    order = [names[i] for i in np.random.default_rng(seed).permutation(len(names))]
    chosen: set[str] = set()
    total = 0
    for episode in order:
        if chosen and total + windows[episode] > n:
            break
        chosen.add(episode)
        total += windows[episode]
    return chosen


def _image_size(image: dict[str, Any]) -> tuple[int, int]:
    """Width and height from the PNG header (no decoding)."""
    with Image.open(io.BytesIO(image["bytes"])) as im:
        return (int(im.size[0]), int(im.size[1]))


def read_conversations(files: Iterable[Path], episodes: set[str]) -> list[Conversation]:
    """The rows of ``episodes`` with their messages and image sizes."""
    out = []
    wanted = sorted(episodes)
    columns = [*_INDEX_COLUMNS[:3], "messages", "images"]
    for path in files:
        table = pq.read_table(path, columns=columns, filters=[("episode_id", "in", wanted)])
        for row in table.to_pylist():
            out.append(
                Conversation(
                    row["episode_id"],
                    row["difficulty"],
                    int(row["window"]),
                    row["messages"],
                    [_image_size(im) for im in row["images"]],
                )
            )
    return out


def whole_episodes(conversations: Sequence[Conversation]) -> list[Conversation]:
    """Each episode's windows joined into its one conversation: the first window's system turn,
    then every window's turns in order (a window's turns are the episode's own)."""
    by_episode: dict[str, list[Conversation]] = {}
    for c in conversations:
        by_episode.setdefault(c.episode_id, []).append(c)
    out = []
    for parts in by_episode.values():
        parts = sorted(parts, key=lambda c: c.window)
        messages = list(parts[0].messages)
        sizes = list(parts[0].image_sizes)
        for c in parts[1:]:
            messages += c.messages[1:]  # the system turn has no image
            sizes += c.image_sizes
        out.append(Conversation(parts[0].episode_id, parts[0].difficulty, 0, messages, sizes))
    return out


def _group(
    index: Sequence[dict[str, Any]],
    counted: Sequence[tuple[Conversation, int]],
    episode_tokens: Sequence[tuple[Conversation, int]],
) -> GroupFigures:
    return GroupFigures(
        conversations=len(index),
        labelled_actions=sum(int(r["n_steps"]) for r in index),
        sampled_conversations=len(counted),
        sampled_actions=sum(_n_actions(c) for c, _ in counted),
        tokens=sum(n for _, n in counted),
        episode_tokens=sum(n for _, n in episode_tokens),
    )


def _n_actions(conversation: Conversation) -> int:
    return sum(m["role"] == "assistant" for m in conversation.messages)


def _order(index: Sequence[dict[str, Any]]) -> list[str]:
    """Difficulties in their canonical order where known, else as they come."""
    known = ("easy", "medium", "hard")
    seen = list(dict.fromkeys(r["difficulty"] for r in index))
    return sorted(seen, key=lambda d: (known.index(d) if d in known else len(known), d))


def measure(
    root: str | Path, counter: TokenCounter, sample: int = DEFAULT_SAMPLE, seed: int = 0
) -> TokenReport | None:
    """Token figures of the export under ``root`` (None when it has no ``sft/*.parquet``)."""
    if sample < 1:
        raise ConfigError(f"token_sample = {sample}: must be >= 1")
    files = export_files(root)
    if not files:
        return None
    index = read_index(files)
    sampled = read_conversations(files, sample_episodes(index, sample, seed))
    counted = [(c, counter.count(c)) for c in sampled]
    once = [(c, counter.count(c)) for c in whole_episodes(sampled)]
    groups = {
        d: _group(
            [r for r in index if r["difficulty"] == d],
            [x for x in counted if x[0].difficulty == d],
            [x for x in once if x[0].difficulty == d],
        )
        for d in _order(index)
    }
    groups[ALL] = _group(index, counted, once)
    return TokenReport(
        groups, counter.name, counter.family, dict(counter.image_tokens), sample, seed
    )


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def format_tokens(report: TokenReport) -> str:
    """The figures as a plain-text table, with a header that says how they were measured."""
    whole = report.groups[ALL]
    sizes = ", ".join(f"{w}x{h} px: {n}" for (w, h), n in sorted(report.image_tokens.items()))
    if report.sampled:
        how = (
            f"a sample of {whole.sampled_conversations} of {whole.conversations} conversations "
            f"(whole episodes, seed {report.seed}); est. tokens: its tokens per action times "
            "every action"
        )
    else:
        how = f"all {whole.conversations} conversations measured"
    lines = [
        (
            f"SFT export tokens (sft/*.parquet): tokenizer {report.tokenizer}; images as "
            f"{report.family} ({sizes or 'none'} visual tokens each)"
        ),
        f"  {how}",
        (
            f"{'difficulty':<10} {'convs':>7} {'actions':>8} {'sampled':>8} {'tokens':>11} "
            f"{'tok/action':>10} {'passes':>7} {'est. tokens':>13}"
        ),
    ]
    for name, g in report.groups.items():
        lines.append(
            f"{name:<10} {g.conversations:>7} {g.labelled_actions:>8} "
            f"{g.sampled_conversations:>8} {g.tokens:>11} "
            f"{_fmt(g.tokens_per_action, '.1f'):>10} {_fmt(g.passes, '.3f'):>7} "
            f"{_fmt(g.estimated_tokens, 'd'):>13}"
        )
    return "\n".join(lines)
