"""The ``endpoint`` policy against a local OpenAI-compatible test server on 127.0.0.1 that plays
a scripted answer list: request format, retries on timeouts and 5xx, garbage answers recorded as
unparsable steps while the episode goes on. No torch needed. Dead, hung and trickling servers,
and the time bounds, are in test_endpoint_faults.py.
"""

from __future__ import annotations

import base64
import io
import pickle

import numpy as np
import pytest
from _cases import small_case
from PIL import Image

from packlab.core.errors import ConfigError
from packlab.core.types import Action, Unparsable
from packlab.policies import make_policy
from packlab.sim.episode import Episode, run_episode
from packlab.sim.raster import heightmap_to_rgb
from packlab.vlm.prompt.render import IMAGE_LINE, action_text, render_messages
from packlab.vlm.serve.endpoint import EndpointError, EndpointPolicy, chat_completions_url
from packlab.vlm.serve.openai_messages import to_openai_messages
from packlab.vlm.serve.protocol import Reply
from packlab.vlm.serve.server import scripted, serve

A0 = action_text(Action(0, 0, 0, 0))
FAST = {"deadline_s": 0.4, "retries": 1, "backoff_s": 0.01}


def _decode(url: str) -> np.ndarray:
    assert url.startswith("data:image/png;base64,")
    with Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))) as im:
        return np.asarray(im.convert("RGB"))


@pytest.fixture
def server_factory():
    servers = []

    def start(answers, **kw):
        s = serve(scripted(answers, **kw))
        servers.append(s)
        return s

    yield start
    for s in servers:
        s.close()


def test_chat_completions_url():
    assert chat_completions_url("http://h:8000/v1") == "http://h:8000/v1/chat/completions"
    assert chat_completions_url("http://h:8000/") == "http://h:8000/v1/chat/completions"
    assert chat_completions_url("https://x/v1/chat/completions") == "https://x/v1/chat/completions"


def test_openai_format_of_the_golden_state(fixed_state):
    container, past, current = fixed_state
    messages = render_messages(container, past, current)
    out = to_openai_messages(messages, image_url=lambda im: f"url:{im}")
    assert [m["role"] for m in out] == ["system", "user", "assistant", "user", "assistant", "user"]
    assert isinstance(out[0]["content"], str) and out[0]["content"].startswith("You are")
    assert out[2]["content"] == A0
    assert out[4]["content"] == "I would place it left"  # an unparsable past answer, as said
    user = out[-1]["content"]
    assert user[0] == {"type": "image_url", "image_url": {"url": "url:images/ep0/step2.png"}}
    assert user[1]["type"] == "text" and user[1]["text"].startswith("Step 3.")


def test_endpoint_episode_with_timeouts_errors_and_garbage(server_factory):
    case = small_case()
    n = len(case.objects)
    assert n == 6
    script = [
        A0,  # step 0: fine
        Reply(content=A0, delay_s=2.0),  # step 1: past the deadline ...
        A0,  #          ... the retry answers
        Reply(status=500),  # step 2: server error ...
        "```json\n" + A0 + "\n```",  #          ... retried: a fenced answer
        "I think the box goes left.",  # step 3: garbage -> unparsable
        Reply(raw="<html>oops</html>"),  # step 4: a 200 that is not JSON -> unparsable
        Reply(raw='{"id": "chatcmpl-1", "choices": []}'),  # step 5: no choices -> unparsable
    ]
    server = server_factory(script)
    policy = make_policy("endpoint", base_url=server.base_url, model="packlab-test", **FAST)
    result = run_episode(case, policy, seed=0, backend="geometric")
    steps = result.steps
    assert len(steps) == n
    assert [s.valid or s.reason for s in steps[:3]] == [True, True, True]
    assert [s.reason for s in steps[3:]] == ["unparsable"] * 3
    garbage, not_json, no_choices = (s.action for s in steps[3:])
    assert isinstance(garbage, Unparsable) and garbage.text == "I think the box goes left."
    assert garbage.error == "no JSON object found"
    assert not_json.text == "" and "not JSON" in not_json.error and "oops" in not_json.error
    assert no_choices.text == "" and "no choices[0].message" in no_choices.error
    assert result.metrics.invalid_by_reason == {"unparsable": 3}
    log = policy.step_log
    assert [s["attempts"] for s in log] == [1, 2, 2, 1, 1, 1]
    assert "deadline" in log[1]["errors"][0]
    assert "HTTP 500" in log[2]["errors"][0]

    # Requests: greedy, the model name, images as PNG data URLs, the history growing.
    reqs = server.requests
    assert len(reqs) == len(script)
    assert all(r["model"] == "packlab-test" and r["temperature"] == 0.0 for r in reqs)
    first = reqs[0]["messages"]
    assert [m["role"] for m in first] == ["system", "user"]
    img = first[1]["content"][0]
    assert img["type"] == "image_url"
    expected = heightmap_to_rgb(np.zeros(case.container.cells, np.int32), case.container)
    assert np.array_equal(_decode(img["image_url"]["url"]), expected)
    last = reqs[-1]["messages"]
    assert len(last) == 1 + 2 * (n - 1) + 1
    # The garbage answer is in the history as the model said it; a garbage response as "".
    assert last[8] == {"role": "assistant", "content": "I think the box goes left."}
    assert last[10] == {"role": "assistant", "content": ""}


