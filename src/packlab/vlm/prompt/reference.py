"""The reference implementation's request, rendered from a packlab observation (no torch).

What a model trained on the reference's data (Correr-Zhou/PackLab, PackData-20K) saw at its
evaluation, field by field:

- system turn: :data:`~.reference_template.SYSTEM_TEMPLATE` with the container as compact JSON,
  ``{"container_grid_size":{"x_cells":..,"y_cells":..,"z_cells":..}}`` (:func:`container_json`);
- each user turn: the heightmap as a PNG ``image_url`` part, then the text
  ``"<image>\\nCurrent visible buffer objects:\\n[{"object_id":i,"size_cells":[dx,dy,dz]}]\\n"``
  (the literal ``<image>`` stays in the text at evaluation);
- each past assistant turn: the model's raw answer, unparsed;
- after the current user turn, the assistant prefill :data:`~.reference_template.THINKING_PREFILL`
  and :data:`EXTRA_BODY`, so the model continues after ``</think>``;
- greedy sampling (:data:`SAMPLING`).

The training form differs in three ways (the reference trains and evaluates on different
prompts; a model fine-tuned on PackData-20K saw the training form): its system JSON also holds
``container_size_cm`` and ``grid_cell_size_cm`` (``container_json(form="train")``), the
``<image>`` literal is replaced by the image itself, and thinking is off with no prefill.
This module renders the evaluation form, which is what the reference's benchmark figures used.

Heightmap image (:func:`heightmap_image`): the (x_cells, y_cells) heightmap coloured from blue
(empty) to red at twice the container height (R = floor(255 h/h_max), G = 0,
B = floor(255 (1 - h/h_max)) for occupied cells, pure blue for empty ones), rows along x and
columns along y, resized to 224 x 224 by nearest neighbour (the cells stop being square).
"""

from __future__ import annotations

import hashlib
import json
import random
from collections.abc import Callable, Sequence
from typing import Any, Literal

import numpy as np
from PIL import Image

from packlab.core.types import Action, Container, Observation, ShownItem, Unparsable
from packlab.vlm.prompt.reference_template import (
    SYSTEM_TEMPLATE,
    THINKING_PREFILL,
    USER_TEMPLATE,
)

#: The reference's history modes (its diagnostics ablations).
ReferenceHistory = Literal["full", "current_only", "no_assistant", "shuffled_assistant_actions"]
#: The reference's image modes that packlab's ``image`` option maps to.
ReferenceImage = Literal["normal", "blank", "none"]

#: Image side in pixels (the reference's ``output_size``).
IMAGE_SIZE = 224
#: Fully red is this many container heights.
COLOUR_HEIGHT_RATIO = 2.0
#: What every evaluation request adds to the body (vLLM's chat-template switches).
EXTRA_BODY: dict[str, Any] = {
    "chat_template_kwargs": {"enable_thinking": True},
    "add_generation_prompt": False,
    "continue_final_message": True,
}
#: The evaluation's sampling settings.
SAMPLING: dict[str, Any] = {"temperature": 0.0, "top_p": 1.0, "max_tokens": 512}
#: The order of the keys of the answer the prompt asks for.
ANSWER_KEYS = ("object_id", "x", "y", "rotation")

# Compact JSON, non-ASCII kept as is: the reference's spelling of every JSON it embeds.
_SEPARATORS = (",", ":")


def _compact(value: Any) -> str:
    return json.dumps(value, ensure_ascii=False, separators=_SEPARATORS)


