"""Context rendering for the packing VLM: (container, past turns, current turn) -> chat messages.

This is the single definition of what the model reads. The data engine's SFT export, the trainer
and the inference policies all call :func:`render_messages`, so training and inference cannot
drift apart; any change to the wording or layout must bump :data:`PROMPT_VERSION` (checkpoints
record it, and the golden tests in tests/vlm pin the output).

Messages follow the Hugging Face multimodal chat format::

    {"role": "user", "content": [{"type": "image", "image": ...}, {"type": "text", "text": ...}]}

The ``image`` value is whatever the caller put in :class:`TurnState` (a relative path string in a
dataset, a PIL image at inference); this module never opens or inspects it. Pure: no torch, no
I/O.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from PIL import Image

from packlab.core.choices import HistoryMode, ImageMode, require_choice
from packlab.core.types import Action, Container, Observation, ShownItem, Unparsable

#: Bump on any change to the rendered text or message layout (golden tests pin the version).
#: v2: the answer puts rotation before the coordinates it decides (v1: object_id, x, y, rotation).
#: Candidate mode's compact text (:mod:`.compact`) shares this version.
PROMPT_VERSION = "packlab-prompt-v2"

#: Stand-in put in image entries under ``image="blank"`` when the caller gives no blank image.
#: The processor (vlm/data/encoding.py) replaces it by an all-zero image of the configured size,
#: so a dataset can carry the ablation without storing blank PNGs.
BLANK_IMAGE = "packlab:blank"

# Compact JSON everywhere: long histories cost tokens, and one canonical spelling keeps the
# assistant target identical between the SFT export and what the parser round-trips.
_JSON_SEPARATORS = (",", ":")


@dataclass(frozen=True, slots=True)
class PromptOptions:
    """Ablation switches of the paper: which parts of the context the model gets."""

    history: HistoryMode = (
        "full"  # full | current_only (no past turns) | no_actions (no past answers)
    )
    image: ImageMode = (
        "heightmap"  # heightmap | blank (uninformative image) | none (no image entries)
    )

    def __post_init__(self) -> None:
        # ConfigError is a ValueError: callers that catch ValueError keep working.
        require_choice(self.history, HistoryMode, "PromptOptions.history")
        require_choice(self.image, ImageMode, "PromptOptions.image")

    def to_dict(self) -> dict[str, str]:
        return {"history": self.history, "image": self.image}


@dataclass(frozen=True, slots=True)
class TurnState:
    """What one user turn shows: the heightmap image, the shown buffer and progress counters."""

    image: Any  # opaque to this module: relative path (datasets) or PIL image (inference)
    shown: tuple[ShownItem, ...]
    step_index: int  # 0-based index of the step this turn asks for
    remaining: int | None  # objects not yet processed, the shown ones included; None: hidden


def action_text(action: Action) -> str:
    """The exact assistant target for ``action``: compact JSON with keys in a fixed order.

    The rotation comes before x and y: it sets the footprint that the coordinates must fit, so a
    model that writes left to right decides it first.
    """
    return json.dumps(
        {
            "object_id": int(action.object_id),
            "rotation": int(action.rotation),
            "x": int(action.x),
            "y": int(action.y),
        },
        separators=_JSON_SEPARATORS,
    )


def buffer_json(shown: Sequence[ShownItem]) -> str:
    """The shown buffer as compact JSON with sizes in cells.

    l and w are xy cells at rotation 0, h is z cells; items are listed by their shown index.
    """
    items = [
        {
            "object_id": s.shown_index,
            "l": s.size_cells[0],
            "w": s.size_cells[1],
            "h": s.size_cells[2],
        }
        for s in sorted(shown, key=lambda s: s.shown_index)
    ]
    return json.dumps(items, separators=_JSON_SEPARATORS)


#: The system-prompt line about images (absent under ``image="none"``). It describes the picture
#: that packlab.sim.raster.heightmap_to_image draws; keep the two in step.
IMAGE_LINE = (
    "Each user turn shows the container's current heightmap as a top-down image: x runs left to "
    "right along the columns, y top to bottom along the rows, cell (0, 0) is the top-left cell, "
    "and stronger grid lines mark every 5 cells. Colour shows height, from dark slate (the floor) "
    "through blue, green and yellow to pale yellow at the rim, and red above the rim."
)


def system_prompt(container: Container, options: PromptOptions = PromptOptions()) -> str:
    """Task, grid, coordinate convention, drop rule and output format."""
    nx, ny = container.cells
    nz = container.height_mm // container.cell_z_mm
    lines = [
        (
            "You are the planner of a robot that packs boxes into an open-top container. Boxes "
            "arrive in a fixed order; at each step you see a buffer of the next few boxes, pick "
            "one of them and say where to put it. Goal: as many boxes as possible inside the "
            "container, packed tightly and low."
        ),
        (
            f"Container: {nx} x {ny} cells on the floor grid (one cell is "
            f"{container.cell_xy_mm} mm), {nz} height units deep (one height unit is "
            f"{container.cell_z_mm} mm)."
        ),
        (
            f"Coordinates: x runs along the container's first dimension (0 to {nx - 1}), y along "
            f"the second (0 to {ny - 1}); cell (0, 0) is the corner at the container origin."
        ),
        (
            'Buffer items: "object_id" is the item\'s index in the buffer; "l" (along x) and "w" '
            '(along y) are its footprint in cells at rotation 0, "h" its height in height units. '
            "Rotation 1 turns the box 90 degrees about the vertical axis, which swaps l and w."
        ),
        (
            "Placement: (x, y) is the footprint's minimum cell, so the box covers cells x to "
            "x+l-1 and y to y+w-1 (l and w swapped at rotation 1), which must lie inside the "
            "container. The box is dropped from above: its bottom rests at the maximum height of "
            "the heightmap under its footprint."
        ),
    ]
    if options.image != "none":
        lines.append(IMAGE_LINE)
    lines.append(
        "Answer with exactly one JSON object and nothing else: "
        '{"object_id": <int>, "rotation": <0 or 1>, "x": <int>, "y": <int>}'
    )
    return "\n".join(lines)


def user_text(turn: TurnState) -> str:
    """The text part of one user turn."""
    return (
        f"Step {turn.step_index + 1}. Objects left (buffer included): {_count(turn.remaining)}. "
        f"Buffer: {buffer_json(turn.shown)}"
    )


def _count(remaining: int | None) -> str:
    """A remaining count as the prompt says it ("unknown" where the run hides it)."""
    return "unknown" if remaining is None else str(remaining)


def _assistant_text(action: Action | Unparsable) -> str:
    # A past answer that did not parse is shown as the model said it: that is the true history.
    return action.text if isinstance(action, Unparsable) else action_text(action)


def _user_message(turn: TurnState, options: PromptOptions, blank: Any) -> dict[str, Any]:
    content: list[dict[str, Any]] = []
    if options.image == "heightmap":
        content.append({"type": "image", "image": turn.image})
    elif options.image == "blank":
        content.append({"type": "image", "image": blank})
    content.append({"type": "text", "text": user_text(turn)})
    return {"role": "user", "content": content}


def render_messages(
    container: Container,
    past: Sequence[tuple[TurnState, Action | Unparsable]],
    current: TurnState,
    options: PromptOptions = PromptOptions(),
    blank: Any = BLANK_IMAGE,
) -> list[dict[str, Any]]:
    """The context X_t = (system, S_1, a_1, ..., S_{t-1}, a_{t-1}, S_t) as chat messages.

    ``blank`` is what image entries hold under ``image="blank"``: pass :func:`blank_like` of a
    real image, or keep the :data:`BLANK_IMAGE` marker for the processor to resolve.
    The result ends with the current user turn; the trainer appends ``action_text(target)``.
    """
    messages: list[dict[str, Any]] = [
        {"role": "system", "content": [{"type": "text", "text": system_prompt(container, options)}]}
    ]
    if options.history != "current_only":
        for turn, action in past:
            messages.append(_user_message(turn, options, blank))
            if options.history == "full":
                messages.append(
                    {
                        "role": "assistant",
                        "content": [{"type": "text", "text": _assistant_text(action)}],
                    }
                )
    messages.append(_user_message(current, options, blank))
    return messages


def ablate(
    messages: Sequence[dict[str, Any]], options: PromptOptions, blank: Any = BLANK_IMAGE
) -> list[dict[str, Any]]:
    """Turn a context rendered with the default options (full history, heightmap images) into the
    one ``render_messages`` gives for ``options``, without the underlying states.

    This lets one SFT export (always rendered in full) feed every ablation at training time.
    The context must end with the current user turn (split the target answer off first).
    """
    msgs = [dict(m, content=list(m["content"])) for m in messages]
    if not msgs or msgs[0]["role"] != "system" or msgs[-1]["role"] != "user":
        raise ValueError(
            "expected a context that starts with the system turn and ends with a user turn"
        )
    if options.history == "current_only":
        msgs = [msgs[0], msgs[-1]]
    elif options.history == "no_actions":
        msgs = [m for m in msgs if m["role"] != "assistant"]
    if options.image != "heightmap":
        for m in msgs[1:]:
            if m["role"] != "user":
                continue
            if options.image == "blank":
                m["content"] = [
                    dict(c, image=blank) if c["type"] == "image" else c for c in m["content"]
                ]
            else:
                m["content"] = [c for c in m["content"] if c["type"] != "image"]
    if options.image == "none":
        text = msgs[0]["content"][0]["text"]
        if IMAGE_LINE + "\n" not in text:
            raise ValueError("the system prompt does not carry this prompt version's image line")
        msgs[0]["content"] = [{"type": "text", "text": text.replace(IMAGE_LINE + "\n", "")}]
    return msgs


def drop_oldest_step(messages: Sequence[dict[str, Any]]) -> list[dict[str, Any]] | None:
    """``messages`` without the oldest past step (user turn and answer); None if there is none.

    Works for every history ablation: a past step is a user turn followed by an optional
    assistant turn; the system message and the final (current) user turn are kept.
    """
    msgs = list(messages)
    start = 1 if msgs and msgs[0]["role"] == "system" else 0
    if len(msgs) - start <= 1:
        return None
    end = start + 1
    if end < len(msgs) - 1 and msgs[end]["role"] == "assistant":
        end += 1
    return msgs[:start] + msgs[end:]


def keep_last_steps(messages: Sequence[dict[str, Any]], n: int) -> list[dict[str, Any]]:
    """``messages`` with only the ``n`` most recent past steps (the rule of
    :func:`drop_oldest_step`, applied until at most ``n`` remain)."""
    if n < 0:
        raise ValueError(f"n = {n}: must be >= 0")
    msgs = list(messages)
    start = 1 if msgs and msgs[0]["role"] == "system" else 0
    # Every past step has one user turn; the last user turn is the current state.
    while sum(m["role"] == "user" for m in msgs[start:]) - 1 > n:
        shorter = drop_oldest_step(msgs)
        assert shorter is not None  # a past step exists here
        msgs = shorter
    return msgs


def split_target(messages: Sequence[dict[str, Any]]) -> tuple[list[dict[str, Any]], str]:
    """(context, answer text) of an SFT example whose last turn is the assistant's target."""
    if not messages or messages[-1]["role"] != "assistant":
        raise ValueError("an SFT example must end with the assistant's target turn")
    texts = [c["text"] for c in messages[-1]["content"] if c.get("type") == "text"]
    if len(texts) != 1:
        raise ValueError("the target turn must hold exactly one text entry")
    return list(messages[:-1]), texts[0]


