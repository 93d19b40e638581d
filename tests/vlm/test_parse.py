"""Golden table of messy model outputs -> parsed action and case, or the error reason (no torch)."""

from __future__ import annotations

import pytest

from packlab.core.types import Action, Unparsable
from packlab.vlm.prompt.parse import (
    PARSE_CASES,
    ActionParseError,
    parse_action,
    parse_or_unparsable,
)

A = Action(object_id=1, rotation=0, x=3, y=4)
J = '{"object_id": 1, "x": 3, "y": 4, "rotation": 0}'

OK = [
    # (text, action, case)
    (J, A, "plain"),
    ('{"object_id":1,"x":3,"y":4,"rotation":0}', A, "plain"),
    ("  \n" + J + "\n\n", A, "plain"),
    ('{"rotation": 0, "y": 4, "x": 3, "object_id": 1}', A, "plain"),
    ("```json\n" + J + "\n```", A, "fenced"),
    ("```\n" + J + "\n```", A, "fenced"),
    ("Here is my move:\n```json\n" + J + "\n```\nGood luck.", A, "fenced"),
    ("```JSON " + J + "```", A, "fenced"),
    ("I place the tall box in the corner: " + J, A, "embedded"),
    ("Answer: " + J + " (flat side down)", A, "embedded"),
    (J + "<|im_end|>", A, "embedded"),
    ("```json\n" + J, A, "embedded"),  # unclosed fence (truncated generation)
    (
        "The answer is " + J + ". To repeat: " + J,
        A,
        "embedded",
    ),  # same object twice is not ambiguous
    (
        '<think>corner first; maybe {"object_id": 0, "x": 0, "y": 0, "rotation": 1}?</think>' + J,
        A,
        "think+plain",
    ),  # the draft inside the reasoning never counts
    ("<think>\nhmm\n</think>\n\n```json\n" + J + "\n```", A, "think+fenced"),
    ("<THINK>x</THINK> so: " + J, A, "think+embedded"),
    (
        "reasoning without an opening tag</think>" + J,
        A,
        "think+plain",
    ),  # template put <think> in the prompt
    ("<think>a</think><think>b</think>" + J, A, "think+plain"),
    (
        '{"object_id": 0, "x": -1, "y": 12, "rotation": 1}',
        Action(0, 1, -1, 12),
        "plain",
    ),  # bounds: episode's job
]

BAD = [
    # (text, reason fragment)
    ("", "empty answer"),
    ("   ", "empty answer"),
    ("I don't know", "no JSON object found"),
    ('<think>still thinking about {"object_id": 1', "unterminated <think> block"),
    ("<think>done</think>   ", "empty answer after </think>"),
    ('{"object_id": 1, "x": 3, "y": 4}', "missing key(s): rotation"),
    ('{"object_id": 1, "x": 3}', "missing key(s): rotation, y"),
    ('{"object_id": 1, "x": 3, "y": 4, "rotation": 0, "z": 2}', "unknown key(s): z"),
    ('{"id": 1, "x": 3, "y": 4, "rotation": 0}', "missing key(s): object_id"),
    ('{"object_id": "1", "x": 3, "y": 4, "rotation": 0}', 'object_id must be an integer, got "1"'),
    ('{"object_id": 1, "x": 3.0, "y": 4, "rotation": 0}', "x must be an integer, got 3.0"),
    ('{"object_id": 1, "x": 3, "y": null, "rotation": 0}', "y must be an integer, got null"),
    (
        '{"object_id": true, "x": 3, "y": 4, "rotation": 0}',
        "object_id must be an integer, got true",
    ),
    ('{"object_id": 1, "x": 3, "y": 4, "rotation": 2}', "rotation must be 0 or 1, got 2"),
    ('{"object_id": 1, "x": 3, "y": 4, "rotation": 90}', "rotation must be 0 or 1, got 90"),
    ('{"object_id": 1, "x": 3, "x": 5, "y": 4, "rotation": 0}', "duplicate key: x"),
    ("[1, 3, 4, 0]", "expected a JSON object, got list"),
    ("{'object_id': 1, 'x': 3, 'y': 4, 'rotation': 0}", "no JSON object found"),  # Python, not JSON
    (
        '{"action": ' + J + "}",
        "missing key(s): object_id, rotation, x, y",
    ),  # wrapped, not tolerated
    (
        'first {"object_id": 0, "x": 0, "y": 0, "rotation": 0} or maybe ' + J,
        "ambiguous: 2 different JSON objects",
    ),
    ("```json\n" + J + "\n```\n```json\n" + J.replace("3", "5") + "\n```", "ambiguous"),
]


@pytest.mark.parametrize("text,action,case", OK)
def test_parse_ok(text, action, case):
    r = parse_action(text)
    assert (r.action, r.case) == (action, case)
    assert r.case in PARSE_CASES


@pytest.mark.parametrize("text,reason", BAD)
def test_parse_errors(text, reason):
    with pytest.raises(ActionParseError) as ei:
        parse_action(text)
    assert reason in ei.value.reason
    assert isinstance(ei.value, ValueError) and ei.value.text == text


def test_parse_or_unparsable():
    assert parse_or_unparsable(J) == A
    u = parse_or_unparsable("nope")
    assert isinstance(u, Unparsable) and u.text == "nope" and u.error == "no JSON object found"


def test_non_string_rejected():
    with pytest.raises(ActionParseError, match="expected text"):
        parse_action(None)  # type: ignore[arg-type]