def container_json(container: Container, form: Literal["eval", "train"] = "eval") -> str:
    """The container as the system turn embeds it; ``train`` adds the centimetre fields the
    training data carries (sizes in cm as floats, cell sizes 2.5 and 0.2 for packlab's grid)."""
    nx, ny = container.cells
    grid = {"x_cells": nx, "y_cells": ny, "z_cells": container.height_mm // container.cell_z_mm}
    if form == "eval":
        return _compact({"container_grid_size": grid})
    return _compact(
        {
            "container_size_cm": [v / 10.0 for v in container.size_mm],
            "container_grid_size": grid,
            "grid_cell_size_cm": {
                "xy": container.cell_xy_mm / 10.0,
                "z": container.cell_z_mm / 10.0,
            },
        }
    )


def buffer_json(shown: Sequence[ShownItem]) -> str:
    """The shown buffer, in shown order: ``[{"object_id":i,"size_cells":[dx,dy,dz]}]``."""
    items = [
        {"object_id": s.shown_index, "size_cells": [int(v) for v in s.size_cells]}
        for s in sorted(shown, key=lambda s: s.shown_index)
    ]
    return _compact(items)


def system_text(container: Container, form: Literal["eval", "train"] = "eval") -> str:
    return SYSTEM_TEMPLATE.replace("{container_json}", container_json(container, form))


def user_text(shown: Sequence[ShownItem]) -> str:
    return USER_TEMPLATE.replace("{buffer_objects_json}", buffer_json(shown))


def answer_text(action: Action) -> str:
    """An action as the reference's training targets spell it (keys in :data:`ANSWER_KEYS`)."""
    return _compact(
        {"object_id": action.object_id, "x": action.x, "y": action.y, "rotation": action.rotation}
    )


def heightmap_image(heightmap: np.ndarray, container: Container) -> Image.Image:
    """The reference's observation image of an (x_cells, y_cells) mm heightmap (RGB, 224 px)."""
    h = np.asarray(heightmap, dtype=np.float64)
    norm = np.clip(h / (COLOUR_HEIGHT_RATIO * container.height_mm), 0.0, 1.0)
    occupied = h > 0
    img = np.zeros((*h.shape, 3), dtype=np.uint8)
    img[..., 0] = np.where(occupied, (norm * 255).astype(np.uint8), 0)
    img[..., 2] = np.where(occupied, ((1.0 - norm) * 255).astype(np.uint8), 255)
    return Image.fromarray(img).resize((IMAGE_SIZE, IMAGE_SIZE), Image.Resampling.NEAREST)


def derived_seed(material: str) -> int:
    """The reference's seed derivation: the first 16 hex digits of a SHA-256."""
    return int(hashlib.sha256(material.encode("utf-8")).hexdigest()[:16], 16)


def _user_message(text: str, image_part: dict[str, Any] | None) -> dict[str, Any]:
    if image_part is None:  # no image: the literal goes too
        return {"role": "user", "content": text.replace("<image>", "", 1).lstrip()}
    return {"role": "user", "content": [image_part, {"type": "text", "text": text}]}


def select_history(
    messages: list[dict[str, Any]],
    mode: ReferenceHistory,
    sample_id: str = "",
    step: int = 0,
    seed: int = 0,
) -> list[dict[str, Any]]:
    """The request's view of the dialogue (system, user/assistant turns, the current user turn)
    under one of the reference's history modes."""
    if mode == "full":
        return list(messages)
    system = [m for m in messages if m["role"] == "system"]
    if mode == "current_only":
        users = [m for m in messages if m["role"] == "user"]
        return system + users[-1:]
    if mode == "no_assistant":
        return [m for m in messages if m["role"] != "assistant"]
    if mode == "shuffled_assistant_actions":
        answers = [m["content"] for m in messages if m["role"] == "assistant"]
        if len(answers) <= 1:
            return list(messages)
        random.Random(derived_seed(f"{seed}:{sample_id}:{step}:assistant_shuffle")).shuffle(answers)
        shuffled = iter(answers)
        return [
            dict(m, content=next(shuffled)) if m["role"] == "assistant" else m for m in messages
        ]
    raise ValueError(f"history mode {mode!r}: not one of the reference's")


def past_answer(action: Action | Unparsable) -> str:
    """A past step's assistant text when the model's raw words are not at hand."""
    return action.text if isinstance(action, Unparsable) else answer_text(action)


def dialogue(
    obs: Observation,
    image_part: Callable[[np.ndarray], dict[str, Any] | None],
    raw_answers: Sequence[str] | None = None,
) -> list[dict[str, Any]]:
    """The whole dialogue up to the current user turn (full history, no prefill).

    ``image_part(heightmap)`` gives a user turn's image content part (an OpenAI ``image_url``
    part for a server, a Hugging Face ``image`` part for a local model), or None for none.
    ``raw_answers`` are the model's past answers, one per past step, as it wrote them (the
    reference's history holds raw text); without them past actions are spelled by
    :func:`past_answer`.
    """
    answers = (
        list(raw_answers)
        if raw_answers is not None and len(raw_answers) == len(obs.history)
        else [past_answer(h.action) for h in obs.history]
    )
    messages: list[dict[str, Any]] = [{"role": "system", "content": system_text(obs.container)}]
    for entry, answer in zip(obs.history, answers):
        messages.append(_user_message(user_text(entry.shown), image_part(entry.heightmap)))
        messages.append({"role": "assistant", "content": answer})
    messages.append(_user_message(user_text(obs.shown), image_part(obs.heightmap)))
    return messages


def with_prefill(messages: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The request's messages: the dialogue view plus the thinking prefill."""
    return [*messages, {"role": "assistant", "content": THINKING_PREFILL}]


__all__ = [
    "ANSWER_KEYS",
    "COLOUR_HEIGHT_RATIO",
    "EXTRA_BODY",
    "IMAGE_SIZE",
    "SAMPLING",
    "ReferenceHistory",
    "ReferenceImage",
    "answer_text",
    "buffer_json",
    "container_json",
    "derived_seed",
    "dialogue",
    "heightmap_image",
    "past_answer",
    "select_history",
    "system_text",
    "user_text",
    "with_prefill",
]
