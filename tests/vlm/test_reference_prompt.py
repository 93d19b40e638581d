"""The reference implementation's prompt protocol (``endpoint`` with ``prompt=reference``): the
rendered request against the reference's template, field by field; its lenient parser on the
reference's cases; and whole bench runs against a scripted server that answers in its format."""

from __future__ import annotations

import hashlib
import json
import random
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import ClassVar

import numpy as np
import pytest

from packlab.bench.records import read_record_file
from packlab.cases.load import load_cases
from packlab.cli.main import main
from packlab.core.errors import EXIT_OK
from packlab.core.types import Action, Container, Observation, ShownItem
from packlab.policies.oracle import OraclePolicy
from packlab.sim.env import demo_cases_path
from packlab.sim.episode import run_episode
from packlab.vlm.prompt import reference as ref
from packlab.vlm.prompt.reference_parse import forced_set_aside, parse_reference
from packlab.vlm.serve.endpoint import EndpointPolicy

CONTAINER = Container((625, 500, 550))  # 25 x 20 cells, 275 height units
SHOWN = (
    ShownItem(0, "obj_00001", (250, 100, 40), (10, 4, 20)),
    ShownItem(1, "obj_00002", (125, 125, 220), (5, 5, 110)),
)

# Lines of the reference's configs/prompts/packing_sft.yaml, written out here on their own.
SECTIONS = [
    "## Role and Goal",
    "## Evaluation Objective",
    "## Container",
    "## Step Input",
    "## Required Output",
    "## Coordinate System and Footprint Occupancy",
    "## Placement Policy",
    "## Rules",
]
TEMPLATE_LINES = [
    "You are a 3D bin-packing agent.",
    "The container is described by this JSON object:",
    (
        "- The top-left cell of the height map is x=0, y=0; x increases from top to bottom, and y "
        "increases from left to right."
    ),
    (
        "- The color scale is fixed for each container: fully red corresponds to about 2x the "
        "container height."
    ),
    "- size_cells: object size in grid cells, ordered as [x, y, z] before rotation.",
    "Return exactly one JSON object:",
    '{"object_id": int, "x": int, "y": int, "rotation": 0 or 1}',
    (
        "- If rotation is 1, first swap dx and dy, then the object occupies grid cells x through "
        "x+dx-1 and y through y+dy-1."
    ),
    '- Never output {"x":0,"y":0} just because it is a valid coordinate.',
    (
        "- The assistant turn starts inside an open <think> block. Keep the thinking short: "
        "at most 3 concise lines."
    ),
    (
        "- Immediately after </think>, output exactly one JSON object and no extra text, markdown, "
        "or code fences."
    ),
]


def _observation(heightmap: np.ndarray | None = None) -> Observation:
    hm = np.zeros(CONTAINER.cells, np.int32) if heightmap is None else heightmap
    return Observation(step_index=0, container=CONTAINER, heightmap=hm, shown=SHOWN)


# -- rendering ---------------------------------------------------------------------------------
def test_system_text_follows_the_template_with_the_eval_container_json():
    text = ref.system_text(CONTAINER)
    assert ref.container_json(CONTAINER) == (
        '{"container_grid_size":{"x_cells":25,"y_cells":20,"z_cells":275}}'
    )
    lines = text.split("\n")
    assert lines[0] == "## Role and Goal" and text.endswith("or code fences.\n")
    assert [line for line in lines if line.startswith("## ")] == SECTIONS
    for line in TEMPLATE_LINES:
        assert line in lines, line
    # The JSON sits on its own line right after its introduction.
    at = lines.index("The container is described by this JSON object:")
    assert lines[at + 1] == ref.container_json(CONTAINER)
    assert 4400 < len(text) < 4700  # the template is about 4.5k characters


def test_container_json_training_form_adds_the_centimetre_fields():
    assert json.loads(ref.container_json(CONTAINER, form="train")) == {
        "container_size_cm": [62.5, 50.0, 55.0],
        "container_grid_size": {"x_cells": 25, "y_cells": 20, "z_cells": 275},
        "grid_cell_size_cm": {"xy": 2.5, "z": 0.2},
    }
    assert list(json.loads(ref.container_json(CONTAINER, form="train"))) == [
        "container_size_cm",
        "container_grid_size",
        "grid_cell_size_cm",
    ]


