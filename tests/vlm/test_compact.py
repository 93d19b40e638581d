"""Candidate mode's compact text state and index answers; the free format's key order (no torch
except the token count, which needs the vlm extra's tokenizer)."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core.types import Action, Container, Observation, ShownItem, Unparsable
from packlab.policies.candidates import ProposerConfig, propose
from packlab.vlm.prompt.compact import (
    CompactOptions,
    answer_text,
    block_size,
    candidate_messages,
    height_levels,
    map_lines,
    parse_choice,
    state_text,
    system_text,
)
from packlab.vlm.prompt.parse import parse_action
from packlab.vlm.prompt.render import action_text

try:  # the vlm extra (tokenizers, transformers): only the token count needs it
    from packlab.vlm.model.tokenizer import build_tokenizer
except ImportError:
    build_tokenizer = None


#: The user turn of :func:`_small_observation`, line by line.
SMALL_STATE_LINES = (
    "Step 3, 3 left.",
    "Map 2:",
    "22000",
    "22000",
    "00055",
    "00055",
    "Boxes: 0:4x3x4 1:2x2x2",
    "Places:",
    "0: b0 r0 x0 y3 z0 s10 f5 v0",
    "1: b0 r1 x0 y3 z0 s10 f5 v0",
    "2: b1 r0 x0 y3 z0 s10 f5 v0",
    "3: b0 r0 x0 y5 z0 s10 f5 v0",
    "4: b0 r1 x0 y4 z0 s10 f5 v0",
    "5: b1 r0 x0 y6 z0 s10 f5 v0",
    "6: b0 r0 x2 y5 z0 s10 f5 v0",
    "7: b0 r1 x7 y0 z0 s10 f5 v0",
)


def _small_observation() -> Observation:
    """10 x 8 cells, rim 200 mm: a 40 mm block at the origin corner and a 100 mm one opposite."""
    hm = np.zeros((10, 8), dtype=np.int32)
    hm[:4, :3] = 40
    hm[6:, 5:] = 100
    shown = (ShownItem(0, 3, (100, 75, 40), (4, 3, 20)), ShownItem(1, 0, (50, 50, 20), (2, 2, 10)))
    return Observation(2, Container((250, 200, 200)), hm, shown, remaining=3)


def _hard_observation(seed: int = 0) -> Observation:
    """A hard-level sized state: 60 x 52 cells, rim 1 m, a rough surface, 10 shown boxes."""
    rng = np.random.default_rng(seed)
    hm = np.zeros((60, 52), dtype=np.int32)
    for _ in range(25):  # boxes already placed, as blocks of random height
        x, y = rng.integers(0, 50), rng.integers(0, 42)
        hm[x : x + rng.integers(4, 16), y : y + rng.integers(4, 16)] += (
            int(rng.integers(5, 40)) * 10
        )
    shown = []
    for i in range(10):
        l, w, h = (int(v) for v in rng.integers(4, 25, size=3))
        shown.append(ShownItem(i, i, (l * 25, w * 25, h * 10), (l, w, h * 5)))
    return Observation(14, Container((1500, 1300, 1000)), np.minimum(hm, 990), tuple(shown), 17)


def test_state_text_literal():
    """The format spelled out, so a reviewer sees it without running anything."""
    obs = _small_observation()
    assert state_text(obs, propose(obs)) == "\n".join(SMALL_STATE_LINES)
    sys_text = system_text(obs.container)
    assert "Container: 10 x 8 cells of 25 mm, rim 20 cm." in sys_text
    assert "one line per 2-cell band along y" in sys_text
    messages = candidate_messages(obs, propose(obs))
    assert [m["role"] for m in messages] == ["system", "user"]
    assert messages[1]["content"] == [{"type": "text", "text": state_text(obs, propose(obs))}]


def test_map_levels_and_blocks():
    container = Container((250, 200, 180))  # 10 x 8 cells, rim 180 mm: a level is 20 mm
    hm = np.zeros((10, 8), dtype=np.int32)
    hm[0, 0], hm[9, 7], hm[4, 4] = 1, 180, 400  # just above the floor, the rim, above it
    levels = height_levels(hm, container, 1)
    assert levels[0, 0] == 1 and levels[9, 7] == 9 and levels[4, 4] == 9 and levels[1, 1] == 0
    assert block_size(container, 8) == 2 and block_size(container, 10) == 1
    pooled = height_levels(hm, container, 3)  # 4 x 3 blocks, the edge ones partial
    assert pooled.shape == (4, 3) and pooled[0, 0] == 1 and pooled[3, 2] == 9
    lines = map_lines(pooled)
    assert lines == ["1000", "0900", "0009"]  # one line per block row along y
    assert map_lines(np.zeros((9, 1), dtype=np.int64), rle=True) == ["0*9"]
    assert map_lines(np.array([[0], [0], [3], [3], [3], [3], [5]]), rle=True) == ["00 3*4 5"]


def test_candidate_answers_map_back_to_exactly_the_listed_placement():
    for obs in (_small_observation(), _hard_observation()):
        for k in (8, 16):
            listed = propose(obs, ProposerConfig(k))
            assert len(listed) == k
            for c in listed:
                for text in (answer_text(c), f" {c.index}\n", f"<think>b</think>{c.index}"):
                    assert parse_choice(text, listed) == c.action
                    assert isinstance(c.action, Action)


@pytest.mark.parametrize(
    "text,reason",
    [
        ("8", "placement 8 is not listed (0..7)"),
        ("123", "placement 123 is not listed (0..7)"),
        ("", "expected a placement number 0..7"),
        ("-1", "expected a placement number 0..7"),
        ("3.0", "expected a placement number 0..7"),
        ("3 4", "expected a placement number 0..7"),
        ("three", "expected a placement number 0..7"),
        ('{"object_id": 0, "rotation": 0, "x": 0, "y": 0}', "expected a placement number"),
        ("<think>3", "expected a placement number"),
        ("1" * 65, "answer too long"),
    ],
)
def test_bad_candidate_answers_are_unparsable(text, reason):
    listed = propose(_small_observation())
    got = parse_choice(text, listed)
    assert isinstance(got, Unparsable) and reason in got.error
    assert got.text == text[:64]


def test_no_listed_placement_parses_nothing():
    assert parse_choice("0", ()) == Unparsable("0", "no places")
    assert parse_choice(None, ()).error == "expected text, got NoneType"  # type: ignore[arg-type]


def test_options_validated():
    for bad in (0, True, 2.5):
        with pytest.raises(ValueError, match="map_side"):
            CompactOptions(map_side=bad)  # type: ignore[arg-type]


@pytest.mark.torch
def test_hard_state_costs_a_few_hundred_tokens():
    if build_tokenizer is None:
        pytest.skip("needs the vlm extra (tokenizers, transformers)")
    tok = build_tokenizer()
    obs = _hard_observation()
    n_state = len(tok(state_text(obs, propose(obs)))["input_ids"])
    n_system = len(tok(system_text(obs.container))["input_ids"])
    # Measured on packlab-bench-v1's hard states: about 370 on average, 411 at most (K = 8).
    assert n_state <= 450 and n_system <= 300


def test_free_format_puts_rotation_first_and_parses_any_key_order():
    a = Action(object_id=2, rotation=1, x=7, y=0)
    assert action_text(a) == '{"object_id":2,"rotation":1,"x":7,"y":0}'
    assert parse_action(action_text(a)).action == a
    assert parse_action('{"x":7,"y":0,"rotation":1,"object_id":2}').action == a
