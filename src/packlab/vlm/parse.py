"""Model text -> :class:`~packlab.types.Action`, tolerant of the usual wrapping, strict on content.

Tolerated wrapping (the reported ``case``):

- ``plain``: the whole text (after trimming whitespace) is the JSON object;
- ``fenced``: the object sits in a Markdown code fence (```json ... ``` or ``` ... ```);
- ``embedded``: the object is surrounded by other text;
- each of these prefixed ``think+`` when ``<think>...</think>`` reasoning came first (only the
  text after the last ``</think>`` is read, so drafts inside the reasoning never count; a lone
  ``</think>`` is accepted because Qwen3 chat templates put the opening tag in the prompt).

Strict content: exactly the keys ``object_id``, ``x``, ``y``, ``rotation``; integer values (not
bools, floats or strings); rotation 0 or 1; no duplicate keys; and one answer only (several
different JSON objects are ambiguous). Negative ids or coordinates parse: judging them against
the container is the episode's job (DESIGN.md section 4), not the parser's. Pure, no torch.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

from packlab.types import Action, Unparsable

ACTION_KEYS: tuple[str, ...] = ("object_id", "x", "y", "rotation")
BASE_CASES: tuple[str, ...] = ("plain", "fenced", "embedded")
#: Every value :attr:`ParseResult.case` can take.
PARSE_CASES: tuple[str, ...] = BASE_CASES + tuple(f"think+{c}" for c in BASE_CASES)

_THINK_OPEN = re.compile(r"<think>", re.IGNORECASE)
_THINK_CLOSE = re.compile(r"</think>", re.IGNORECASE)
# A fence: three backticks, an optional language tag, the body (non-greedy), three backticks.
_FENCE = re.compile(r"```[ \t]*[A-Za-z0-9_+.-]*[ \t]*\r?\n?(.*?)```", re.DOTALL)


class ActionParseError(ValueError):
    """The text holds no single well-formed action; ``reason`` says why in one line."""

    def __init__(self, reason: str, text: str):
        super().__init__(reason)
        self.reason = reason
        self.text = text


@dataclass(frozen=True, slots=True)
class ParseResult:
    action: Action
    case: str  # one of PARSE_CASES


class _DuplicateKey(ValueError):
    pass


def _no_duplicates(pairs: list[tuple[str, object]]) -> dict[str, object]:
    out: dict[str, object] = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


_DECODER = json.JSONDecoder(object_pairs_hook=_no_duplicates)


def _decode_whole(s: str) -> object | None:
    """The JSON value ``s`` is, or None when it is not exactly one JSON value."""
    try:
        value, end = _DECODER.raw_decode(s)
    except _DuplicateKey:
        raise
    except ValueError:
        return None
    return value if s[end:].strip() == "" else None


def _scan_objects(s: str) -> list[dict[str, object]]:
    """Every top-level JSON object in ``s``, left to right (nested ones belong to their parent)."""
    found: list[dict[str, object]] = []
    i = s.find("{")
    while i != -1:
        try:
            value, end = _DECODER.raw_decode(s, i)
        except _DuplicateKey:
            raise
        except ValueError:
            i = s.find("{", i + 1)
            continue
        if isinstance(value, dict):
            found.append(value)
        i = s.find("{", end)
    return found


def _to_action(obj: dict[str, object], text: str) -> Action:
    missing = [k for k in ACTION_KEYS if k not in obj]
    unknown = sorted(k for k in obj if k not in ACTION_KEYS)
    if missing:
        raise ActionParseError(f"missing key(s): {', '.join(missing)}", text)
    if unknown:
        raise ActionParseError(f"unknown key(s): {', '.join(unknown)}", text)
    for k in ACTION_KEYS:
        v = obj[k]
        # bool is an int subclass in Python; true/false is not a coordinate.
        if type(v) is not int:
            raise ActionParseError(f"{k} must be an integer, got {json.dumps(v)}", text)
    if obj["rotation"] not in (0, 1):
        raise ActionParseError(f"rotation must be 0 or 1, got {obj['rotation']}", text)
    return Action(object_id=obj["object_id"], rotation=obj["rotation"], x=obj["x"], y=obj["y"])  # type: ignore[arg-type]


def _single(objs: list[dict[str, object]], text: str) -> dict[str, object] | None:
    if not objs:
        return None
    first = objs[0]
    if any(o != first for o in objs[1:]):
        raise ActionParseError(f"ambiguous: {len(objs)} different JSON objects", text)
    return first


def parse_action(text: str) -> ParseResult:
    """Parse one model answer; raises :class:`ActionParseError` when it holds no single action."""
    if not isinstance(text, str):
        raise ActionParseError(f"expected text, got {type(text).__name__}", str(text))
    body, think = text, False
    closes = list(_THINK_CLOSE.finditer(body))
    if closes:
        body, think = body[closes[-1].end() :], True
    elif _THINK_OPEN.search(body):
        raise ActionParseError("unterminated <think> block", text)
    body = body.strip()
    if not body:
        raise ActionParseError("empty answer" + (" after </think>" if think else ""), text)
    prefix = "think+" if think else ""
    try:
        whole = _decode_whole(body)
        if isinstance(whole, dict):
            return ParseResult(_to_action(whole, text), prefix + "plain")
        if whole is not None:
            raise ActionParseError(f"expected a JSON object, got {type(whole).__name__}", text)
        fenced = [o for block in _FENCE.findall(body) for o in _scan_objects(block)]
        obj = _single(fenced, text)
        if obj is not None:
            return ParseResult(_to_action(obj, text), prefix + "fenced")
        obj = _single(_scan_objects(body), text)
        if obj is not None:
            return ParseResult(_to_action(obj, text), prefix + "embedded")
    except _DuplicateKey as e:
        raise ActionParseError(f"duplicate key: {e}", text) from None
    raise ActionParseError("no JSON object found", text)


def parse_or_unparsable(text: str) -> Action | Unparsable:
    """For policies: the action, or an :class:`Unparsable` carrying the text and the reason."""
    try:
        return parse_action(text).action
    except ActionParseError as e:
        return Unparsable(text=text, error=e.reason)
