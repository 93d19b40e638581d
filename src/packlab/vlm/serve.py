"""A small OpenAI-compatible chat-completions server, for tests and local trials.

``serve(answer_fn)`` starts a :class:`http.server.ThreadingHTTPServer` in a background thread
(on 127.0.0.1 and a free port by default) and returns a :class:`ChatServer` handle (``.port``,
``.base_url``, ``.requests``, ``.close()``; a context manager). Each valid
``POST /v1/chat/completions`` calls ``answer_fn(request_body)``, which returns either the
assistant text or a :class:`Reply` that can also delay the answer, fail with an HTTP status, or
send a raw (malformed) body.

Two answer functions are provided:

- :func:`scripted` plays a list of answers in order (tests of the ``endpoint`` policy; no torch);
- :func:`model_answer_fn` answers with a local model through the same greedy generator as the
  ``vlm`` policy (needs the vlm extra): OpenAI messages are converted back to the chat messages
  of :mod:`packlab.vlm.prompt`, images decoded from their data URLs.

What the server answers (the OpenAI API's shapes, so that the official ``openai`` client works):

- ``GET /v1/models`` lists the one served model by its served name (``--served-name``; by default
  the checkpoint directory's name, or the ``tiny:F:S`` spec), never a filesystem path;
  ``GET /v1/models/{name}``; ``GET /health``;
- ``POST /v1/chat/completions``: a ``chat.completion``; with ``"stream": true``, server-sent
  events of ``chat.completion.chunk`` objects (``data: {...}`` then ``data: [DONE]``; a usage
  chunk when ``stream_options.include_usage``). The answer is generated whole, then sent as
  chunks of about a word;
- a client's mistake (body not JSON, not an object, no ``messages``, a wrong type, an image that
  does not decode, ``n`` other than 1, ...) gets 400 with ``{"error": {"message", "type",
  "param", "code"}}`` saying what and where; a body over :data:`MAX_REQUEST_BYTES` gets 413;
  an unknown route 404, a known route with another method 405. A failure of the model itself
  is a 500 whose message says so (the traceback goes to the server's log, not the client).

Sampling options (``temperature``, ``top_p``, ``seed``, ``stop``) are accepted when well typed and
ignored: answers are greedy. Any ``model`` value is answered by the one served model.

Command line (serves the tiny random model unless ``--model`` names a checkpoint)::

    packlab serve --model tiny:qwen3_5:tiny --port 8000   # or python -m packlab.vlm.serve

This is a test server: one generation at a time per model (a lock), no auth.
"""

from __future__ import annotations

import argparse
import base64
import binascii
import io
import json
import logging
import math
import re
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Self

log = logging.getLogger(__name__)

#: Largest request body read (a long history of 224-pixel PNG heightmaps is well under 1 MiB).
MAX_REQUEST_BYTES = 32 << 20
#: Largest ``max_tokens`` served (the action is about 20 tokens).
MAX_TOKENS_LIMIT = 4096
#: Largest decoded image, in pixels (width x height).
MAX_IMAGE_PIXELS = 4096 * 4096
ROLES = ("system", "user", "assistant")
#: Seconds a connection may stay silent before the server drops it (a stalled client cannot
#: hold a server thread for ever).
CONNECTION_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class Reply:
    """A scripted server behaviour: answer ``content`` after ``delay_s`` with HTTP ``status``
    (an error body when status is not 200), or send ``raw`` bytes as the 200 body. ``usage``
    (prompt_tokens, completion_tokens) and ``finish_reason`` go into the response."""

    content: str = ""
    status: int = 200
    delay_s: float = 0.0
    raw: str | None = None
    usage: dict[str, int] | None = None
    finish_reason: str = "stop"


AnswerFn = Callable[[dict[str, Any]], "str | Reply"]


class RequestError(ValueError):
    """A client's mistake, answered with ``status`` (400 by default) and this one-line message;
    ``param`` names the offending field (``messages[1].content[0].image_url``)."""

    def __init__(self, message: str, param: str | None = None, status: int = 400):
        super().__init__(message)
        self.message, self.param, self.status = message, param, status


def scripted(answers: Iterable[str | Reply], default: str | Reply | None = None) -> AnswerFn:
    """An answer function that plays ``answers`` in order, then ``default`` (or HTTP 503)."""
    queue = list(answers)
    lock = threading.Lock()

    def answer(_request: dict[str, Any]) -> str | Reply:
        with lock:
            if queue:
                return queue.pop(0)
        return default if default is not None else Reply(status=503, content="script exhausted")

    answer.remaining = queue  # type: ignore[attr-defined]
    return answer