def test_heightmaps_in_the_request_are_the_episode_heightmaps(server_factory):
    case = small_case()
    server = server_factory([A0] * 10)
    policy = make_policy("endpoint", base_url=server.base_url, **FAST)
    episode = Episode("geometric")
    obs = episode.reset(case, 0)
    policy.reset(case, 0)
    heightmaps = []
    while not episode.done:
        heightmaps.append(obs.heightmap.copy())
        episode.step(policy.act(obs))
        if not episode.done:
            obs = episode.observe()
    msgs = server.requests[-1]["messages"]
    images = [
        c["image_url"]["url"]
        for m in msgs
        if isinstance(m["content"], list)
        for c in m["content"]
        if c["type"] == "image_url"
    ]
    assert len(images) == len(heightmaps)
    for url, hm in zip(images, heightmaps):
        assert np.array_equal(_decode(url), heightmap_to_rgb(hm, case.container))
    assert any(hm.any() for hm in heightmaps[1:])  # boxes were placed


def test_ablations_change_the_request(server_factory):
    case = small_case()
    server = server_factory([A0] * 20)
    for image in ("blank", "none"):
        policy = make_policy(
            "endpoint", base_url=server.base_url, image=image, history="current_only", **FAST
        )
        run_episode(case, policy, seed=0, backend="geometric")
    blank, none = server.requests[5]["messages"], server.requests[-1]["messages"]
    assert [m["role"] for m in blank] == ["system", "user"]  # current_only
    assert IMAGE_LINE in blank[0]["content"] and IMAGE_LINE not in none[0]["content"]
    assert not _decode(blank[1]["content"][0]["image_url"]["url"]).any()  # all black
    assert isinstance(none[1]["content"], str)  # no image part at all


def test_max_past_steps_keeps_the_most_recent_steps(server_factory):
    case = small_case()
    server = server_factory([action_text(Action(0, 0, 0, 0))] * 20)
    policy = make_policy("endpoint", base_url=server.base_url, max_past_steps=2, **FAST)
    run_episode(case, policy, seed=0, backend="geometric")
    roles = [[m["role"] for m in r["messages"]] for r in server.requests]
    assert roles[0] == ["system", "user"]
    assert roles[1] == ["system", "user", "assistant", "user"]
    assert all(len(r) == 6 for r in roles[2:]) and len(roles) > 3  # 2 past steps, then current
    with pytest.raises(ConfigError, match="max_past_steps"):
        EndpointPolicy(max_past_steps=-1)


def test_client_errors_are_not_retried(server_factory):
    server = server_factory([Reply(status=400, content="context too long"), A0])
    policy = make_policy("endpoint", base_url=server.base_url, **FAST)
    case = small_case()
    obs = Episode("geometric").reset(case, 0)
    policy.reset(case, 0)
    out = policy.act(obs)
    assert (
        isinstance(out, Unparsable) and "HTTP 400" in out.error and "context too long" in out.error
    )
    assert policy.step_log[0]["attempts"] == 1
    assert isinstance(policy.act(obs), Action)


def test_wrong_url_or_model_fails_fast(server_factory):
    server = server_factory([Reply(status=404, content="model 'x' does not exist")])
    policy = make_policy("endpoint", base_url=server.base_url, model="x", **FAST)
    case = small_case()
    with pytest.raises(EndpointError, match="does not exist"):
        run_episode(case, policy, seed=0, backend="geometric")


def test_api_key_comes_from_the_named_environment_variable(server_factory, monkeypatch):
    server = server_factory([A0, A0])
    monkeypatch.setenv("PACKLAB_TEST_KEY", "sk-test")
    policy = make_policy(
        "endpoint", base_url=server.base_url, api_key_env="PACKLAB_TEST_KEY", **FAST
    )
    assert "sk-test" not in pickle.dumps(policy).decode("latin-1")
    case = small_case()
    obs = Episode("geometric").reset(case, 0)
    policy.reset(case, 0)
    policy.act(obs)
    assert server.headers[-1].get("Authorization") == "Bearer sk-test"
    monkeypatch.delenv("PACKLAB_TEST_KEY")
    policy.act(obs)
    assert "Authorization" not in server.headers[-1]


def test_policy_is_picklable_and_runs_after_a_round_trip(server_factory):
    server = server_factory([A0] * 12)
    policy = make_policy("endpoint", base_url=server.base_url, **FAST)
    case = small_case()
    a = run_episode(case, policy, seed=0, backend="geometric")
    clone = pickle.loads(pickle.dumps(policy))
    b = run_episode(case, clone, seed=0, backend="geometric")
    assert a.steps[0].to_record()["action"] == b.steps[0].to_record()["action"]
    assert a.metrics.to_dict()["n_inside"] == b.metrics.to_dict()["n_inside"]
    assert isinstance(clone, EndpointPolicy) and clone.config()["base_url"] == server.base_url


def test_server_side_conversion_inverts_the_client_side():
    from packlab.vlm.serve.openai_messages import from_openai_messages, png_data_url

    case = small_case()
    obs = Episode("geometric").reset(case, 0)
    from packlab.vlm.prompt.context import ContextRenderer

    messages = ContextRenderer().messages(obs)
    back = from_openai_messages(to_openai_messages(messages, png_data_url))
    assert [m["role"] for m in back] == [m["role"] for m in messages]
    assert back[0]["content"] == messages[0]["content"]
    sent, got = messages[1]["content"], back[1]["content"]
    assert got[1] == sent[1]
    assert np.array_equal(np.asarray(got[0]["image"]), np.asarray(sent[0]["image"]))