def with_answer(messages: list[dict[str, Any]], action: Action) -> list[dict[str, Any]]:
    """``messages`` plus the assistant target turn (the SFT example for this step)."""
    return [
        *messages,
        {"role": "assistant", "content": [{"type": "text", "text": action_text(action)}]},
    ]


def render_conversation(
    container: Container, turns: Sequence[TurnState], actions: Sequence[Action]
) -> list[dict[str, Any]]:
    """A whole episode (or a window of it) as one conversation: the system turn, then a user
    turn and the assistant's answer for every step. Each assistant turn is a training target; the
    context in front of answer t is exactly :func:`render_messages` of the steps before it."""
    if not turns or len(turns) != len(actions):
        raise ValueError(f"{len(turns)} turns and {len(actions)} actions: need as many, >= 1")
    past = list(zip(turns[:-1], actions[:-1]))
    return with_answer(render_messages(container, past, turns[-1]), actions[-1])


def blank_like(image: Any) -> Any:
    """An all-zero image of the same size and mode as ``image`` (PIL image or numpy array).

    A string (dataset path) has no size here, so it maps to the :data:`BLANK_IMAGE` marker,
    which the processor resolves at its configured image size.
    """
    if isinstance(image, str):
        return BLANK_IMAGE
    if hasattr(image, "shape") and hasattr(image, "dtype"):  # numpy array
        return np.zeros_like(image)
    return Image.new(image.mode, image.size)


def turns_from_observation(
    obs: Observation, render_image: Callable[[Any], Any]
) -> tuple[list[tuple[TurnState, Action | Unparsable]], TurnState]:
    """(past, current) for :func:`render_messages` from a policy observation.

    ``render_image(heightmap)`` turns an (x_cells, y_cells) int32 mm heightmap into the image the
    caller wants in the messages (e.g. ``packlab.sim.raster.heightmap_to_image``). Remaining
    counts and step indices of past turns are reconstructed: every step processes exactly one
    object and the history holds every past step.
    """
    n_past = len(obs.history)
    past = [
        (
            TurnState(
                image=render_image(h.heightmap),
                shown=h.shown,
                step_index=obs.step_index - n_past + i,
                remaining=None if obs.remaining is None else obs.remaining + (n_past - i),
            ),
            h.action,
        )
        for i, h in enumerate(obs.history)
    ]
    current = TurnState(
        image=render_image(obs.heightmap),
        shown=obs.shown,
        step_index=obs.step_index,
        remaining=obs.remaining,
    )
    return past, current
