"""Candidate-mode examples composed from labelled states, lazily (at training time) or as an export.

The trainer reads :mod:`.states` files and builds each example's chat messages here when it
needs them; :func:`export_chat_jsonl` writes the very same messages plus the answer as the
paper-style chat JSONL (``{"messages": [system, user, assistant]}``) for other trainers. One
function builds the messages for both, so they cannot drift apart (a test checks the tokens).

``instructions``: ``"full"`` is :func:`packlab.vlm.prompt.compact.system_text` (the task and a
legend of every field, about 250 tokens, for a pretrained model that reads instructions);
``"short"`` is one line with the container (about 20 tokens): a model trained from random
weights learns the fields from data, and every step then costs only its state.

``map`` (:data:`packlab.core.choices.PointerMap`): ``"text"`` writes the heightmap as the digit
map; ``"image"`` and ``"blank"`` put one image entry (``{"type": "image"}``, which the chat
template writes as ``<|vision_start|><|image_pad|><|vision_end|>``) before the user text and
leave the digit map out; ``"both"`` shows the image and the digit map. The image itself is made
by :mod:`.image` when the prompt is encoded (:mod:`.pointer`).

``line_fields`` (:data:`packlab.core.choices.LineFields`): ``"full"`` writes each listed line
as :func:`packlab.vlm.prompt.compact.candidate_line` (box, rotation, cell, then the resting
height z, support s, flushness f and gap v the proposer computed from the heightmap);
``"cell"`` (:func:`cell_line`) keeps the index, box, rotation and cell only, so nothing about
the container's surface reaches the model except through the map it is shown.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from packlab.core.choices import LineFields, PointerMap, PromptInstructions, choices
from packlab.core.errors import ConfigError
from packlab.core.types import Container, Observation
from packlab.policies.candidates import Candidate
from packlab.vlm.candidate.states import LabelledState, listed_of, observation_of
from packlab.vlm.prompt.compact import CompactOptions, candidate_line, state_text, system_text
from packlab.vlm.prompt.render import PROMPT_VERSION, action_text

Instructions = PromptInstructions
INSTRUCTIONS: tuple[str, ...] = choices(PromptInstructions)
#: The answer: the listed index (candidate mode) or the chosen placement as free JSON, rotation
#: first (:func:`packlab.vlm.prompt.render.action_text`), generated token by token (the
#: format ablation: the same states and labels, only the answer's form changes).
Answer = Literal["index", "json"]
ANSWERS: tuple[str, ...] = ("index", "json")
MAPS: tuple[str, ...] = choices(PointerMap)
#: The map modes that show the heightmap as an image (``"blank"``: an all-zero one).
IMAGE_MAPS = ("image", "both", "blank")
DEFAULT_OPTIONS = CompactOptions()
LINE_FIELDS: tuple[str, ...] = choices(LineFields)


def cell_line(c: Candidate) -> str:
    """A listed placement without geometry: its index, box, rotation and cell."""
    return f"{c.index}: b{c.object_index} r{c.rotation} x{c.x} y{c.y}"


def line_text(c: Candidate, line_fields: LineFields = "full") -> str:
    """The text of one listed line under ``line_fields`` (module docstring)."""
    if line_fields == "cell":
        return cell_line(c)
    if line_fields != "full":
        raise ConfigError(f"line_fields = {line_fields!r}: expected one of {LINE_FIELDS}")
    return candidate_line(c)


def _with_lines(user: str, listed: Sequence[Candidate], line_fields: LineFields) -> str:
    """The user turn with its listed lines (its last ``len(listed)`` lines) in ``line_fields``."""
    if line_fields == "full" or not listed:
        return user
    lines = user.split("\n")
    lines[-len(listed) :] = [line_text(c, line_fields) for c in listed]
    return "\n".join(lines)


def short_system_text(container: Container) -> str:
    nx, ny = container.cells
    return f"Pack boxes. Container {nx} x {ny} cells, rim {round(container.height_mm / 10)} cm."


def observation_messages(
    observation: Observation,
    listed: Sequence[Candidate],
    instructions: Instructions = "short",
    options: CompactOptions = DEFAULT_OPTIONS,
    blank_map: bool = False,
    map: PointerMap = "text",
    line_fields: LineFields = "full",
) -> list[dict[str, Any]]:
    """[system, user] messages of one step; ``blank_map`` shows an empty heightmap (ablation:
    the model then sees the boxes and the listed placements but not the container's surface),
    ``map`` how the heightmap is shown, ``line_fields`` what each listed line names (module
    docstring)."""
    if instructions not in INSTRUCTIONS:
        raise ConfigError(f"instructions = {instructions!r}: expected one of {INSTRUCTIONS}")
    if map not in MAPS:
        raise ConfigError(f"map = {map!r}: expected one of {MAPS}")
    if blank_map:
        observation = replace(observation, heightmap=np.zeros_like(observation.heightmap))
    container = observation.container
    system = (
        system_text(container, options, image_map=map in IMAGE_MAPS and map != "both")
        if instructions == "full"
        else short_system_text(container)
    )
    user = state_text(observation, listed, options, show_map=map in ("text", "both"))
    user = _with_lines(user, listed, line_fields)
    image = [{"type": "image"}] if map in IMAGE_MAPS else []
    return [
        {"role": "system", "content": [{"type": "text", "text": system}]},
        {"role": "user", "content": [*image, {"type": "text", "text": user}]},
    ]


def state_messages(
    state: LabelledState,
    instructions: Instructions = "short",
    options: CompactOptions = DEFAULT_OPTIONS,
    blank_map: bool = False,
    map: PointerMap = "text",
    line_fields: LineFields = "full",
) -> list[dict[str, Any]]:
    """:func:`observation_messages` of a stored state (what training and the export read)."""
    return observation_messages(
        observation_of(state), listed_of(state), instructions, options, blank_map, map,
        line_fields,
    )  # fmt: skip


def answer_text(state: LabelledState, answer: Answer = "index") -> str:
    """The assistant target of a labelled state (label >= 0)."""
    if answer == "json":
        return action_text(listed_of(state)[state.label].action)
    return str(state.label)


def answer_message(state: LabelledState, answer: Answer = "index") -> dict[str, Any]:
    return {"role": "assistant", "content": [{"type": "text", "text": answer_text(state, answer)}]}


def export_chat_jsonl(
    states: Iterable[LabelledState],
    out: Path,
    instructions: Instructions = "short",
    options: CompactOptions = DEFAULT_OPTIONS,
    answer: Answer = "index",
) -> int:
    """Write each labelled state (label >= 0) as one chat example; the number written."""
    n = 0
    with open(out, "w") as f:
        for s in states:
            if s.label < 0:
                continue
            row = {
                "messages": [*state_messages(s, instructions, options), answer_message(s, answer)],
                "episode_id": s.case_id,
                "difficulty": s.difficulty,
                "step_index": s.step,
                "teacher": s.teacher,
                "prompt_version": PROMPT_VERSION,
            }
            f.write(json.dumps(row) + "\n")
            n += 1
    return n
