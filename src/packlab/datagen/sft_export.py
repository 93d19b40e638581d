"""The SFT export of a PackData dataset: one multi-turn conversation per episode.

Each example is a whole episode (or a window of it): the system turn, then for every step a
user turn (that step's heightmap image and buffer) and an assistant turn (the action), so a
trainer that puts the loss on every assistant turn learns every step of the episode from one
encoding of it. Tokens grow linearly with the episode, not with its square as they would with one
example per step carrying the whole history.

Two formats, both Parquet (pyarrow only, no ``datasets`` needed to write them):

- ``hf`` (``sft/<shard>.parquet``, written by ``packlab generate``): columns ``messages`` (the
  Hugging Face multimodal chat format, image entries as ``{"type": "image"}`` placeholders) and
  ``images`` (the PNGs themselves, as ``datasets.Image`` structs with their bytes), plus
  ``episode_id``, ``difficulty``, ``window``, ``first_step``, ``n_steps``, ``prompt_version``.
  The schema carries the ``datasets`` feature metadata, so ``datasets.load_dataset`` yields PIL
  images and TRL's ``SFTTrainer`` reads the rows as they are. The images are embedded so the
  export is self-contained: it reads the same from any working directory or machine.
- ``verl`` (``packlab export sft DIR --format verl``): the reference implementation's schema for
  verl's multi-turn SFT dataset: ``data_source``, ``prompt_template_id``, ``enable_thinking``,
  ``messages`` with string contents holding one ``<image>`` placeholder per image, ``images`` as
  ``[{"image": path}]`` (relative to the dataset root: pass it as verl's ``data.data_root``), and
  ``extra_info``. The text is packlab's prompt; only the layout is the reference's.

``window`` > 0 cuts an episode into consecutive windows of that many steps, for episodes longer
than a model's context: every step is a target in exactly one window, and a window's history
starts at its first step.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from packlab.core.errors import ConfigError
from packlab.core.types import Action
from packlab.datagen import format as fmt
from packlab.vlm.prompt.render import PROMPT_VERSION, TurnState, render_conversation

#: ``packlab export sft --format`` choices.
SFT_FORMATS = ("hf", "verl")
#: What replaces each image in a verl message's text (verl's multi-turn dataset splits on it).
VERL_IMAGE = "<image>"
#: The ``data_source`` value of verl rows (the reference's).
VERL_DATA_SOURCE = "packing_sft"

_HF_FEATURES = {
    "messages": {
        "feature": {
            "role": {"dtype": "string", "_type": "Value"},
            "content": {
                "feature": {
                    "type": {"dtype": "string", "_type": "Value"},
                    "text": {"dtype": "string", "_type": "Value"},
                },
                "_type": "List",
            },
        },
        "_type": "List",
    },
    "images": {"feature": {"_type": "Image"}, "_type": "List"},
    "episode_id": {"dtype": "string", "_type": "Value"},
    "difficulty": {"dtype": "string", "_type": "Value"},
    "window": {"dtype": "int32", "_type": "Value"},
    "first_step": {"dtype": "int32", "_type": "Value"},
    "n_steps": {"dtype": "int32", "_type": "Value"},
    "prompt_version": {"dtype": "string", "_type": "Value"},
}
_CONTENT = pa.list_(pa.struct([("type", pa.string()), ("text", pa.string())]))
HF_SCHEMA = pa.schema(
    [
        ("messages", pa.list_(pa.struct([("role", pa.string()), ("content", _CONTENT)]))),
        ("images", pa.list_(pa.struct([("bytes", pa.binary()), ("path", pa.string())]))),
        ("episode_id", pa.string()),
        ("difficulty", pa.string()),
        ("window", pa.int32()),
        ("first_step", pa.int32()),
        ("n_steps", pa.int32()),
        ("prompt_version", pa.string()),
    ],
    # What datasets reads the columns as (datasets.Features.to_dict(); List needs datasets >= 4).
    metadata={"huggingface": json.dumps({"info": {"features": _HF_FEATURES}})},
)
_PROMPT_VIEW = pa.struct([("history_mode", pa.string()), ("height_map_mode", pa.string())])
VERL_SCHEMA = pa.schema(
    [
        ("data_source", pa.string()),
        ("prompt_template_id", pa.string()),
        ("enable_thinking", pa.bool_()),
        ("messages", pa.list_(pa.struct([("role", pa.string()), ("content", pa.string())]))),
        ("images", pa.list_(pa.struct([("image", pa.string())]))),
        (
            "extra_info",
            pa.struct(
                [
                    ("episode_id", pa.string()),
                    ("difficulty", pa.string()),
                    ("buffer_size", pa.int32()),
                    ("num_steps", pa.int32()),
                    ("row_step_index", pa.int32()),  # always null: a row is a whole dialogue
                    ("window", pa.int32()),
                    ("first_step", pa.int32()),
                    ("image_paths", pa.list_(pa.string())),
                    (
                        "prompt_view",
                        pa.struct(
                            [("history_mode", pa.string()), ("height_map_mode", pa.string())]
                        ),
                    ),
                ]
            ),
        ),
    ]
)


@dataclass(frozen=True, slots=True)
class Conversation:
    """One training example: a window of an episode rendered as chat messages.

    ``messages`` are :func:`packlab.vlm.prompt.render.render_conversation`'s, their image entries
    holding the image paths (relative to the dataset root) in the order they appear.
    """

    episode_id: str
    difficulty: str
    window: int  # index of the window within its episode (0 when not windowed)
    first_step: int  # step index of the window's first target
    messages: list[dict[str, Any]]
    buffer_size: int

    @property
    def image_paths(self) -> list[str]:
        return [
            c["image"]
            for m in self.messages
            if not isinstance(m["content"], str)
            for c in m["content"]
            if c["type"] == "image"
        ]

    @property
    def n_steps(self) -> int:
        return sum(m["role"] == "assistant" for m in self.messages)


def _episodes(rows: Sequence[dict[str, Any]]) -> Iterator[Sequence[dict[str, Any]]]:
    """Consecutive runs of step rows sharing an episode id (the step shards' order)."""
    start = 0
    for i in range(1, len(rows) + 1):
        if i == len(rows) or rows[i]["episode_id"] != rows[start]["episode_id"]:
            yield rows[start:i]
            start = i


def episode_conversations(rows: Sequence[dict[str, Any]], window: int = 0) -> list[Conversation]:
    """The conversations of many episodes' step rows (grouped by episode, in step order)."""
    if window < 0:
        raise ConfigError(f"window = {window}: must be >= 0 (0: whole episodes)")
    out: list[Conversation] = []
    for steps in _episodes(rows):
        container = fmt.container_of(steps[0])
        turns = [
            TurnState(
                image=r["image"],
                shown=fmt.shown_items(r["shown"]),
                step_index=r["step_index"],
                remaining=r["remaining"],
            )
            for r in steps
        ]
        actions = [Action(**r["action"]) for r in steps]
        size = window or len(steps)
        for k, start in enumerate(range(0, len(steps), size)):
            stop = start + size
            out.append(
                Conversation(
                    episode_id=steps[0]["episode_id"],
                    difficulty=steps[0]["difficulty"],
                    window=k,
                    first_step=int(steps[start]["step_index"]),
                    messages=render_conversation(container, turns[start:stop], actions[start:stop]),
                    buffer_size=max(len(r["shown"]) for r in steps),
                )
            )
    return out


def _hf_messages(messages: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Image entries as bare placeholders (the images go in the ``images`` column)."""
    return [
        {
            "role": m["role"],
            "content": [
                {"type": "image", "text": None}
                if c["type"] == "image"
                else {"type": "text", "text": c["text"]}
                for c in m["content"]
            ],
        }
        for m in messages
    ]


def _read_image(root: Path, rel: str) -> bytes:
    path = root / rel
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(
            f"{path}: image missing (named by the step rows' 'image' field)"
        ) from None


def hf_table(conversations: Sequence[Conversation], root: Path) -> pa.Table:
    """The ``hf`` rows of ``conversations``, their PNGs read from under ``root``."""
    rows = [
        {
            "messages": _hf_messages(c.messages),
            "images": [{"bytes": _read_image(root, p), "path": p} for p in c.image_paths],
            "episode_id": c.episode_id,
            "difficulty": c.difficulty,
            "window": c.window,
            "first_step": c.first_step,
            "n_steps": c.n_steps,
            "prompt_version": PROMPT_VERSION,
        }
        for c in conversations
    ]
    return pa.Table.from_pylist(rows, schema=HF_SCHEMA)


def _verl_content(content: Sequence[dict[str, Any]]) -> str:
    return "\n".join(VERL_IMAGE if c["type"] == "image" else c["text"] for c in content)


def verl_table(conversations: Sequence[Conversation], root: Path) -> pa.Table:
    """The ``verl`` rows of ``conversations`` (image paths relative to the dataset root)."""
    rows = []
    for c in conversations:
        paths = c.image_paths
        for p in paths:
            if not (root / p).is_file():
                raise ConfigError(f"{root / p}: image missing (named by the step rows' 'image')")
        rows.append(
            {
                "data_source": VERL_DATA_SOURCE,
                "prompt_template_id": PROMPT_VERSION,
                "enable_thinking": False,
                "messages": [
                    {"role": m["role"], "content": _verl_content(m["content"])} for m in c.messages
                ],
                "images": [{"image": p} for p in paths],
                "extra_info": {
                    "episode_id": c.episode_id,
                    "difficulty": c.difficulty,
                    "buffer_size": c.buffer_size,
                    "num_steps": c.n_steps,
                    "row_step_index": None,
                    "window": c.window,
                    "first_step": c.first_step,
                    "image_paths": paths,
                    "prompt_view": {"history_mode": "full", "height_map_mode": "image"},
                },
            }
        )
    return pa.Table.from_pylist(rows, schema=VERL_SCHEMA)


def sft_table(
    rows: Sequence[dict[str, Any]], root: Path, form: str = "hf", window: int = 0
) -> pa.Table:
    """One shard's SFT table in ``form`` from its step rows."""
    if form not in SFT_FORMATS:
        raise ConfigError(f"format = {form!r}: choose from {', '.join(SFT_FORMATS)}")
    conversations = episode_conversations(rows, window)
    return (hf_table if form == "hf" else verl_table)(conversations, root)


def export_sft(
    dataset_dir: str | os.PathLike[str],
    form: str = "hf",
    window: int = 0,
    out: str | os.PathLike[str] | None = None,
) -> list[Path]:
    """(Re)write the SFT export of a dataset from its step shards, one Parquet file per shard.

    ``out`` defaults to ``DIR/sft`` for ``hf`` and ``DIR/sft-verl`` for ``verl``. Each file is
    written atomically, so a run stopped half-way leaves whole files only; the step shards are
    only read.
    """
    if form not in SFT_FORMATS:
        raise ConfigError(f"format = {form!r}: choose from {', '.join(SFT_FORMATS)}")
    root = Path(dataset_dir)
    shards = sorted((root / fmt.STEPS_DIR).glob("*.parquet"))
    if not shards:
        raise ConfigError(f"{root}: no step shards under {fmt.STEPS_DIR}/ (not a PackData dir?)")
    dest = Path(out) if out is not None else root / (fmt.SFT_DIR if form == "hf" else "sft-verl")
    written = []
    for path in shards:
        table = sft_table(pq.read_table(path).to_pylist(), root, form, window)
        target = dest / f"{path.stem}.parquet"
        fmt.write_parquet(target, table)
        written.append(target)
    return written
