"""A small OpenAI-compatible chat-completions server, for tests and local trials.

``serve(answer_fn)`` starts a :class:`http.server.ThreadingHTTPServer` in a background thread
(on 127.0.0.1 and a free port by default) and returns a :class:`ChatServer` handle (``.port``,
``.base_url``, ``.requests``, ``.close()``; a context manager). Each valid
``POST /v1/chat/completions`` calls ``answer_fn(request_body)``, which returns either the
assistant text or a :class:`Reply` that can also delay the answer, fail with an HTTP status, or
send a raw (malformed) body.

Two answer functions are provided:

- :func:`scripted` plays a list of answers in order (tests of the ``endpoint`` policy; no torch);
- :func:`packlab.vlm.serve.model_answers.model_answer_fn` answers with a local model through the
  same greedy generator as the ``vlm`` policy (needs the vlm extra): OpenAI messages are
  converted back to the chat messages of :mod:`packlab.vlm.prompt.render`, images decoded from
  their data URLs.

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
  "param", "code"}}`` saying what and where (:mod:`packlab.vlm.serve.protocol`); a body over
  :data:`~packlab.vlm.serve.protocol.MAX_REQUEST_BYTES` gets 413;
  an unknown route 404, a known route with another method 405. A failure of the model itself
  is a 500 whose message says so (the traceback goes to the server's log, not the client).

Sampling options (``temperature``, ``top_p``, ``seed``, ``stop``) are accepted when well typed and
ignored: answers are greedy. Any ``model`` value is answered by the one served model.

Command line (serves the tiny random model unless ``--model`` names a checkpoint)::

    packlab serve --model tiny:qwen3_5:tiny --port 8000   # or python -m packlab.vlm.serve

(:mod:`packlab.vlm.serve.command`).
This is the offline test server for tiny models: one generation at a time per model (a lock), no
auth. Real checkpoints are served by vLLM, which batches the requests of many episodes:
``packlab serve --engine vllm DIR`` (:mod:`packlab.vlm.serve.vllm_command`).
"""

from __future__ import annotations

import json
import logging
import sys
import threading
import time
from collections.abc import Iterable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Self

from packlab.vlm.serve.protocol import (
    MAX_REQUEST_BYTES,
    AnswerFn,
    Reply,
    RequestError,
    completion_body,
    error_body,
    parse_body,
    stream_chunks,
)

log = logging.getLogger(__name__)

#: Seconds a connection may stay silent before the server drops it (a stalled client cannot
#: hold a server thread for ever).
CONNECTION_TIMEOUT_S = 60.0


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


class _ChatHTTPServer(ThreadingHTTPServer):
    """The HTTP server, holding what its request handlers share."""

    daemon_threads = True

    def __init__(self, address: tuple[str, int], answer_fn: AnswerFn, model_name: str) -> None:
        super().__init__(address, _ChatHandler)
        self.answer_fn = answer_fn
        self.model_name = model_name
        self.model_card = {
            "id": model_name,
            "object": "model",
            "created": int(time.time()),
            "owned_by": "packlab",
        }
        self.stop = threading.Event()  # set on close: wakes handlers sleeping on a delay
        self.lock = threading.Lock()
        self.requests: list[dict[str, Any]] = []  # accepted request bodies, in order
        self.recorded_headers: list[dict[str, str]] = []  # and their HTTP headers

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A client that hung up mid-answer (its own timeout, a stopped run) is routine: no
        traceback on stderr. Anything else is reported as the standard library does."""
        if isinstance(sys.exc_info()[1], (BrokenPipeError, ConnectionResetError, TimeoutError)):
            return
        super().handle_error(request, client_address)


class ChatServer:
    """A running server: ``port``, ``base_url`` (``http://host:port/v1``), the ``requests``
    bodies it accepted (and their ``headers``), and ``close()`` (also on leaving a ``with``
    block)."""

    def __init__(self, httpd: _ChatHTTPServer, thread: threading.Thread) -> None:
        self._httpd, self._thread = httpd, thread
        self.requests = httpd.requests
        self.headers = httpd.recorded_headers
        self.model_name = httpd.model_name
        host, self.port = httpd.server_address[:2]
        assert isinstance(host, str)  # the bound address: getsockname() names the host by a str
        self.host = host

    @property
    def base_url(self) -> str:
        return f"http://{self.host}:{self.port}/v1"

    def close(self) -> None:
        self._httpd.stop.set()  # wakes handlers sleeping on a scripted delay
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(timeout=5)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


ROUTES = {"/v1/chat/completions": ("POST",), "/v1/models": ("GET",), "/health": ("GET",)}


class _ChatHandler(BaseHTTPRequestHandler):
    """One connection of the chat server (``self.server`` is the :class:`_ChatHTTPServer`)."""

    server: _ChatHTTPServer
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

    def _json(self, status: int, obj: dict[str, Any], extra: dict[str, str] | None = None) -> None:
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
            self._json(200, {"object": "list", "data": [self.server.model_card]})
        elif path == "/health":
            self._json(200, {"status": "ok", "model": self.server.model_name})
        elif path is not None:
            name = path[len("/v1/models/") :]
            if name == self.server.model_name:
                self._json(200, self.server.model_card)
            else:
                self._error(
                    404,
                    f"model {name!r} is not served; this server serves {self.server.model_name!r}",
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
        with self.server.lock:
            self.server.requests.append(request)
            self.server.recorded_headers.append(dict(self.headers.items()))
        try:
            reply = self.server.answer_fn(request)
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
        if reply.delay_s > 0 and self.server.stop.wait(reply.delay_s):
            return  # shutting down
        if reply.raw is not None:
            self._send(200, reply.raw.encode())
        elif reply.status != 200:
            self._error(reply.status, reply.content or f"status {reply.status}")
        elif request.get("stream"):
            include_usage = bool((request.get("stream_options") or {}).get("include_usage"))
            self._stream(stream_chunks(reply, self.server.model_name, include_usage))
        else:
            body = completion_body(
                reply.content,
                self.server.model_name,
                finish_reason=reply.finish_reason,
                **(reply.usage or {}),
            )
            self._json(200, body)


def serve(
    answer_fn: AnswerFn, host: str = "127.0.0.1", port: int = 0, model_name: str = "packlab-test"
) -> ChatServer:
    """Start serving ``answer_fn`` in a background thread as model ``model_name``; returns the
    handle (bound port in ``.port``)."""
    httpd = _ChatHTTPServer((host, port), answer_fn, model_name)
    thread = threading.Thread(
        target=httpd.serve_forever,
        kwargs={"poll_interval": 0.05},
        name=f"packlab-serve-{httpd.server_address[1]}",
        daemon=True,
    )
    thread.start()
    return ChatServer(httpd, thread)