# -- response bodies ------------------------------------------------------------------------------
def completion_body(
    content: str,
    model: str,
    prompt_tokens: int = 0,
    completion_tokens: int = 0,
    finish_reason: str = "stop",
) -> dict[str, Any]:
    """A chat-completions response object."""
    return {
        "id": f"chatcmpl-packlab-{time.time_ns()}",
        "object": "chat.completion",
        "created": int(time.time()),
        "model": model,
        "choices": [
            {
                "index": 0,
                "message": {"role": "assistant", "content": content},
                "finish_reason": finish_reason,
            }
        ],
        "usage": _usage(prompt_tokens, completion_tokens),
    }


def _usage(prompt_tokens: int, completion_tokens: int) -> dict[str, int]:
    return {
        "prompt_tokens": prompt_tokens,
        "completion_tokens": completion_tokens,
        "total_tokens": prompt_tokens + completion_tokens,
    }


_PIECE = re.compile(r"\s*\S+|\s+")


def stream_chunks(reply: Reply, model: str, include_usage: bool) -> Iterator[dict[str, Any]]:
    """The ``chat.completion.chunk`` objects of one answer, as OpenAI streams them: the role,
    the content about a word per chunk, the finish reason, then (if asked) the usage alone."""
    base = {
        "id": f"chatcmpl-packlab-{time.time_ns()}",
        "object": "chat.completion.chunk",
        "created": int(time.time()),
        "model": model,
    }
    extra = {"usage": None} if include_usage else {}

    def chunk(delta: dict[str, Any], finish: str | None = None) -> dict[str, Any]:
        choice = {"index": 0, "delta": delta, "logprobs": None, "finish_reason": finish}
        return {**base, "choices": [choice], **extra}

    yield chunk({"role": "assistant", "content": ""})
    for piece in _PIECE.findall(reply.content):
        yield chunk({"content": piece})
    yield chunk({}, reply.finish_reason)
    if include_usage:
        usage = reply.usage or {}
        yield {**base, "choices": [], "usage": _usage(**usage)}


def error_body(message: str, status: int, param: str | None = None) -> dict[str, Any]:
    """An OpenAI-style error object (the ``openai`` client shows ``message``)."""
    kind = "invalid_request_error" if status < 500 else "server_error"
    code = {404: "not_found", 405: "method_not_allowed", 413: "request_too_large"}.get(status)
    return {"error": {"message": message, "type": kind, "param": param, "code": code}}


# -- request validation ---------------------------------------------------------------------------
def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: object) -> bool:
    # (math.isfinite would overflow on a 400-digit integer)
    return _is_int(value) or (isinstance(value, float) and math.isfinite(value))


def _kind(value: object) -> str:
    """The JSON name of a value's type, for messages."""
    if value is None:
        return "null"
    if value == [] or value == {}:
        return f"an empty {'array' if isinstance(value, list) else 'object'}"
    return {
        bool: "a boolean",
        int: "an integer",
        float: "a number",
        str: "a string",
        list: "an array",
        dict: "an object",
    }.get(type(value), type(value).__name__)


def _show(value: object) -> str:
    """A value for a message: scalars as JSON (cut short), containers by their kind only."""
    if isinstance(value, (list, dict)):
        return _kind(value)
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _check_part(part: object, where: str) -> None:
    if not isinstance(part, dict):
        raise RequestError(f"{where} must be an object, got {_kind(part)}", where)
    kind = part.get("type")
    if kind == "text":
        if not isinstance(part.get("text"), str):
            raise RequestError(
                f"{where}.text must be a string, got {_kind(part.get('text'))}", f"{where}.text"
            )
    elif kind == "image_url":
        image = part.get("image_url")
        url = image.get("url") if isinstance(image, dict) else image
        if not isinstance(url, str):
            raise RequestError(
                f"{where}.image_url must be an object with a string url, got {_kind(image)}",
                f"{where}.image_url",
            )
    else:
        raise RequestError(
            f"{where}.type must be 'text' or 'image_url', got {_show(kind)}",
            f"{where}.type",
        )


