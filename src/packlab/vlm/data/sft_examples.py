"""Reading and selecting SFT examples (pure apart from reading the files; no torch).

The SFT export is JSONL, one step-level example per line::

    # messages: render_messages(...) then with_answer(target)
    {"messages": [system, user, assistant, ..., user, assistant-target],
     "episode_id": "easy-17", "difficulty": "easy", "step_index": 3,
     "prompt_version": "packlab-prompt-v2"}

rendered with the default options (full history, heightmap images given as paths relative to the
dataset root); the trainer derives the ablations with
:func:`packlab.vlm.prompt.render.ablate`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from packlab.core.errors import ConfigError
from packlab.vlm.prompt.render import PROMPT_VERSION, split_target

#: --recipe choices (paper's data ablation) -> difficulties kept.
RECIPES: dict[str, frozenset[str]] = {
    "easy": frozenset({"easy"}),
    "easy+medium": frozenset({"easy", "medium"}),
    "mixed": frozenset({"easy", "medium", "hard"}),
}


@dataclass(frozen=True, slots=True)
class SFTExample:
    context: tuple[dict[str, Any], ...]  # chat messages ending with the current user turn
    answer: str  # the exact assistant target (action_text)
    episode_id: str
    difficulty: str
    step_index: int


def find_sft_files(path: str | Path) -> tuple[list[Path], Path]:
    """(JSONL files, image root) for a dataset directory or a single JSONL file.

    Image paths in the messages are relative to the dataset root: the nearest directory at or
    above ``path`` that holds ``meta/info.json``, else the directory given (or the file's own).
    """
    p = Path(path)
    if p.is_file():
        files, start = [p], p.parent
    elif p.is_dir():
        files = sorted((p / "sft").glob("*.jsonl")) or sorted(p.glob("*.jsonl"))
        start = p
    else:
        raise ConfigError(f"data = {str(p)!r}: no such file or directory")
    if not files:
        raise ConfigError(
            f"data = {str(p)!r}: no SFT .jsonl files (looked in sft/ and the top level)"
        )
    root = next((d for d in (start, *start.parents) if (d / "meta" / "info.json").is_file()), start)
    return files, root


def load_sft_examples(path: str | Path) -> tuple[list[SFTExample], Path]:
    """All examples of an SFT export, and the root their image paths are relative to."""
    files, root = find_sft_files(path)
    out: list[SFTExample] = []
    for f in files:
        with f.open() as fh:
            for line_no, line in enumerate(fh, 1):
                if not line.strip():
                    continue
                try:
                    rec = json.loads(line)
                    version = rec.get("prompt_version", PROMPT_VERSION)
                    if version != PROMPT_VERSION:
                        raise ValueError(
                            f"prompt_version {version!r} != this code's {PROMPT_VERSION!r}; "
                            "re-export the SFT data"
                        )
                    context, answer = split_target(rec["messages"])
                    out.append(
                        SFTExample(
                            tuple(context),
                            answer,
                            str(rec.get("episode_id", "")),
                            str(rec.get("difficulty", "")),
                            int(rec.get("step_index", -1)),
                        )
                    )
                except (ValueError, KeyError, TypeError) as e:
                    raise ConfigError(f"{f}:{line_no}: bad SFT record: {e}") from None
    return out, root


def select_examples(
    examples: Sequence[SFTExample], recipe: str = "mixed", data_fraction: float = 1.0, seed: int = 0
) -> list[SFTExample]:
    """The paper's data controls: difficulties by recipe, then a seeded fraction of *episodes*
    (whole episodes, so every kept step still has its own history)."""
    if recipe not in RECIPES:
        raise ConfigError(f"recipe = {recipe!r}: choose from {', '.join(RECIPES)}")
    if not 0.0 < data_fraction <= 1.0:
        raise ConfigError(f"data_fraction = {data_fraction}: must be in (0, 1]")
    kept = [
        e
        for e in examples
        if e.difficulty in RECIPES[recipe] or (recipe == "mixed" and not e.difficulty)
    ]
    episodes = sorted({e.episode_id for e in kept})
    if data_fraction < 1.0 and episodes:
        n = max(1, round(len(episodes) * data_fraction))
        rng = np.random.default_rng(seed)
        chosen = set(rng.choice(np.array(episodes, dtype=object), size=n, replace=False).tolist())
        kept = [e for e in kept if e.episode_id in chosen]
    return kept
