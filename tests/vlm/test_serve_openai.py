"""``packlab serve`` driven by the official ``openai`` client: plain and streaming
answers, the model listed by its served name, and a client's mistakes answered 400 with a
reason (through the client as ``openai.BadRequestError`` and through raw HTTP).

The protocol tests use a scripted server (no torch); the ``torch`` tests serve a tiny random
model in-process, as ``packlab serve --model tiny:qwen3_vl:tiny`` does.
"""

from __future__ import annotations

import base64
import http.client
import io
import json
import socket

import numpy as np
import pytest
from PIL import Image

from packlab.vlm.serve.command import served_name
from packlab.vlm.serve.openai_messages import from_openai_messages, png_data_url
from packlab.vlm.serve.protocol import MAX_REQUEST_BYTES, Reply, RequestError
from packlab.vlm.serve.server import scripted, serve

openai = pytest.importorskip("openai")

TINY = "tiny:qwen3_vl:tiny"
ANSWER = 'Here: {"object_id": 0, "x": 1, "y": 2, "rotation": 0} done.'
PYTHON_NAMES = ("Error:", "Exception", "Traceback", "KeyError", "TypeError", "NoneType")


def client_for(server) -> openai.OpenAI:
    return openai.OpenAI(base_url=server.base_url, api_key="unused", max_retries=0, timeout=60)


def png_url(color: tuple[int, int, int] = (10, 200, 30)) -> str:
    return png_data_url(Image.new("RGB", (32, 32), color))


def user(content: object) -> list[dict]:
    return [{"role": "system", "content": "Pack boxes."}, {"role": "user", "content": content}]


IMAGE_TURN = [
    {"type": "image_url", "image_url": {"url": png_url()}},
    {"type": "text", "text": "Step 1. Place a box."},
]


def raw(server, method: str, path: str, body: bytes | None = None, headers: dict | None = None):
    """(status, decoded JSON body) of one raw HTTP request."""
    conn = http.client.HTTPConnection(server.host, server.port, timeout=10)
    try:
        conn.request(
            method, path, body=body, headers={"Content-Type": "application/json", **(headers or {})}
        )
        resp = conn.getresponse()
        return resp.status, json.loads(resp.read())
    finally:
        conn.close()


def assert_error(body: dict, *fragments: str) -> str:
    message = body["error"]["message"]
    assert all(f in message for f in fragments), message
    assert not any(name in message for name in PYTHON_NAMES), message
    assert "\n" not in message
    return message


# -- the protocol, with a scripted answer (no torch) ---------------------------------------------
@pytest.fixture
def scripted_server():
    with serve(
        scripted(
            [], default=Reply(content=ANSWER, usage={"prompt_tokens": 7, "completion_tokens": 5})
        ),
        model_name="vlm-small",
    ) as server:
        yield server


def test_openai_client_plain_and_streaming(scripted_server):
    client = client_for(scripted_server)
    assert [m.id for m in client.models.list()] == ["vlm-small"]
    plain = client.chat.completions.create(model="vlm-small", messages=user(IMAGE_TURN))
    assert plain.choices[0].message.content == ANSWER and plain.model == "vlm-small"
    assert plain.usage.prompt_tokens == 7 and plain.choices[0].finish_reason == "stop"

    stream = client.chat.completions.create(
        model="vlm-small", messages=user("hi"), stream=True, stream_options={"include_usage": True}
    )
    chunks = list(stream)
    deltas = [c.choices[0].delta for c in chunks if c.choices]
    assert len(deltas) > 3  # the answer arrives in pieces, not one body
    assert deltas[0].role == "assistant"
    assert "".join(d.content or "" for d in deltas) == ANSWER
    finishes = [c.choices[0].finish_reason for c in chunks if c.choices]
    assert finishes[-1] == "stop" and set(finishes[:-1]) == {None}
    assert chunks[-1].choices == [] and chunks[-1].usage.completion_tokens == 5
    assert all(c.object == "chat.completion.chunk" and c.id == chunks[0].id for c in chunks)


def test_streaming_without_usage_ends_with_the_finish_chunk(scripted_server):
    client = client_for(scripted_server)
    chunks = list(client.chat.completions.create(model="m", messages=user("hi"), stream=True))
    assert chunks[-1].choices[0].finish_reason == "stop" and chunks[-1].usage is None


