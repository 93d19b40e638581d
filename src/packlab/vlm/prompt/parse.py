"""Model text -> :class:`~packlab.core.types.Action`: tolerant of the usual wrapping, strict on
content.

Tolerated wrapping (the reported ``case``):

- ``plain``: the whole text (after trimming whitespace) is the JSON object;
- ``fenced``: the object sits in a Markdown code fence (```json ... ``` or ``` ... ```);
- ``embedded``: the object is surrounded by other text;
- each of these prefixed ``think+`` when ``<think>...</think>`` reasoning came first (only the
  text after the last ``</think>`` is read, so drafts inside the reasoning never count; a lone
  ``</think>`` is accepted because Qwen3 chat templates put the opening tag in the prompt).

Strict content: exactly the keys ``object_id``, ``rotation``, ``x``, ``y`` in any order (the
prompt renders them in this order); integer values (not bools, floats or strings); rotation 0
or 1; no duplicate keys; and one answer only (several different JSON objects are ambiguous).
Negative ids or coordinates parse: judging them against the container is the episode's job
(DESIGN.md section 4), not the parser's. Pure, no torch.

Limits (any ``str`` gets a :class:`ParseResult` or an :class:`ActionParseError`, nothing else):

- answers longer than :data:`MAX_ANSWER_CHARS` characters (64 Ki, reasoning included) are
  refused unread (``answer too long``); an action is about 50 characters;
- the text read (after any reasoning) may hold at most :data:`MAX_BRACKETS` ``{`` and ``[``
  characters in all (``too many brackets``): each may start a candidate object;
- JSON nested deeper than :data:`MAX_DEPTH` levels is not read (an action has one level);
- integers longer than :data:`MAX_INT_DIGITS` digits are refused (Python's own string-to-int
  limit would otherwise raise, and no coordinate is that long).

Time is linear in the length of the answer: JSON is checked by an iterative scanner (an
explicit stack, no recursion) before the standard decoder sees a span, and the search for an
object embedded in text retries from later braces within a budget (:data:`RETRY_BUDGET` times
the text, :data:`RETRY_STEPS` scanner steps); past that it resumes where the failed candidate
broke. With these limits the slowest answers an adversarial search found take about 10 ms on
one CPU core (the tests assert the bound of 50 ms per parse).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from packlab.core.records import FormatEvent
from packlab.core.types import Action, Unparsable

#: The keys of an action, in the order the prompt renders them; any order parses.
ACTION_KEYS: tuple[str, ...] = ("object_id", "rotation", "x", "y")
BASE_CASES: tuple[str, ...] = ("plain", "fenced", "embedded")
#: Every value :attr:`ParseResult.case` can take.
PARSE_CASES: tuple[str, ...] = BASE_CASES + tuple(f"think+{c}" for c in BASE_CASES)

#: Longest answer read, in characters (the worst case of the scanner stays a few milliseconds).
MAX_ANSWER_CHARS = 65_536
#: Deepest JSON nesting read; deeper spans are treated as not JSON (bounds the decoder's own
#: recursion, which would otherwise raise RecursionError near a depth of 1,000).
MAX_DEPTH = 32
#: Most ``{`` and ``[`` characters in the text read (after any reasoning): each may start a
#: candidate, and candidates are what costs time. An action has one.
MAX_BRACKETS = 1024
#: Longest integer literal accepted, in digits.
MAX_INT_DIGITS = 100
#: What failed candidates may rescan when retrying from later braces: characters, as a multiple
#: of the text's length, and scanner steps (enough for every realistic answer).
RETRY_BUDGET = 2
RETRY_STEPS = 4096

_THINK_OPEN = re.compile(r"<think>", re.IGNORECASE)
# Greedy: one anchored match finds the last closing tag (linear; no list of every match).
_THROUGH_LAST_THINK_CLOSE = re.compile(r"(?s:.*)</think>", re.IGNORECASE)
_FENCE = "```"
# A fence's language tag and the rest of its opening line (possessive: no backtracking).
_FENCE_TAG = re.compile(r"[ \t]*+[A-Za-z0-9_+.-]*+[ \t]*+\r?\n?")

# JSON lexemes (RFC 8259; no NaN/Infinity). Possessive quantifiers keep every match linear.
_WS = r"[ \t\n\r]*+"
_STRING = r'"(?:[^"\\\x00-\x1f]++|\\(?:["\\/bfnrt]|u[0-9a-fA-F]{4}))*+"'
_NUMBER = r"-?+(?:0|[1-9][0-9]*+)(?:\.[0-9]++)?+(?:[eE][+-]?+[0-9]++)?+"
_SCALAR = rf"(?:{_STRING}|{_NUMBER}|true|false|null)"
_R_SCALAR = re.compile(_WS + _SCALAR)
_R_KEY = re.compile(_WS + _STRING + _WS + ":")
_R_OPEN = re.compile(_WS + r"([{\[])")
_R_PUNCT = re.compile(_WS + r"([,}\]])")
# Fast paths: runs of flat members / items, each followed by a comma, in one C-level match.
_R_MEMBERS = re.compile(rf"(?:{_WS}{_STRING}{_WS}:{_WS}{_SCALAR}{_WS},)*+")
_R_ITEMS = re.compile(rf"(?:{_WS}{_SCALAR}{_WS},)*+")
# A whole flat object (no nested value), the usual answer, in one C-level match.
_R_FLAT = re.compile(
    rf"\{{{_WS}(?:{_STRING}{_WS}:{_WS}{_SCALAR}{_WS}(?:,{_WS}{_STRING}{_WS}:{_WS}{_SCALAR}{_WS})*+)?+\}}"
)
# Where an object can start: a brace followed by a key or by its closing brace.
_R_START = re.compile(r'\{[ \t\n\r]*+["}]')

# Scanner states: what the next lexeme must be.
_VALUE, _FIRST_KEY, _KEY, _FIRST_ITEM, _AFTER = range(5)


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


@dataclass(frozen=True, slots=True)
class _Scan:
    """Outcome of scanning one JSON value: ``ok`` with its ``end``, or where it broke."""

    ok: bool
    end: int  # one past the value when ok, else the position where the scan failed
    steps: int = 1  # scanner iterations spent (the Python-level cost)
    too_deep: bool = False
    #: For a too-deep failure: where the innermost open container starts, the place to look for
    #: shallower objects next (one level of the nesting per MAX_DEPTH is rescanned, no more).
    resume: int = 0


class _Refused(ValueError):
    """A decoded value that the parser refuses as a whole (duplicate key, giant integer)."""


def _scan_value(s: str, start: int) -> _Scan:
    """Check that one JSON value starts at ``s[start]`` (no leading whitespace), iteratively.

    Linear in the length scanned; nesting deeper than MAX_DEPTH fails with ``too_deep``.
    """
    stack: list[int] = []  # where each open container starts (s[p] is "{" or "[")
    pos, need, steps = start, _VALUE, 0
    while True:
        steps += 1
        if need == _VALUE:
            m = _R_SCALAR.match(s, pos)
            if m:
                pos, need = m.end(), _AFTER
                continue
            m = _R_OPEN.match(s, pos)
            if not m:
                return _Scan(False, pos, steps)
            if len(stack) == MAX_DEPTH:
                return _Scan(False, m.start(1), steps, too_deep=True, resume=stack[-1])
            stack.append(m.start(1))
            pos, need = m.end(), (_FIRST_KEY if m.group(1) == "{" else _FIRST_ITEM)
        elif need in (_FIRST_KEY, _KEY):
            run = _R_MEMBERS.match(s, pos).end()  # type: ignore[union-attr]  # always matches
            if run > pos:
                pos, need = run, _KEY  # after a comma: a key must follow
            m = _R_KEY.match(s, pos)
            if m:
                pos, need = m.end(), _VALUE
            elif need == _FIRST_KEY and (m := _R_PUNCT.match(s, pos)) and m.group(1) == "}":
                stack.pop()
                pos, need = m.end(), _AFTER
            else:
                return _Scan(False, pos, steps)
        elif need == _FIRST_ITEM:
            run = _R_ITEMS.match(s, pos).end()  # type: ignore[union-attr]  # always matches
            if run > pos:
                pos, need = run, _VALUE  # after a comma: a value must follow
            elif (m := _R_PUNCT.match(s, pos)) and m.group(1) == "]":
                stack.pop()
                pos, need = m.end(), _AFTER
            else:
                need = _VALUE
        else:  # _AFTER a complete value
            if not stack:
                return _Scan(True, pos, steps)
            m = _R_PUNCT.match(s, pos)
            if not m:
                return _Scan(False, pos, steps)
            c, top = m.group(1), s[stack[-1]]
            if c == ",":
                pos, need = m.end(), (_KEY if top == "{" else _VALUE)
            elif (c == "}") == (top == "{"):
                stack.pop()
                pos = m.end()
            else:
                return _Scan(False, m.start(1), steps)


def _no_duplicates(pairs: list[tuple[str, object]]) -> dict[str, object]:
    out: dict[str, object] = {}
    for k, v in pairs:
        if k in out:
            raise _Refused(f"duplicate key: {_clip(_escaped(k))}")
        out[k] = v
    return out


def _bounded_int(literal: str) -> int:
    digits = len(literal.lstrip("-"))
    if digits > MAX_INT_DIGITS:
        raise _Refused(f"integer with {digits} digits (more than {MAX_INT_DIGITS})")
    return int(literal)


_DECODER = json.JSONDecoder(object_pairs_hook=_no_duplicates, parse_int=_bounded_int)


def _decode(s: str, start: int) -> object:
    """Decode the value at ``start``, which :func:`_scan_value` accepted (so it is standard JSON
    at most MAX_DEPTH deep: the decoder cannot fail on syntax or recurse far)."""
    return _DECODER.raw_decode(s, start)[0]


@dataclass(frozen=True, slots=True)
class _Found:
    objects: list[dict[str, object]]
    too_deep: bool  # some candidate was not read because of its depth


def _find_objects(s: str) -> _Found:
    """Every top-level JSON object in ``s``, left to right (nested ones belong to their parent).

    A candidate that fails is retried from the next brace after its start (an object may sit
    inside a broken one) while the rescanning stays within its budget (RETRY_BUDGET times the
    text's length in characters, RETRY_STEPS scanner steps); after that, from where the failed
    candidate broke. One too deep is retried from its innermost open container. Linear.
    """
    found: list[dict[str, object]] = []
    decoded: dict[str, dict[str, object]] = {}  # span text -> object: repeats decode once
    too_deep = False
    chars_left = RETRY_BUDGET * len(s) + 1024
    steps_left = RETRY_STEPS
    pos = 0
    while (m := _R_START.search(s, pos)) is not None:
        i = m.start()
        flat = _R_FLAT.match(s, i)
        scan = _Scan(True, flat.end()) if flat else _scan_value(s, i)
        too_deep |= scan.too_deep
        if scan.ok:
            span = s[i : scan.end]
            if span not in decoded:
                value = _decode(span, 0)
                assert isinstance(value, dict)  # _R_START only matches at an object's brace
                decoded[span] = value
            found.append(decoded[span])
            pos = scan.end
            continue
        chars_left -= scan.end - i
        steps_left -= scan.steps
        if scan.too_deep:
            pos = scan.resume
        elif chars_left > 0 and steps_left > 0:
            pos = i + 1
        else:
            pos = max(scan.end, i + 1)
    return _Found(found, too_deep)


def _whole_value(body: str) -> tuple[_Scan, object]:
    """(the scan of ``body`` from its start, the value when ``body`` is exactly one JSON value)."""
    scan = _scan_value(body, 0)
    if scan.ok and scan.end == len(body):
        return scan, _decode(body, 0)
    return scan, None


def _fence_bodies(body: str) -> list[str]:
    """The insides of the closed Markdown code fences of ``body``, language tags removed."""
    parts = body.split(_FENCE)
    # Only fences holding a brace matter, which MAX_BRACKETS bounds (the fence count is not).
    return [p[_FENCE_TAG.match(p).end() :] for p in parts[1:-1:2] if "{" in p]  # type: ignore[union-attr]


def _clip(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _escaped(key: str) -> str:
    """A key as JSON writes it, without the quotes: one line whatever it holds."""
    return json.dumps(key)[1:-1]


def _short(value: object) -> str:
    return _clip(json.dumps(value))


def _to_action(obj: dict[str, object], text: str) -> Action:
    missing = [k for k in ACTION_KEYS if k not in obj]
    unknown = sorted(k for k in obj if k not in ACTION_KEYS)
    if missing:
        raise ActionParseError(f"missing key(s): {', '.join(missing)}", text)
    if unknown:
        raise ActionParseError(
            f"unknown key(s): {_clip(', '.join(_escaped(k) for k in unknown))}", text
        )
    for k in ACTION_KEYS:
        v = obj[k]
        # bool is an int subclass in Python; true/false is not a coordinate.
        if type(v) is not int:
            raise ActionParseError(f"{k} must be an integer, got {_short(v)}", text)
    if obj["rotation"] not in (0, 1):
        raise ActionParseError(f"rotation must be 0 or 1, got {_short(obj['rotation'])}", text)
    return Action(object_id=obj["object_id"], rotation=obj["rotation"], x=obj["x"], y=obj["y"])  # type: ignore[arg-type]


def _single(objs: list[dict[str, object]], text: str) -> dict[str, object] | None:
    if not objs:
        return None
    first = objs[0]
    if any(o != first for o in objs[1:]):
        raise ActionParseError(f"ambiguous: {len(objs)} different JSON objects", text)
    return first


def _after_think(text: str) -> tuple[str, bool]:
    """(the text after the last ``</think>``, whether there was one)."""
    last = _THROUGH_LAST_THINK_CLOSE.match(text)
    if last is not None:
        return text[last.end() :], True
    if _THINK_OPEN.search(text):
        raise ActionParseError("unterminated <think> block", text)
    return text, False


def _parse_body(body: str, text: str) -> tuple[dict[str, object], str]:
    """(the answer object, its base case) in a stripped, non-empty body."""
    brackets = body.count("{") + body.count("[")
    if brackets > MAX_BRACKETS:
        raise ActionParseError(
            f"too many brackets: {brackets:,} '{{' or '[' (limit {MAX_BRACKETS:,})", text
        )
    scan, whole = _whole_value(body)
    if isinstance(whole, dict):
        return whole, "plain"
    if scan.ok and scan.end == len(body):
        raise ActionParseError(f"expected a JSON object, got {type(whole).__name__}", text)
    too_deep = scan.too_deep
    fenced: list[dict[str, object]] = []
    for block in _fence_bodies(body):
        found = _find_objects(block)
        fenced += found.objects
        too_deep |= found.too_deep
    obj = _single(fenced, text)
    if obj is not None:
        return obj, "fenced"
    found = _find_objects(body)
    obj = _single(found.objects, text)
    if obj is not None:
        return obj, "embedded"
    if too_deep or found.too_deep:
        raise ActionParseError(
            f"no JSON object found (nesting deeper than {MAX_DEPTH} is not read)", text
        )
    raise ActionParseError("no JSON object found", text)


def parse_action(text: str) -> ParseResult:
    """Parse one model answer; raises :class:`ActionParseError` (only) when it holds no single
    action. Linear time in ``len(text)``; see the module's limits."""
    if not isinstance(text, str):
        raise ActionParseError(f"expected text, got {type(text).__name__}", "")
    if len(text) > MAX_ANSWER_CHARS:
        raise ActionParseError(
            f"answer too long: {len(text):,} characters (limit {MAX_ANSWER_CHARS:,})", text
        )
    body, think = _after_think(text)
    body = body.strip()
    if not body:
        raise ActionParseError("empty answer" + (" after </think>" if think else ""), text)
    try:
        obj, case = _parse_body(body, text)
    except _Refused as e:
        raise ActionParseError(str(e), text) from None
    return ParseResult(_to_action(obj, text), ("think+" if think else "") + case)


def parse_or_unparsable(text: str) -> Action | Unparsable:
    """For policies: the action, or an :class:`Unparsable` carrying the text and the reason.

    Never raises. The text kept is cut to MAX_ANSWER_CHARS (it goes into step records and the
    next prompt's history).
    """
    return parse_with_format(text)[0]


def parse_with_format(text: str) -> tuple[Action | Unparsable, FormatEvent]:
    """:func:`parse_or_unparsable` and the answer's format event as this parser sees it:
    ``strict_json`` when the whole answer (after any reasoning) is the object (``plain``),
    ``extra_text`` when it was found in a code fence or among other text, ``parse_fail`` when
    the answer holds no action. Never raises."""
    try:
        found = parse_action(text)
    except ActionParseError as e:
        kept = text[:MAX_ANSWER_CHARS] if isinstance(text, str) else ""
        return Unparsable(text=kept, error=e.reason), "parse_fail"
    strict = found.case.removeprefix("think+") == "plain"
    return found.action, "strict_json" if strict else "extra_text"


#: Step-log keys of the text-answer policies (``vlm``, ``endpoint``) -> the answer-format
#: hook's keys (``packlab.sim.episode.answer_format``).
_LOGGED_FORMAT = {
    "format_event": "format_event",
    "reasked": "reasked",
    "forced_set_aside": "forced",
}


def logged_answer_format(entry: Mapping[str, Any]) -> dict[str, Any] | None:
    """The ``last_answer_format`` hook's value from a text-answer policy's step-log entry: its
    format event, whether it re-asked (where logged) and a forced set-aside's reason (where one
    was played); None when the entry has no format event (no answer was read)."""
    if entry.get("format_event") is None:
        return None
    return {
        hook: entry[logged]
        for logged, hook in _LOGGED_FORMAT.items()
        if entry.get(logged) is not None
    }
