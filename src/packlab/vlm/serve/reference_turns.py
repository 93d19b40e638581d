"""One episode of the reference's prompt protocol on the client side: which messages each request
carries, and which action an answer becomes (stdlib, numpy and PIL; no torch).

The rendering and the reading are :mod:`packlab.vlm.prompt.reference` and
:mod:`packlab.vlm.prompt.reference_parse`; this module keeps what they need across steps: the
model's raw answers (the reference's history holds them unparsed), the image data URLs (each
heightmap is encoded once per episode), and the case's sample id (it seeds the forced
set-aside). ``fallback`` picks what an answer that does not parse becomes: the relaxed mode's
forced set-aside (``set_aside``, default) or the strict mode's invalid action (``invalid``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from PIL import Image

from packlab.core.choices import HistoryMode, ImageMode
from packlab.core.errors import ConfigError
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Case, Container, Observation, Unparsable
from packlab.vlm.prompt.reference import (
    IMAGE_SIZE,
    ReferenceHistory,
    dialogue,
    heightmap_image,
    select_history,
    with_prefill,
)
from packlab.vlm.prompt.reference_parse import (
    FALLBACKS,
    FORCED_SEED,
    MAX_ANSWER_CHARS,
    Fallback,
    ForcedReason,
    ReferenceParse,
    forced_set_aside,
)
from packlab.vlm.prompt.reference_template import REASK_PROMPT
from packlab.vlm.serve.openai_messages import png_data_url

#: packlab's ``history`` option -> the reference's history mode.
HISTORY_MODES: dict[str, ReferenceHistory] = {
    "full": "full",
    "current_only": "current_only",
    "no_actions": "no_assistant",
}


def sample_id(case: Case) -> str:
    """The id the reference's evaluation knows a case by: the benchmark row's ``index`` for a
    case read from the reference's files (its rows carry no episode id), else packlab's id."""
    if case.origin is not None and case.origin.index is not None:
        return str(case.origin.index)
    return case.episode_id


def openai_image(image: Image.Image) -> dict[str, Any]:
    """An image as an OpenAI content part (PNG data URL), as the reference's client sends it."""
    return {"type": "image_url", "image_url": {"url": png_data_url(image)}}


def local_image(image: Image.Image) -> dict[str, Any]:
    """An image as a Hugging Face content part, for a model run in this process."""
    return {"type": "image", "image": image}


@dataclass(frozen=True, slots=True)
class Decision:
    """What one answer became: the action played and the labels the step log records."""

    action: Action | Unparsable  # Unparsable: fallback="invalid" after an unreadable answer
    event: str  # strict_json | extra_text | parse_fail
    error: str | None  # the parse error, or invalid_object_id
    forced: ForcedReason | None  # why the action is a forced set-aside, if it is