def test_user_turn_and_answer_key_order():
    assert ref.user_text(SHOWN) == (
        "<image>\nCurrent visible buffer objects:\n"
        '[{"object_id":0,"size_cells":[10,4,20]},{"object_id":1,"size_cells":[5,5,110]}]\n'
    )
    assert ref.answer_text(Action(1, 1, 2, 3)) == '{"object_id":1,"x":2,"y":3,"rotation":1}'


def test_heightmap_image_colours_and_orientation():
    hm = np.zeros(CONTAINER.cells, np.int32)
    hm[0, -1] = 550  # the container's height: half the colour scale
    hm[-1, 0] = 1100  # twice the height: fully red
    img = np.asarray(ref.heightmap_image(hm, CONTAINER))
    assert img.shape == (224, 224, 3)
    assert tuple(img[100, 100]) == (0, 0, 255)  # empty: pure blue
    assert tuple(img[0, -1]) == (127, 0, 127)  # x = 0 is the top row, y the column
    assert tuple(img[-1, 0]) == (255, 0, 0)


def test_request_carries_the_prefill_switches_and_sampling():
    body = EndpointPolicy(prompt="reference").payload(_observation())
    system, user, prefill = body["messages"]
    assert system == {"role": "system", "content": ref.system_text(CONTAINER)}
    assert user["role"] == "user"
    assert [part["type"] for part in user["content"]] == ["image_url", "text"]
    assert user["content"][0]["image_url"]["url"].startswith("data:image/png;base64,")
    assert user["content"][1]["text"] == ref.user_text(SHOWN)
    assert prefill == {
        "role": "assistant",
        "content": "Pick a valid placement directly.\n</think>\n\n",
    }
    assert body["chat_template_kwargs"] == {"enable_thinking": True}
    assert body["add_generation_prompt"] is False and body["continue_final_message"] is True
    assert (body["temperature"], body["top_p"], body["max_tokens"]) == (0.0, 1.0, 512)


def test_image_none_drops_the_literal_and_the_part():
    body = EndpointPolicy(prompt="reference", image="none").payload(_observation())
    assert body["messages"][1]["content"] == ref.user_text(SHOWN).replace("<image>\n", "")


def test_history_modes():
    msgs = [
        {"role": "system", "content": "s"},
        {"role": "user", "content": "u1"},
        {"role": "assistant", "content": "a1"},
        {"role": "user", "content": "u2"},
        {"role": "assistant", "content": "a2"},
        {"role": "user", "content": "u3"},
    ]
    assert ref.select_history(msgs, "full") == msgs
    assert [m["content"] for m in ref.select_history(msgs, "current_only")] == ["s", "u3"]
    assert [m["content"] for m in ref.select_history(msgs, "no_assistant")] == [
        "s",
        "u1",
        "u2",
        "u3",
    ]
    shuffled = ref.select_history(msgs, "shuffled_assistant_actions", "7", 2)
    assert sorted(m["content"] for m in shuffled if m["role"] == "assistant") == ["a1", "a2"]


def test_option_checks_and_display_name():
    assert EndpointPolicy(prompt="reference").name == "endpoint (reference prompt)"
    assert EndpointPolicy().name == "endpoint" and EndpointPolicy().max_tokens == 64
    assert EndpointPolicy(prompt="reference").config()["prompt"] == "reference"
    with pytest.raises(ValueError, match="prompt"):
        EndpointPolicy(prompt="nope")


# -- parsing -----------------------------------------------------------------------------------
A = Action(1, 0, 2, 3)
A_ROT = Action(1, 1, 2, 3)
J = '{"object_id":1,"x":2,"y":3,"rotation":0}'


