"""Golden tests of the rendered VLM context (no torch). Regenerate the golden files after an
intended change with PACKLAB_UPDATE_GOLDEN=1, review the diff, and bump PROMPT_VERSION."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from packlab.core.types import Action, HistoryEntry, Observation
from packlab.vlm.prompt.render import (
    BLANK_IMAGE,
    PROMPT_VERSION,
    PromptOptions,
    TurnState,
    ablate,
    action_text,
    blank_like,
    drop_oldest_step,
    keep_last_steps,
    render_messages,
    split_target,
    turns_from_observation,
    with_answer,
)

GOLDEN = Path(__file__).parent / "golden"
COMBOS = [
    (h, i) for h in ("full", "current_only", "no_actions") for i in ("heightmap", "blank", "none")
]


def test_prompt_version_pinned():
    assert PROMPT_VERSION == "packlab-prompt-v2"


@pytest.mark.parametrize("history,image", COMBOS)
def test_messages_match_golden(fixed_state, history, image):
    container, past, current = fixed_state
    got = render_messages(container, past, current, PromptOptions(history, image))
    path = GOLDEN / f"prompt_{history}_{image}.json"
    if os.environ.get("PACKLAB_UPDATE_GOLDEN"):
        path.write_text(json.dumps(got, indent=1) + "\n")
    assert got == json.loads(path.read_text())


def test_full_context_literal(fixed_state):
    """The key strings spelled out here, so a reviewer sees the format without opening JSON."""
    container, past, current = fixed_state
    m = render_messages(container, past, current)
    assert [x["role"] for x in m] == ["system", "user", "assistant", "user", "assistant", "user"]
    sys_text = m[0]["content"][0]["text"]
    assert (
        "Container: 10 x 8 cells on the floor grid (one cell is 25 mm), 100 height units"
        in sys_text
    )
    assert "x runs along the container's first dimension (0 to 9)" in sys_text
    assert (
        "Rotation 1 turns the box 90 degrees about the vertical axis, which swaps l and w."
        in sys_text
    )
    assert "maximum height of the heightmap under its footprint" in sys_text
    assert m[1]["content"] == [
        {"type": "image", "image": "images/ep0/step0.png"},
        {
            "type": "text",
            "text": "Step 1. Objects left (buffer included): 5. Buffer: "
            '[{"object_id":0,"l":4,"w":3,"h":20},{"object_id":1,"l":2,"w":2,"h":10}]',
        },
    ]
    assert m[2]["content"] == [{"type": "text", "text": '{"object_id":0,"rotation":0,"x":0,"y":0}'}]
    assert m[4]["content"][0]["text"] == "I would place it left"  # unparsable past answer, verbatim


def test_ablations_shape(fixed_state):
    container, past, current = fixed_state
    cur_only = render_messages(container, past, current, PromptOptions(history="current_only"))
    assert [x["role"] for x in cur_only] == ["system", "user"]
    no_act = render_messages(container, past, current, PromptOptions(history="no_actions"))
    assert [x["role"] for x in no_act] == ["system", "user", "user", "user"]
    blank = render_messages(container, past, current, PromptOptions(image="blank"))
    imgs = [c["image"] for x in blank for c in x["content"] if c["type"] == "image"]
    assert imgs == [BLANK_IMAGE] * 3
    none = render_messages(container, past, current, PromptOptions(image="none"))
    assert not [c for x in none for c in x["content"] if c["type"] == "image"]
    assert "top-down image" not in none[0]["content"][0]["text"]
    assert "top-down image" in blank[0]["content"][0]["text"]


def test_blank_passthrough_and_helper(fixed_state):
    from PIL import Image

    container, past, current = fixed_state
    img = Image.new("RGB", (224, 224), (200, 10, 10))
    b = blank_like(img)
    assert b.size == img.size and b.mode == img.mode and b.getextrema() == ((0, 0),) * 3
    m = render_messages(container, past, current, PromptOptions(image="blank"), blank=b)
    assert m[-1]["content"][0]["image"] is b
    assert blank_like("images/x.png") == BLANK_IMAGE
    assert (blank_like(np.ones((4, 4, 3), np.uint8)) == 0).all()


@pytest.mark.parametrize("history,image", COMBOS)
def test_ablate_matches_direct_rendering(fixed_state, history, image):
    container, past, current = fixed_state
    full = render_messages(container, past, current)
    opts = PromptOptions(history, image)
    assert ablate(full, opts) == render_messages(container, past, current, opts)
    assert full == render_messages(container, past, current)  # input left untouched


def test_split_target(fixed_state):
    container, past, current = fixed_state
    ctx = render_messages(container, past, current)
    got_ctx, answer = split_target(with_answer(ctx, Action(1, 1, 2, 3)))
    assert got_ctx == ctx and answer == '{"object_id":1,"rotation":1,"x":2,"y":3}'
    with pytest.raises(ValueError):
        split_target(ctx)


def test_options_validated():
    with pytest.raises(ValueError, match="history"):
        PromptOptions(history="all")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="image"):
        PromptOptions(image="rgb")  # type: ignore[arg-type]


def test_action_text_exact_and_round_trips():
    from packlab.vlm.prompt.parse import parse_action

    a = Action(object_id=2, rotation=1, x=7, y=0)
    assert action_text(a) == '{"object_id":2,"rotation":1,"x":7,"y":0}'
    r = parse_action(action_text(a))
    assert r.action == a and r.case == "plain"


def test_with_answer_appends_target(fixed_state):
    container, past, current = fixed_state
    m = render_messages(container, past, current)
    full = with_answer(m, Action(1, 0, 3, 4))
    assert full[:-1] == m and full[-1]["role"] == "assistant"
    assert full[-1]["content"][0]["text"] == '{"object_id":1,"rotation":0,"x":3,"y":4}'


def test_turns_from_observation(fixed_state):
    container, past, current = fixed_state
    hm = np.zeros(container.cells, np.int32)
    hist = tuple(HistoryEntry(hm, t.shown, a, True) for t, a in past)
    obs = Observation(2, container, hm, current.shown, hist, remaining=3)
    got_past, got_cur = turns_from_observation(obs, lambda h: f"img{int(h.sum())}")
    assert [(t.step_index, t.remaining) for t, _ in got_past] == [(0, 5), (1, 4)]
    assert got_cur == TurnState("img0", current.shown, 2, 3)
    assert [a for _, a in got_past] == [a for _, a in past]


def test_prompt_module_imports_no_torch():
    import subprocess

    code = (
        "import sys, packlab.vlm.prompt.render, packlab.vlm.prompt.parse, "
        "packlab.vlm.prompt.context; "
        "bad = [m for m in ('torch', 'transformers') if m in sys.modules]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_keep_last_steps(fixed_state):
    container, past, current = fixed_state
    full = render_messages(container, past, current)
    assert len(past) == 2
    assert keep_last_steps(full, 2) == full and keep_last_steps(full, 9) == full
    assert keep_last_steps(full, 1) == drop_oldest_step(full)
    latest = keep_last_steps(full, 1)
    assert latest[1] == full[3] and latest[2] == full[4]  # the most recent step survives
    assert [m["role"] for m in keep_last_steps(full, 0)] == ["system", "user"]
    no_act = render_messages(container, past, current, PromptOptions(history="no_actions"))
    assert [m["role"] for m in keep_last_steps(no_act, 1)] == ["system", "user", "user"]
    with pytest.raises(ValueError, match="n = -1"):
        keep_last_steps(full, -1)