class ReferenceTurns:
    """Per-episode state of the protocol; :meth:`reset` at every episode."""

    def __init__(
        self,
        history: HistoryMode = "full",
        image: ImageMode = "heightmap",
        forced_seed: int = FORCED_SEED,
        image_part: Callable[[Image.Image], dict[str, Any]] = openai_image,
        fallback: Fallback = "set_aside",
    ) -> None:
        check_fallback(fallback)
        self.fallback = fallback
        self.history: ReferenceHistory = HISTORY_MODES[history]
        self.image = image
        self.forced_seed = forced_seed
        self.image_part = image_part
        self.sample_id = ""
        self.raw_answers: list[str] = []
        self._parts: dict[tuple, dict[str, Any]] = {}

    def reset(self, case: Case | EpisodeStart) -> None:
        """A new episode. The relaxed mode's forced set-aside is seeded by the case's sample id,
        so it needs the case; the strict mode is handed only the episode's start."""
        if reads_sample_id("reference", self.fallback) and not isinstance(case, Case):
            raise TypeError("the relaxed mode's forced set-aside needs the case's sample id")
        self.sample_id = sample_id(case) if isinstance(case, Case) else ""
        self.raw_answers = []
        self._parts = {}

    def _image(self, heightmap: np.ndarray, container: Container) -> dict[str, Any] | None:
        """A heightmap's content part, made once per distinct heightmap and episode (the
        container is fixed within an episode, so the heightmap alone is the key)."""
        if self.image == "none":
            return None
        hm = np.ascontiguousarray(heightmap)
        # The reference's blank: an all-zero image of the same size.
        key = ("blank",) if self.image == "blank" else (hm.shape, str(hm.dtype), hm.tobytes())
        part = self._parts.get(key)
        if part is None:
            image = (
                Image.new("RGB", (IMAGE_SIZE, IMAGE_SIZE))
                if self.image == "blank"
                else heightmap_image(hm, container)
            )
            part = self._parts[key] = self.image_part(image)
        return part

    def view(self, obs: Observation) -> list[dict[str, Any]]:
        """The dialogue as this step's request shows it (history mode applied, no prefill)."""
        messages = dialogue(obs, lambda hm: self._image(hm, obs.container), self.raw_answers)
        return select_history(messages, self.history, self.sample_id, obs.step_index)

    @staticmethod
    def request(view: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return with_prefill(view)

    @staticmethod
    def reask(view: list[dict[str, Any]], raw: str) -> list[dict[str, Any]]:
        """The second request after an unusable answer: the answer, then the JSON-only ask."""
        return [
            *view,
            {"role": "assistant", "content": raw},
            {"role": "user", "content": REASK_PROMPT},
        ]

    def decide(self, obs: Observation, raw: str, parsed: ReferenceParse) -> Decision:
        """The action the reference's evaluation plays for the final answer ``raw``: in its
        relaxed mode (``fallback="set_aside"``) a forced set-aside replaces an answer that does
        not parse or names an object outside the buffer; in its strict mode (``"invalid"``) an
        answer that does not parse is an invalid step (an ``Unparsable`` carrying the answer and
        the parse error) and any action is played as it is."""
        self.raw_answers.append(raw)
        action = parsed.action
        if action is not None and 0 <= action.object_id < len(obs.shown):
            return Decision(action, parsed.event, None, None)
        if self.fallback == "invalid":
            # The episode records it: an ``unparsable`` step, or a ``bad_object_id`` one.
            if action is None:
                assert parsed.error is not None  # no action: the parser says why
                unread = Unparsable(raw[:MAX_ANSWER_CHARS], parsed.error)
                return Decision(unread, parsed.event, parsed.error, None)
            return Decision(action, parsed.event, "invalid_object_id", None)
        reason: ForcedReason = "parse_fail" if action is None else "invalid_object_id"
        k = forced_set_aside(
            len(obs.shown), self.sample_id, obs.step_index, reason, self.forced_seed
        )
        error = parsed.error if action is None else "invalid_object_id"
        return Decision(Action.set_aside(k), parsed.event, error, reason)

    def record_failure(self, text: str) -> None:
        """A step that got no answer (a refused request): an empty turn keeps the history
        aligned with the episode's steps."""
        self.raw_answers.append(text)


def reads_sample_id(prompt: str, fallback: str) -> bool:
    """Whether a policy under ``prompt`` and ``fallback`` needs the case at reset: the reference's
    relaxed mode seeds its forced set-aside by the case's sample id."""
    return prompt == "reference" and fallback == "set_aside"


def check_fallback(fallback: object, prompt: str = "reference") -> None:
    """ConfigError (one line) for a ``fallback`` the prompt protocol cannot take: one of
    :data:`FALLBACKS`, and ``invalid`` only with ``prompt=reference`` (packlab's own prompt
    always records an answer it cannot read as an invalid ``unparsable`` step)."""
    if fallback not in FALLBACKS:
        raise ConfigError(f"fallback = {fallback!r}: choose one of {', '.join(FALLBACKS)}")
    if fallback != "set_aside" and prompt != "reference":
        raise ConfigError(
            f"fallback = {fallback!r}: applies to prompt=reference only (prompt = {prompt!r} "
            "records an answer it cannot read as an invalid unparsable step)"
        )


__all__ = [
    "HISTORY_MODES",
    "Decision",
    "ReferenceTurns",
    "check_fallback",
    "local_image",
    "openai_image",
    "reads_sample_id",
    "sample_id",
]