def _check_messages(messages: object) -> None:
    if messages is None:
        raise RequestError("'messages' is required: a list of {role, content} objects", "messages")
    if not isinstance(messages, list) or not messages:
        raise RequestError(
            f"'messages' must be a non-empty array, got {_kind(messages)}", "messages"
        )
    for i, m in enumerate(messages):
        where = f"messages[{i}]"
        if not isinstance(m, dict):
            raise RequestError(f"{where} must be an object, got {_kind(m)}", where)
        if m.get("role") not in ROLES:
            raise RequestError(
                f"{where}.role must be one of {', '.join(ROLES)}, got {_show(m.get('role'))}",
                f"{where}.role",
            )
        content = m.get("content")
        if isinstance(content, list):
            for j, part in enumerate(content):
                _check_part(part, f"{where}.content[{j}]")
        elif not isinstance(content, str):
            raise RequestError(
                f"{where}.content must be a string or an array of parts, got {_kind(content)}",
                f"{where}.content",
            )


def _check_options(request: dict[str, Any]) -> None:
    def optional(name: str, ok: Callable[[object], bool], rule: str) -> None:
        value = request.get(name)
        if value is not None and not ok(value):
            raise RequestError(f"'{name}' must be {rule}, got {_show(value)}", name)

    optional("model", lambda v: isinstance(v, str), "a string")
    for name in ("max_tokens", "max_completion_tokens"):
        optional(
            name,
            lambda v: _is_int(v) and 1 <= v <= MAX_TOKENS_LIMIT,  # type: ignore[operator]
            f"an integer in [1, {MAX_TOKENS_LIMIT}]",
        )
    optional("stream", lambda v: isinstance(v, bool), "a boolean")
    optional(
        "stream_options",
        lambda v: isinstance(v, dict) and isinstance(v.get("include_usage", False), bool),
        "an object with a boolean include_usage",
    )
    optional("temperature", lambda v: _is_number(v) and 0 <= v <= 2, "a number in [0, 2]")  # type: ignore[operator]
    optional("top_p", lambda v: _is_number(v) and 0 <= v <= 1, "a number in [0, 1]")  # type: ignore[operator]
    optional("seed", _is_int, "an integer")
    optional(
        "stop",
        lambda v: (
            isinstance(v, str) or (isinstance(v, list) and all(isinstance(s, str) for s in v))
        ),
        "a string or an array of strings",
    )
    optional("n", lambda v: v == 1 and _is_int(v), "1 (one answer per request is served)")


def validate_chat_request(request: object) -> dict[str, Any]:
    """The request if it is a chat-completions request this server can answer; RequestError
    (one line naming the field and what is wrong) otherwise. Images are decoded later, by the
    answer function that uses them."""
    if not isinstance(request, dict):
        raise RequestError(f"the request body must be a JSON object, got {_kind(request)}")
    _check_messages(request.get("messages"))
    _check_options(request)
    return request


def requested_max_tokens(request: dict[str, Any], default: int) -> int:
    """``max_completion_tokens`` (the newer name), else ``max_tokens``, else ``default``."""
    for name in ("max_completion_tokens", "max_tokens"):
        if request.get(name) is not None:
            return int(request[name])
    return default


def parse_body(raw: bytes) -> dict[str, Any]:
    """The validated request in ``raw``; RequestError when it is not JSON or not valid."""
    try:
        request = json.loads(raw)
    except RecursionError:
        raise RequestError("the request body is not valid JSON: nested too deeply") from None
    except json.JSONDecodeError as e:
        raise RequestError(
            f"the request body is not valid JSON: {e.msg} at line {e.lineno} column {e.colno}"
        ) from None
    except UnicodeDecodeError:
        raise RequestError("the request body is not valid JSON: not UTF-8 text") from None
    except ValueError as e:  # e.g. an integer past Python's digit limit
        raise RequestError(
            f"the request body is not valid JSON: {' '.join(str(e).split())[:120]}"
        ) from None
    return validate_chat_request(request)


# -- the HTTP server -----------------------------------------------------------------------------
class ChatServer:
    """A running server: ``port``, ``base_url`` (``http://host:port/v1``), the ``requests``
    bodies it accepted (and their ``headers``), and ``close()`` (also on leaving a ``with``
    block)."""

    def __init__(
        self,
        httpd: ThreadingHTTPServer,
        thread: threading.Thread,
        stop: threading.Event,
        requests: list[dict[str, Any]],
        headers: list[dict[str, str]],
        model_name: str,
    ) -> None:
        self._httpd, self._thread, self._stop = httpd, thread, stop
        self.requests = requests
        self.headers = headers
        self.model_name = model_name
        self.host, self.port = httpd.server_address[:2]

    @property
    def base_url(self) -> str:
        return f"http://{self.host}:{self.port}/v1"

    def close(self) -> None:
        self._stop.set()  # wakes handlers sleeping on a scripted delay
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(timeout=5)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


