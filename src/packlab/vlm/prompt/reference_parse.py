"""Model text -> action the way the reference implementation reads it, and what its evaluation
does with an answer it cannot use (pure; no torch).

Reading (:func:`parse_reference`):

1. reasoning is removed: every ``<think ...>...</think>`` block, or, when there is none but a
   ``</think>`` occurs, everything up to the first one (the opening tag sat in the prompt);
2. the whole remaining text is decoded as JSON (format event ``strict_json``; surrounding
   whitespace is allowed); failing that, the span from the first ``{`` to the last ``}``
   (``extra_text``: code fences and chatter around one object land here); failing that, the
   answer is a ``parse_fail`` with error ``json_parse_failed``;
3. ``object_id``, ``x``, ``y`` and ``rotation`` (default 0) are converted with ``int()``, so
   ``"3"`` and ``2.7`` are accepted as 3 and 2; a missing key or a value ``int()`` refuses gives
   ``missing_or_invalid_field``, a rotation other than 0 or 1 ``invalid_rotation``.

This is looser than packlab's own parser (:mod:`.parse`) on purpose: the point is to score a
model the way its authors did. Two guards are packlab's own, for answers the reference would
crash on or spend long on: an answer over :data:`MAX_ANSWER_CHARS` characters, and a number
``int()`` cannot convert (infinity, a 5000-digit integer), are parse failures.

What the evaluation does with a failure (:func:`forced_set_aside`): in its relaxed mode an
answer that does not parse, or names an object id outside the shown buffer, sets aside a shown
object drawn at random with a seed derived from (seed, sample id, step, reason). Its strict
mode plays ``{object_id: -1, x: 0, y: 0, rotation: 0}`` instead, an invalid action that places
nothing (:data:`FALLBACKS`; packlab records it as an invalid ``unparsable`` step).
"""

from __future__ import annotations

import json
import random
import re
from dataclasses import dataclass
from typing import Any, Literal

from packlab.core.records import FormatEvent
from packlab.core.types import Action
from packlab.vlm.prompt.reference import derived_seed

ParseError = Literal["json_parse_failed", "missing_or_invalid_field", "invalid_rotation"]
#: Why an answer was replaced by a forced set-aside.
ForcedReason = Literal["parse_fail", "invalid_object_id"]
#: What is played in place of an answer that does not parse: a forced set-aside of a random
#: shown box (``set_aside``, the reference's relaxed mode, which its benchmark configuration
#: uses) or an invalid step that places nothing (``invalid``, its strict mode).
Fallback = Literal["set_aside", "invalid"]
FALLBACKS: tuple[Fallback, ...] = ("set_aside", "invalid")

#: Longest answer read (reasoning included); the reference asks for at most 512 tokens.
MAX_ANSWER_CHARS = 64 * 1024
#: The reference evaluation's ``placement.forced_outside_seed``.
FORCED_SEED = 42

_THINK_BLOCK = re.compile(r"<think\b[^>]*>.*?</think>", re.DOTALL | re.IGNORECASE)
_THINK_CLOSE = re.compile(r"</think>", re.IGNORECASE)
_FIRST_OBJECT = re.compile(r"\{.*\}", re.DOTALL)


@dataclass(frozen=True, slots=True)
class ReferenceParse:
    """One answer read the reference's way."""

    action: Action | None  # None when the answer is not usable
    error: ParseError | None
    strict_json: bool  # the whole (reasoning-free) text was the JSON
    think_stripped: bool

    @property
    def event(self) -> FormatEvent:
        """The reference's per-step format event."""
        if self.action is None:
            return "parse_fail"
        return "strict_json" if self.strict_json else "extra_text"


def strip_think(text: str) -> tuple[str, bool]:
    """(text without reasoning, whether anything was removed)."""
    stripped = _THINK_BLOCK.sub("", text)
    if stripped == text and "</think>" in text.lower():
        stripped = _THINK_CLOSE.split(text, maxsplit=1)[1]
    return stripped, stripped != text


def _loads(text: str) -> Any:
    try:
        return json.loads(text)
    except (ValueError, RecursionError):  # ValueError: also integers past Python's digit limit
        return None


def _decode(text: str) -> tuple[Any, bool]:
    """(decoded JSON or None, whether the whole text decoded)."""
    value = _loads(text)
    if value is not None:
        return value, True
    match = _FIRST_OBJECT.search(text)
    return (_loads(match.group(0)) if match else None), False


def parse_reference(text: str) -> ReferenceParse:
    """Read one answer as the reference's ``llm_json`` policy does (module docstring)."""
    if len(text) > MAX_ANSWER_CHARS:
        return ReferenceParse(None, "json_parse_failed", False, False)
    body, stripped = strip_think(text)
    value, strict = _decode(body)
    # JSON null decodes to None and is a failure there too (it has no fields to read).
    if value is None:
        return ReferenceParse(None, "json_parse_failed", False, stripped)
    try:
        fields = [value["object_id"], value["x"], value["y"], value.get("rotation", 0)]
        object_id, x, y, rotation = (int(v) for v in fields)
    except (KeyError, ValueError, TypeError, AttributeError, OverflowError):
        return ReferenceParse(None, "missing_or_invalid_field", strict, stripped)
    if rotation not in (0, 1):
        return ReferenceParse(None, "invalid_rotation", strict, stripped)
    return ReferenceParse(Action(object_id, rotation, x, y), None, strict, stripped)


def forced_set_aside(
    n_shown: int, sample_id: str, step: int, reason: ForcedReason, seed: int = FORCED_SEED
) -> int:
    """The shown index the reference's relaxed evaluation discards in place of an unusable
    answer: ``random.Random(sha256("seed:sample_id:step:reason")[:16 hex]).randrange(n)``."""
    if n_shown < 1:
        raise ValueError("no shown object to set aside")
    rng = random.Random(derived_seed(f"{seed}:{sample_id}:{step}:{reason}"))
    return rng.randrange(n_shown)


__all__ = [
    "FALLBACKS",
    "FORCED_SEED",
    "MAX_ANSWER_CHARS",
    "Fallback",
    "ForcedReason",
    "FormatEvent",
    "ParseError",
    "ReferenceParse",
    "forced_set_aside",
    "parse_reference",
    "strip_think",
]