BAD_REQUESTS = [
    # (keyword arguments of create, fragments of the message)
    ({"messages": []}, ["'messages' must be a non-empty array", "empty array"]),
    ({"messages": [{"role": "tool", "content": "x"}]}, ["messages[0].role must be one of"]),
    (
        {"messages": [{"role": "user"}]},
        ["messages[0].content must be a string or an array", "null"],
    ),
    ({"messages": [{"role": "user", "content": 5}]}, ["messages[0].content", "an integer"]),
    ({"messages": user([{"type": "video", "url": "x"}])}, ["messages[1].content[0].type"]),
    (
        {"messages": user([{"type": "text", "text": 3}])},
        ["messages[1].content[0].text must be a string"],
    ),
    (
        {"messages": user([{"type": "image_url"}])},
        ["messages[1].content[0].image_url must be an object"],
    ),
    ({"messages": user("hi"), "max_tokens": 0}, ["'max_tokens' must be an integer in [1, 4096]"]),
    ({"messages": user("hi"), "extra_body": {"max_tokens": "8"}}, ["'max_tokens'", '"8"']),
    ({"messages": user("hi"), "temperature": -1}, ["'temperature' must be a number"]),
    ({"messages": user("hi"), "n": 2}, ["'n' must be 1"]),
    ({"messages": user("hi"), "extra_body": {"stream": "yes"}}, ["'stream' must be a boolean"]),
]


@pytest.mark.parametrize("kwargs,fragments", BAD_REQUESTS, ids=range(len(BAD_REQUESTS)))
def test_client_mistakes_are_400_with_a_reason(scripted_server, kwargs, fragments):
    with pytest.raises(openai.BadRequestError) as ei:
        client_for(scripted_server).chat.completions.create(model="m", **kwargs)
    assert ei.value.status_code == 400
    assert_error({"error": ei.value.body}, *fragments)
    assert scripted_server.requests == []  # refused before the answer function


def test_a_request_without_messages_is_400(scripted_server):
    status, body = raw(scripted_server, "POST", "/v1/chat/completions", b'{"model": "m"}')
    assert status == 400 and body["error"]["param"] == "messages"
    assert_error(body, "'messages' is required")


@pytest.mark.parametrize(
    "payload,fragments",
    [
        (b"{oops", ["not valid JSON", "line 1 column 2"]),
        (b"", ["not valid JSON"]),
        (b"\xff\xfe\xfa", ["not valid JSON"]),
        (b"[" * 100_000 + b"]" * 100_000, ["not valid JSON"]),
        (b'[{"role": "user", "content": "hi"}]', ["must be a JSON object", "an array"]),
        (b'"hello"', ["must be a JSON object", "a string"]),
        (
            b'{"messages": [{"role": "user", "content": "hi"}], "temperature": 1e999999}',
            ["'temperature'"],
        ),
        (
            b'{"messages": [{"role": "user", "content": "hi"}], "top_p": 1' + b"0" * 500 + b"}",
            ["'top_p'"],
        ),
    ],
    ids=["malformed", "empty", "not-utf8", "deep", "array", "string", "inf", "huge-int"],
)
def test_malformed_bodies_are_400_over_raw_http(scripted_server, payload, fragments):
    status, body = raw(scripted_server, "POST", "/v1/chat/completions", payload)
    assert status == 400
    assert_error(body, *fragments)


def test_oversized_body_is_413_without_reading_it(scripted_server):
    with socket.create_connection((scripted_server.host, scripted_server.port), timeout=10) as s:
        s.sendall(
            b"POST /v1/chat/completions HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            b"Content-Length: %d\r\n\r\n" % (MAX_REQUEST_BYTES + 1)
        )
        answer = b""
        while chunk := s.recv(65536):  # the server closes: the unread body ends the connection
            answer += chunk
    head, _, body = answer.decode().partition("\r\n\r\n")
    assert head.startswith("HTTP/1.1 413")
    assert_error(json.loads(body), f"{MAX_REQUEST_BYTES + 1:,} bytes", "at most")


@pytest.mark.parametrize(
    "method,path,status",
    [
        ("GET", "/", 404),
        ("GET", "/v1/completions", 404),
        ("POST", "/v1/embeddings", 404),
        ("GET", "/v1/chat/completions", 405),
        ("DELETE", "/v1/models", 405),
        ("GET", "/v1/models/other-model", 404),
    ],
)
def test_unknown_routes_and_methods(scripted_server, method, path, status):
    got, body = raw(scripted_server, method, path, b"{}" if method == "POST" else None)
    assert got == status
    assert_error(body)


def test_model_routes_name_the_served_model(scripted_server):
    client = client_for(scripted_server)
    assert client.models.retrieve("vlm-small").id == "vlm-small"
    with pytest.raises(openai.NotFoundError, match="serves 'vlm-small'"):
        client.models.retrieve("gpt-4")
    assert raw(scripted_server, "GET", "/health") == (200, {"status": "ok", "model": "vlm-small"})


def test_a_failing_model_is_a_500_that_says_so_without_python_names():
    def broken(_request):
        return {}["missing"]  # a bug in the answer function: KeyError

    with serve(broken) as server, pytest.raises(openai.InternalServerError) as ei:
        client_for(server).chat.completions.create(model="m", messages=user("hi"))
    assert ei.value.status_code == 500
    assert_error({"error": ei.value.body}, "the model failed on this request", "missing")