ROUTES = {"/v1/chat/completions": ("POST",), "/v1/models": ("GET",), "/health": ("GET",)}


def serve(
    answer_fn: AnswerFn, host: str = "127.0.0.1", port: int = 0, model_name: str = "packlab-test"
) -> ChatServer:
    """Start serving ``answer_fn`` in a background thread as model ``model_name``; returns the
    handle (bound port in ``.port``)."""
    stop = threading.Event()
    requests: list[dict[str, Any]] = []
    headers: list[dict[str, str]] = []
    lock = threading.Lock()
    created = int(time.time())
    model_card = {"id": model_name, "object": "model", "created": created, "owned_by": "packlab"}

    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"
        timeout = CONNECTION_TIMEOUT_S

        def log_message(self, *args: Any) -> None:  # quiet
            pass

        # -- writing ------------------------------------------------------------------------
        def _send(self, status: int, body: bytes, extra: dict[str, str] | None = None) -> None:
            try:
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
                for k, v in (extra or {}).items():
                    self.send_header(k, v)
                self.end_headers()
                self.wfile.write(body)
            except (BrokenPipeError, ConnectionResetError):  # the client gave up (deadline)
                self.close_connection = True

        def _json(
            self, status: int, obj: dict[str, Any], extra: dict[str, str] | None = None
        ) -> None:
            self._send(status, json.dumps(obj).encode(), extra)

        def _error(
            self,
            status: int,
            message: str,
            param: str | None = None,
            extra: dict[str, str] | None = None,
        ) -> None:
            self._json(status, error_body(message, status, param), extra)

        def _stream(self, events: Iterable[dict[str, Any]]) -> None:
            """Server-sent events in HTTP/1.1 chunked encoding, ending with ``data: [DONE]``."""
            try:
                self.send_response(200)
                self.send_header("Content-Type", "text/event-stream")
                self.send_header("Cache-Control", "no-cache")
                self.send_header("Transfer-Encoding", "chunked")
                self.end_headers()
                lines = [f"data: {json.dumps(e)}\n\n" for e in events] + ["data: [DONE]\n\n"]
                for line in lines:
                    data = line.encode()
                    self.wfile.write(b"%X\r\n%s\r\n" % (len(data), data))
                    self.wfile.flush()
                self.wfile.write(b"0\r\n\r\n")
            except (BrokenPipeError, ConnectionResetError):
                self.close_connection = True

        # -- routing ------------------------------------------------------------------------
        def _route(self, method: str) -> str | None:
            """The route for this request, or None after answering 404 / 405."""
            path = self.path.split("?", 1)[0].rstrip("/") or "/"
            if path.startswith("/v1/models/") and method == "GET":
                return path
            allowed = ROUTES.get(path)
            if allowed is None:
                self._discard_body()
                self._error(
                    404,
                    f"no route {method} {path}: this server has POST "
                    "/v1/chat/completions, GET /v1/models and GET /health",
                )
                return None
            if method not in allowed:
                self._discard_body()
                self._error(
                    405,
                    f"{path} takes {', '.join(allowed)}, not {method}",
                    extra={"Allow": ", ".join(allowed)},
                )
                return None
            return path

        def _discard_body(self) -> None:
            """Read a small unread body (so keep-alive stays in step); close for a large one."""
            try:
                length = int(self.headers.get("Content-Length") or 0)
            except ValueError:
                length = -1
            if 0 <= length <= 1 << 16:
                self.rfile.read(length)
            else:
                self.close_connection = True

        def do_GET(self) -> None:
            path = self._route("GET")
            if path == "/v1/models":
                self._json(200, {"object": "list", "data": [model_card]})
            elif path == "/health":
                self._json(200, {"status": "ok", "model": model_name})
            elif path is not None:
                name = path[len("/v1/models/") :]
                if name == model_name:
                    self._json(200, model_card)
                else:
                    self._error(
                        404,
                        f"model {name!r} is not served; this server serves {model_name!r}",
                        "model",
                    )

        def _unsupported(self) -> None:
            self._route(self.command)

        do_PUT = do_DELETE = do_PATCH = do_OPTIONS = _unsupported

        def _read_body(self) -> bytes:
            if "chunked" in (self.headers.get("Transfer-Encoding") or "").lower():
                self.close_connection = True
                raise RequestError(
                    "send the body with a Content-Length (chunked requests are not read)",
                    status=411,
                )
            text = self.headers.get("Content-Length")
            try:
                length = int(text) if text is not None else 0
            except ValueError:
                length = -1
            if length < 0:
                self.close_connection = True
                raise RequestError(f"Content-Length {text!r} is not a byte count")
            if length > MAX_REQUEST_BYTES:
                self.close_connection = True  # the rest of the body is not read
                raise RequestError(
                    f"the request body has {length:,} bytes; at most {MAX_REQUEST_BYTES:,} are read",
                    status=413,
                )
            return self.rfile.read(length)

        def do_POST(self) -> None:
            if self._route("POST") is None:
                return
            try:
                request = parse_body(self._read_body())
            except RequestError as e:
                self._error(e.status, e.message, e.param)
                return
            with lock:
                requests.append(request)
                headers.append(dict(self.headers.items()))
            try:
                reply = answer_fn(request)
            except RequestError as e:  # found while answering, e.g. an image that does not decode
                self._error(e.status, e.message, e.param)
                return
            except Exception as e:
                log.exception("the answer function failed on a request")
                detail = " ".join(str(e).split())[:300] or "no detail"
                self._error(500, f"the model failed on this request: {detail}")
                return
            self._answer(request, Reply(content=reply) if isinstance(reply, str) else reply)

        def _answer(self, request: dict[str, Any], reply: Reply) -> None:
            if reply.delay_s > 0 and stop.wait(reply.delay_s):
                return  # shutting down
            if reply.raw is not None:
                self._send(200, reply.raw.encode())
            elif reply.status != 200:
                self._error(reply.status, reply.content or f"status {reply.status}")
            elif request.get("stream"):
                include_usage = bool((request.get("stream_options") or {}).get("include_usage"))
                self._stream(stream_chunks(reply, model_name, include_usage))
            else:
                body = completion_body(
                    reply.content,
                    model_name,
                    finish_reason=reply.finish_reason,
                    **(reply.usage or {}),
                )
                self._json(200, body)

    httpd = ThreadingHTTPServer((host, port), Handler)
    httpd.daemon_threads = True
    thread = threading.Thread(
        target=httpd.serve_forever,
        kwargs={"poll_interval": 0.05},
        name=f"packlab-serve-{httpd.server_address[1]}",
        daemon=True,
    )
    thread.start()
    return ChatServer(httpd, thread, stop, requests, headers, model_name)


