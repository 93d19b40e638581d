"""A small OpenAI-compatible chat-completions server, for tests and local trials.

``serve(answer_fn)`` starts a :class:`http.server.ThreadingHTTPServer` in a background thread
(on 127.0.0.1 and a free port by default) and returns a :class:`ChatServer` handle (``.port``,
``.base_url``, ``.requests``, ``.close()``; a context manager). Each ``POST /v1/chat/completions``
calls ``answer_fn(request_body)``, which returns either the assistant text or a :class:`Reply`
that can also delay the answer, fail with an HTTP status, or send a raw (malformed) body.

Two answer functions are provided:

- :func:`scripted` plays a list of answers in order (tests of the ``endpoint`` policy; no torch);
- :func:`model_answer_fn` answers with a local model through the same greedy generator as the
  ``vlm`` policy (needs the vlm extra): OpenAI messages are converted back to the chat messages
  of :mod:`packlab.vlm.prompt`, images decoded from their data URLs.

Command line (serves the tiny random model unless ``--model`` names a checkpoint)::

    python -m packlab.vlm.serve --model tiny:qwen3_5:tiny --port 8000

This is a test server: one request at a time per model (a lock), no streaming, no auth.
"""

from __future__ import annotations

import argparse
import base64
import io
import json
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Self


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
        "usage": {
            "prompt_tokens": prompt_tokens,
            "completion_tokens": completion_tokens,
            "total_tokens": prompt_tokens + completion_tokens,
        },
    }


class ChatServer:
    """A running server: ``port``, ``base_url`` (``http://host:port/v1``), the ``requests``
    bodies it received (and their ``headers``), and ``close()`` (also on leaving a ``with``
    block)."""

    def __init__(
        self,
        httpd: ThreadingHTTPServer,
        thread: threading.Thread,
        stop: threading.Event,
        requests: list[dict[str, Any]],
        headers: list[dict[str, str]],
    ) -> None:
        self._httpd, self._thread, self._stop = httpd, thread, stop
        self.requests = requests
        self.headers = headers
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


def serve(
    answer_fn: AnswerFn, host: str = "127.0.0.1", port: int = 0, model_name: str = "packlab-test"
) -> ChatServer:
    """Start serving ``answer_fn`` in a background thread; returns the handle (bound port in
    ``.port``)."""
    stop = threading.Event()
    requests: list[dict[str, Any]] = []
    headers: list[dict[str, str]] = []
    lock = threading.Lock()

    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args: Any) -> None:  # quiet
            pass

        def _send(self, status: int, body: bytes) -> None:
            try:
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)
            except (BrokenPipeError, ConnectionResetError):  # the client gave up (timeout)
                pass

        def do_GET(self) -> None:
            if self.path.rstrip("/") == "/v1/models":
                body = {"object": "list", "data": [{"id": model_name, "object": "model"}]}
                self._send(200, json.dumps(body).encode())
            else:
                self._send(404, b'{"error": {"message": "not found"}}')

        def do_POST(self) -> None:
            length = int(self.headers.get("Content-Length") or 0)
            raw = self.rfile.read(length)
            if self.path.rstrip("/") != "/v1/chat/completions":
                self._send(404, b'{"error": {"message": "not found"}}')
                return
            try:
                request = json.loads(raw)
            except ValueError:
                self._send(400, b'{"error": {"message": "body is not JSON"}}')
                return
            with lock:
                requests.append(request)
                headers.append(dict(self.headers.items()))
            try:
                reply = answer_fn(request)
            except Exception as e:  # noqa: BLE001 - a server error, reported as such
                msg = json.dumps({"error": {"message": f"{type(e).__name__}: {e}"}})
                self._send(500, msg.encode())
                return
            if isinstance(reply, str):
                reply = Reply(content=reply)
            if reply.delay_s > 0 and stop.wait(reply.delay_s):
                return  # shutting down
            if reply.raw is not None:
                self._send(200, reply.raw.encode())
            elif reply.status != 200:
                msg = json.dumps({"error": {"message": reply.content or f"status {reply.status}"}})
                self._send(reply.status, msg.encode())
            else:
                body = completion_body(
                    reply.content,
                    request.get("model", model_name),
                    finish_reason=reply.finish_reason,
                    **(reply.usage or {}),
                )
                self._send(200, json.dumps(body).encode())

    httpd = ThreadingHTTPServer((host, port), Handler)
    httpd.daemon_threads = True
    thread = threading.Thread(
        target=httpd.serve_forever,
        kwargs={"poll_interval": 0.05},
        name=f"packlab-serve-{httpd.server_address[1]}",
        daemon=True,
    )
    thread.start()
    return ChatServer(httpd, thread, stop, requests, headers)


# -- serving a local model (vlm extra) -----------------------------------------------------------
def from_openai_messages(messages: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """OpenAI chat messages -> the Hugging Face chat messages of :mod:`packlab.vlm.prompt`
    (image data URLs decoded to PIL images). The inverse of ``endpoint.to_openai_messages``."""
    from PIL import Image

    out = []
    for m in messages:
        content = m["content"]
        if isinstance(content, str):
            out.append({"role": m["role"], "content": [{"type": "text", "text": content}]})
            continue
        parts = []
        for c in content:
            if c.get("type") == "text":
                parts.append({"type": "text", "text": c["text"]})
            elif c.get("type") == "image_url":
                url = c["image_url"]["url"] if isinstance(c["image_url"], dict) else c["image_url"]
                if not url.startswith("data:"):
                    raise ValueError("only data: image URLs are served (no downloads)")
                data = base64.b64decode(url.split(",", 1)[1])
                with Image.open(io.BytesIO(data)) as im:
                    parts.append({"type": "image", "image": im.convert("RGB")})
            else:
                raise ValueError(f"unsupported content part type {c.get('type')!r}")
        out.append({"role": m["role"], "content": parts})
    return out


def model_answer_fn(
    model: str | Any = "tiny:qwen3_5:tiny",
    max_new_tokens: int = 64,
    reuse_prefix: bool = True,
    **processing: Any,
) -> AnswerFn:
    """Answer with a local model (a ``VLM``, a checkpoint directory or ``tiny:F:S``), greedy.

    ``max_tokens`` in a request caps the answer length. Requests are served one at a time.
    """
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
            generator.max_new_tokens = int(request.get("max_tokens") or max_new_tokens)
            gen = generator.generate(messages)
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
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument("--max-new-tokens", type=int, default=64)


def run_server(args: argparse.Namespace) -> int:
    """Serve ``args.model`` until interrupted (the ``packlab serve`` command)."""
    server = serve(
        model_answer_fn(args.model, args.max_new_tokens),
        args.host,
        args.port,
        model_name=args.model,
    )
    print(f"serving {args.model} at {server.base_url} (Ctrl-C to stop)", flush=True)
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