@pytest.mark.parametrize(
    ("text", "action", "event", "error"),
    [
        ('{"object_id": 1, "x": 2, "y": 3, "rotation": 1}', A_ROT, "strict_json", None),
        ('\n\n{"object_id":1,"x":2,"y":3,"rotation":0}\n', A, "strict_json", None),
        ('{"object_id": 1, "x": 2, "y": 3}', A, "strict_json", None),  # rotation defaults to 0
        ('{"object_id": "1", "x": 2.9, "y": true}', Action(1, 0, 2, 1), "strict_json", None),
        (f"```json\n{J}\n```", A, "extra_text", None),
        (f"Answer: {J} done", A, "extra_text", None),
        (f'<think>try {{"object_id": 0}}</think>\n{J}', A, "strict_json", None),
        (f'<THINK mode="x">a\nb</THINK>{J}', A, "strict_json", None),
        (f"reasoning without its tag</think>\n\n{J}", A, "strict_json", None),
        ("no json here", None, "parse_fail", "json_parse_failed"),
        ('{"object_id": 1, "x": 2,', None, "parse_fail", "json_parse_failed"),
        (f"{J} and {J}", None, "parse_fail", "json_parse_failed"),  # greedy span: two objects
        ('{"object_id": 1, "x": 2}', None, "parse_fail", "missing_or_invalid_field"),
        ('{"object_id":null,"x":2,"y":3}', None, "parse_fail", "missing_or_invalid_field"),
        ('{"object_id":"one","x":2,"y":3}', None, "parse_fail", "missing_or_invalid_field"),
        ("[1, 2, 3]", None, "parse_fail", "missing_or_invalid_field"),
        ('{"object_id":1,"x":2,"y":3,"rotation":2}', None, "parse_fail", "invalid_rotation"),
        ('{"object_id":1,"x":Infinity,"y":3}', None, "parse_fail", "missing_or_invalid_field"),
    ],
)  # fmt: skip
def test_parse_like_the_reference(text, action, event, error):
    parsed = parse_reference(text)
    assert (parsed.action, parsed.event, parsed.error) == (action, event, error)


def test_think_stripping_is_reported():
    assert parse_reference('<think>x</think>{"object_id":1,"x":2,"y":3}').think_stripped
    assert not parse_reference('{"object_id":1,"x":2,"y":3}').think_stripped


def test_forced_set_aside_is_seeded_as_the_reference_seeds_it():
    material = "42:3:5:parse_fail"
    seed = int(hashlib.sha256(material.encode()).hexdigest()[:16], 16)
    assert forced_set_aside(4, "3", 5, "parse_fail") == random.Random(seed).randrange(4)
    picks = {forced_set_aside(5, "3", step, "parse_fail") for step in range(40)}
    assert picks == set(range(5))  # it is a draw, not a fixed index


# -- whole runs against a scripted server ------------------------------------------------------
class _Recorder:
    """The oracle, remembering what it saw and did at every step."""

    name = "oracle"
    needs_case = True  # the oracle's plan

    def __init__(self) -> None:
        self.inner = OraclePolicy()
        self.steps: list[tuple[str, Action]] = []

    def reset(self, case, seed):
        self.inner.reset(case, seed)

    def act(self, obs):
        action = self.inner.act(obs)
        self.steps.append((ref.user_text(obs.shown), action))
        return action


def _oracle_answers(seed: int) -> dict[tuple[str, int], tuple[str, str]]:
    """(container JSON, step) -> (the user text the step shows, the answer in the reference's
    format) for every demo case, from the oracle's own episodes."""
    script = {}
    for case in load_cases(demo_cases_path()):
        rec = _Recorder()
        run_episode(case, rec, seed, backend="geometric")
        for step, (text, action) in enumerate(rec.steps):
            script[(ref.container_json(case.container), step)] = (text, ref.answer_text(action))
    return script


class _Handler(BaseHTTPRequestHandler):
    script: ClassVar[dict] = {}
    garbage = False
    requests: ClassVar[list] = []

    def log_message(self, *args: object) -> None:
        pass

    def do_POST(self) -> None:
        body = json.loads(self.rfile.read(int(self.headers.get("Content-Length", 0))))
        self.requests.append(body)
        messages = body["messages"]
        container = next(
            line for line in messages[0]["content"].split("\n") if "container_grid_size" in line
        )
        users = [m for m in messages if m["role"] == "user"]
        shown_text, answer = self.script.get((container, len(users) - 1), ("", "?"))
        last = users[-1]["content"]  # a string for the re-ask, else [image, text]
        if self.garbage or isinstance(last, str) or last[1]["text"] != shown_text:
            answer = "I cannot tell."
        # As vLLM continues after the prefill: only the text after </think> comes back.
        reply = {"choices": [{"message": {"role": "assistant", "content": answer}}]}
        data = json.dumps(reply).encode()
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)