# -- serving a local model (vlm extra) -----------------------------------------------------------
def decode_image_url(url: str, where: str) -> Any:
    """The RGB PIL image of a ``data:image/...;base64,...`` URL; RequestError saying what is
    wrong with it otherwise (no downloads: a test server must not fetch URLs)."""
    from PIL import Image

    head, sep, data = url.partition(",")
    if not url.startswith("data:") or not sep or ";base64" not in head:
        raise RequestError(
            f"{where}: only data:image/...;base64, URLs are served (no downloads)", where
        )
    try:
        raw = base64.b64decode(data, validate=True)
    except (binascii.Error, ValueError):
        raise RequestError(f"{where}: the image data is not valid base64", where) from None
    try:
        with Image.open(io.BytesIO(raw)) as im:
            w, h = im.size
            if w * h > MAX_IMAGE_PIXELS:
                raise RequestError(
                    f"{where}: the image has {w} x {h} pixels; at most {MAX_IMAGE_PIXELS:,} are served",
                    where,
                )
            return im.convert("RGB")
    except RequestError:
        raise
    except Image.UnidentifiedImageError:
        raise RequestError(f"{where}: the data is not an image (PNG, JPEG, ...)", where) from None
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError):  # PIL's ways to refuse
        raise RequestError(
            f"{where}: the image does not decode (corrupt or truncated)", where
        ) from None