def test_served_name_option_of_the_command():
    import argparse

    from packlab.vlm.serve.command import add_arguments

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert parser.parse_args([]).served_name is None
    assert parser.parse_args(["--served-name", "packer"]).served_name == "packer"


def test_served_name_is_never_a_path(tmp_path):
    assert served_name(TINY) == TINY
    ckpt = tmp_path / "runs" / "vlm-small-v2"
    assert served_name(str(ckpt)) == "vlm-small-v2"
    assert served_name(str(ckpt) + "/") == "vlm-small-v2"


def _image_message(url: str) -> list[dict]:
    return [{"role": "user", "content": [{"type": "image_url", "image_url": {"url": url}}]}]


@pytest.mark.parametrize(
    "url,fragment",
    [
        ("data:image/png;base64,%%%notbase64", "not valid base64"),
        ("data:image/png;base64," + base64.b64encode(b"just some text").decode(), "not an image"),
        ("data:image/png;base64," + png_url().split(",", 1)[1][:60], "does not decode"),
        ("https://example.com/heightmap.png", "only data:image"),
        ("data:image/png,rawbytes", "only data:image"),
    ],
    ids=["base64", "not-image", "truncated", "download", "no-base64"],
)
def test_undecodable_images_are_request_errors(url, fragment):
    with pytest.raises(RequestError) as ei:
        from_openai_messages(_image_message(url))
    assert ei.value.status == 400 and ei.value.param == "messages[0].content[0].image_url"
    assert fragment in ei.value.message and not any(n in ei.value.message for n in PYTHON_NAMES)


def test_huge_images_are_refused_before_decoding():
    buf = io.BytesIO()
    Image.new("L", (5000, 4000)).save(buf, format="PNG")  # compresses to a few kB
    url = "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()
    with pytest.raises(RequestError, match="5000 x 4000 pixels"):
        from_openai_messages(_image_message(url))


def test_images_round_trip_through_data_urls():
    im = Image.fromarray(np.arange(48, dtype=np.uint8).reshape(4, 4, 3))
    (got,) = from_openai_messages(_image_message(png_data_url(im)))[0]["content"]
    assert np.array_equal(np.asarray(got["image"]), np.asarray(im))


# -- a tiny model behind the server (torch) ------------------------------------------------------
@pytest.fixture(scope="module")
def model_server():
    torch = pytest.importorskip("torch")
    pytest.importorskip("transformers")
    torch.set_num_threads(1)
    from packlab.vlm.serve.model_answers import model_answer_fn

    with serve(model_answer_fn(TINY, max_new_tokens=8), model_name=served_name(TINY)) as server:
        yield server


@pytest.mark.torch
def test_tiny_model_plain_and_streaming_agree(model_server):
    client = client_for(model_server)
    assert [m.id for m in client.models.list()] == [TINY]
    messages = user(IMAGE_TURN)
    plain = client.chat.completions.create(model=TINY, messages=messages, max_tokens=6)
    text = plain.choices[0].message.content
    assert isinstance(text, str) and plain.choices[0].finish_reason in ("stop", "length")
    assert plain.usage.prompt_tokens > 0 and 1 <= plain.usage.completion_tokens <= 6
    chunks = list(
        client.chat.completions.create(
            model=TINY,
            messages=messages,
            max_tokens=6,
            stream=True,
            stream_options={"include_usage": True},
        )
    )
    streamed = "".join(c.choices[0].delta.content or "" for c in chunks if c.choices)
    assert streamed == text  # greedy: the same answer, in chunks
    assert chunks[-1].usage.prompt_tokens == plain.usage.prompt_tokens


@pytest.mark.torch
@pytest.mark.parametrize(
    "messages,fragment",
    [
        (
            user([{"type": "image_url", "image_url": {"url": "data:image/png;base64,AAAA"}}]),
            "not an image",
        ),
        (
            user([{"type": "image_url", "image_url": {"url": "data:image/png;base64,@@"}}]),
            "not valid base64",
        ),
        ([{"role": "user", "content": "hi"}, {"role": "system", "content": "late"}], None),
    ],
    ids=["bad-image", "bad-base64", "late-system"],
)
def test_tiny_model_refuses_what_it_cannot_read_with_400(model_server, messages, fragment):
    n = len(model_server.requests)
    try:
        out = client_for(model_server).chat.completions.create(
            model=TINY, messages=messages, max_tokens=4
        )
    except openai.BadRequestError as e:
        assert_error({"error": e.body}, *([fragment] if fragment else []))
    else:  # a template that takes any order of roles answers: what it must not do is fail with 500
        assert fragment is None and isinstance(out.choices[0].message.content, str)
    assert len(model_server.requests) == n + 1