@pytest.fixture
def server(request) -> Iterator[type[_Handler]]:
    handler = type(
        "Handler",
        (_Handler,),
        {"script": _oracle_answers(0), "garbage": request.param == "garbage", "requests": []},
    )
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    httpd.daemon_threads = True
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    handler.url = f"http://127.0.0.1:{httpd.server_address[1]}/v1"
    try:
        yield handler
    finally:
        httpd.shutdown()
        httpd.server_close()


@pytest.mark.parametrize("server", ["oracle"], indirect=True)
def test_reference_answers_of_the_oracle_score_one(tmp_path, capsys, server):
    run_dir = tmp_path / "run"
    argv = [
        "bench",
        "--cases",
        demo_cases_path(),
        "--backend",
        "geometric",
        "--policies",
        "endpoint",
        "--seeds",
        "0",
        "--workers",
        "1",
        "--out",
        str(run_dir),
        "--no-progress",
        "--no-figures",
        "--policy-arg",
        f"endpoint:base_url={server.url}",
        "--policy-arg",
        "endpoint:prompt=reference",
    ]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == EXIT_OK, err
    records = list(read_record_file(run_dir / "episodes.jsonl").records)
    assert len(records) == 3
    assert [round(r.metrics.overall, 6) for r in records] == [1.0, 1.0, 1.0]
    assert all(r["continue_final_message"] for r in server.requests)
    config = json.loads((run_dir / "config.json").read_text())
    assert "reference" in json.dumps(config)  # the run records the protocol


@pytest.mark.parametrize("server", ["garbage"], indirect=True)
def test_unusable_answers_become_seeded_set_asides(server):
    case = load_cases(demo_cases_path())[0]
    policy = EndpointPolicy(base_url=server.url, prompt="reference", reask=True)
    result = run_episode(case, policy, 0, backend="geometric")
    assert {s.reason for s in result.steps} == {"set_aside"}
    assert len(server.requests) == 2 * len(result.steps)  # every answer was asked for twice
    reask = server.requests[1]["messages"]
    assert reask[-2] == {"role": "assistant", "content": "I cannot tell."}
    assert reask[-1]["content"].startswith("Return only one JSON object for the same current step.")
    assert "continue_final_message" not in server.requests[1]
    log = policy.step_log[0]
    assert (log["format_event"], log["parse_error"], log["forced_set_aside"], log["reasked"]) == (
        "parse_fail",
        "json_parse_failed",
        "parse_fail",
        True,
    )
    # The history keeps the raw answers, as the reference's does.
    assert server.requests[-2]["messages"][2] == {"role": "assistant", "content": "I cannot tell."}


# -- the local model ---------------------------------------------------------------------------
def test_local_model_continues_the_prefill():
    pytest.importorskip("transformers")
    from packlab.vlm.data.encoding import encode
    from packlab.vlm.infer.policy import VLMPolicy
    from packlab.vlm.serve.reference_turns import ReferenceTurns, local_image

    case = load_cases(demo_cases_path())[0]
    policy = VLMPolicy(
        model="tiny:qwen3_5:tiny", prompt="reference", max_new_tokens=4, device="cpu"
    )
    assert policy.name == "vlm (reference prompt)"
    result = run_episode(case, policy, 0, backend="geometric")
    # A random-weight model writes no JSON: every step is a seeded forced set-aside.
    assert {s.reason for s in result.steps} == {"set_aside"}
    assert {log["forced_set_aside"] for log in policy.step_log} == {"parse_fail"}
    assert policy.config()["template_kwargs"] == {"enable_thinking": True}
    gen = policy.generator
    turns = ReferenceTurns(image_part=local_image)
    turns.reset(case)
    messages = ref.with_prefill(turns.view(_observation()))
    enc = encode(messages, gen.tokenizer, gen.processor, gen.config)
    text = gen.tokenizer.decode(enc.input_ids.tolist())
    assert text.endswith("assistant\nPick a valid placement directly.\n</think>\n\n")
    assert "<image>\nCurrent visible buffer objects:" in text