def from_openai_messages(messages: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """OpenAI chat messages -> the Hugging Face chat messages of :mod:`packlab.vlm.prompt`
    (image data URLs decoded to PIL images). The inverse of ``endpoint.to_openai_messages``.
    Raises RequestError naming the part that cannot be used."""
    out = []
    for i, m in enumerate(messages):
        content = m["content"]
        if isinstance(content, str):
            out.append({"role": m["role"], "content": [{"type": "text", "text": content}]})
            continue
        parts = []
        for j, c in enumerate(content):
            where = f"messages[{i}].content[{j}]"
            if c.get("type") == "text":
                parts.append({"type": "text", "text": c["text"]})
            elif c.get("type") == "image_url":
                url = c["image_url"]["url"] if isinstance(c["image_url"], dict) else c["image_url"]
                parts.append(
                    {"type": "image", "image": decode_image_url(url, f"{where}.image_url")}
                )
            else:
                raise RequestError(
                    f"{where}: unsupported content part type {c.get('type')!r}", where
                )
        out.append({"role": m["role"], "content": parts})
    return out


def served_name(model: str) -> str:
    """The name a model is served under by default: a ``tiny:F:S`` spec as it is, a checkpoint
    by its directory's name (never the path, which would tell clients about the server's disk)."""
    if model.startswith("tiny:"):
        return model
    return Path(model).resolve().name or "packlab-model"


def model_answer_fn(
    model: str | Any = "tiny:qwen3_5:tiny",
    max_new_tokens: int = 64,
    reuse_prefix: bool = True,
    **processing: Any,
) -> AnswerFn:
    """Answer with a local model (a ``VLM``, a checkpoint directory or ``tiny:F:S``), greedy.

    ``max_completion_tokens`` / ``max_tokens`` in a request cap the answer length. Requests are
    served one at a time. Messages the model cannot take (an image that does not decode, an
    order of roles the chat template refuses) raise RequestError (400).
    """
    from jinja2 import TemplateError

    from packlab.vlm.inference import PrefixCachedGenerator
    from packlab.vlm.processing import ProcessingConfig
    from packlab.vlm.sft import make_model

    vlm = make_model(model) if isinstance(model, str) else model
    generator = PrefixCachedGenerator(
        vlm, ProcessingConfig(**processing), max_new_tokens, reuse_prefix
    )
    lock = threading.Lock()

    def answer(request: dict[str, Any]) -> Reply:
        messages = from_openai_messages(request["messages"])
        with lock:
            generator.max_new_tokens = requested_max_tokens(request, max_new_tokens)
            try:
                gen = generator.generate(messages)
            except TemplateError as e:
                raise RequestError(
                    f"the chat template refused the messages: {e.message}", "messages"
                ) from None
            except ValueError as e:  # the encoder's input checks, e.g. longer than max_length
                raise RequestError(
                    f"the model cannot take these messages: {e}", "messages"
                ) from None
        return Reply(
            content=gen.text,
            usage={"prompt_tokens": gen.prompt_tokens, "completion_tokens": len(gen.token_ids)},
            finish_reason="stop" if gen.finished else "length",
        )

    return answer


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model",
        default="tiny:qwen3_5:tiny",
        help="checkpoint directory or tiny:<family>:<size> (default: tiny random)",
    )
    parser.add_argument(
        "--served-name",
        default=None,
        help="the model's name in /v1/models and in answers (default: the checkpoint "
        "directory's name, or the tiny:F:S spec)",
    )
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument("--max-new-tokens", type=int, default=64)


def run_server(args: argparse.Namespace) -> int:
    """Serve ``args.model`` until interrupted (the ``packlab serve`` command)."""
    from packlab.core.errors import ConfigError

    model = args.model
    if not model.startswith("tiny:") and not (Path(model) / "config.json").is_file():
        raise ConfigError(
            f"--model {model!r}: not a checkpoint directory (no config.json) "
            "and not tiny:<family>:<size>"
        )
    if not 0 <= args.port <= 65535:
        raise ConfigError(f"--port {args.port}: must be in [0, 65535] (0: any free port)")
    if not 1 <= args.max_new_tokens <= MAX_TOKENS_LIMIT:
        raise ConfigError(
            f"--max-new-tokens {args.max_new_tokens}: must be in [1, {MAX_TOKENS_LIMIT}]"
        )
    name = args.served_name or served_name(model)
    answer_fn = model_answer_fn(model, args.max_new_tokens)
    try:
        server = serve(answer_fn, args.host, args.port, model_name=name)
    except (OSError, OverflowError) as e:  # port in use, no such address, port out of range
        reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        raise ConfigError(
            f"--host {args.host} --port {args.port}: cannot listen there ({reason})"
        ) from None
    print(f"serving {name!r} at {server.base_url} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m packlab.vlm.serve",
        description="Serve a packing VLM over an OpenAI-compatible "
        "/v1/chat/completions API (a test server).",
    )
    add_arguments(parser)
    return run_server(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
