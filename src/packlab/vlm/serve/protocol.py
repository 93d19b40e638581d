"""The OpenAI chat-completions contract as this project's server speaks it (stdlib only):
request validation, the response and error bodies, and what an answer function returns.

- a client's mistake (body not JSON, not an object, no ``messages``, a wrong type, ``n`` other
  than 1, ...) is a :class:`RequestError` naming the field (``param``) and what is wrong; the
  server answers it with 400 (or the error's status) and ``{"error": {"message", "type",
  "param", "code"}}`` (:func:`error_body`);
- :func:`completion_body` is a ``chat.completion``; :func:`stream_chunks` the
  ``chat.completion.chunk`` objects of a streamed answer (a usage chunk when asked);
- sampling options (``temperature``, ``top_p``, ``seed``, ``stop``) are accepted when well typed
  and ignored: answers are greedy.
"""

from __future__ import annotations

import json
import math
import re
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

#: Largest request body read (a long history of 224-pixel PNG heightmaps is well under 1 MiB).
MAX_REQUEST_BYTES = 32 << 20
#: Largest ``max_tokens`` served (the action is about 20 tokens).
MAX_TOKENS_LIMIT = 4096
ROLES = ("system", "user", "assistant")


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
