"""The ``endpoint`` policy: the packing VLM behind any OpenAI-compatible chat-completions server
(vLLM, SGLang, a hosted API). Standard library only (urllib + json); no torch.

The context is rendered exactly as for the local policy (:mod:`packlab.vlm.context`), then turned
into the OpenAI chat format: text parts as ``{"type": "text", "text": ...}``, images as PNG data
URLs (``{"type": "image_url", "image_url": {"url": "data:image/png;base64,..."}}``), messages
without images as plain strings. Requests are greedy (``temperature`` 0) by default.

Failures, following DESIGN.md section 4 (a step that cannot get an action is data):

- timeouts, connection errors, HTTP 5xx, 408 and 429 are retried ``retries`` times with
  exponential backoff; if every attempt fails the step returns :class:`Unparsable` with the error
  (``text`` empty), which the episode records as an invalid ``unparsable`` step;
- HTTP 400 and 413 (e.g. a context longer than the served model accepts) are not retried and
  return :class:`Unparsable` with the server's message;
- an answer that does not parse (or a response that is not the expected JSON) is
  :class:`Unparsable` with the parser's reason;
- HTTP 401, 403 and 404 mean the configuration is wrong (key, URL, model name): they raise
  :class:`EndpointError` at once rather than quietly filling a bench run with invalid steps, and
  so do ``max_consecutive_failures`` steps in a row whose every attempt failed in transport.

The API key is read at request time from the environment variable named by ``api_key_env``; it is
never stored on the policy (which stays picklable and carries only its configuration).
Concurrency across cases is the bench runner's job: each worker process builds its own policy.
"""

from __future__ import annotations

import base64
import http.client
import io
import json
import os
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Sequence
from typing import Any

from packlab.errors import ConfigError, PacklabError
from packlab.types import Action, Case, Observation, Unparsable
from packlab.vlm.context import DEFAULT_IMAGE_SIZE, ContextRenderer
from packlab.vlm.parse import parse_or_unparsable
from packlab.vlm.prompt import BLANK_IMAGE, PromptOptions, keep_last_steps

RETRY_STATUS = frozenset({408, 429, 500, 502, 503, 504})
FATAL_STATUS = frozenset({401, 403, 404})


class EndpointError(PacklabError):
    """The endpoint cannot be used at all (wrong URL, model or key; unreachable)."""


class TransportError(Exception):
    """One request failed in transport (retryable) or with a status (``status`` set)."""

    def __init__(self, message: str, status: int | None = None, retryable: bool = True):
        super().__init__(message)
        self.status = status
        self.retryable = retryable


def chat_completions_url(base_url: str) -> str:
    """The chat-completions URL for an OpenAI base URL.

    ``http://host:8000/v1`` and ``http://host:8000`` both give
    ``http://host:8000/v1/chat/completions``; a URL already ending in ``/chat/completions`` is
    kept as it is.
    """
    url = base_url.rstrip("/")
    if url.endswith("/chat/completions"):
        return url
    if not url.endswith("/v1"):
        url += "/v1"
    return url + "/chat/completions"


def png_data_url(image: Any) -> str:
    """A ``data:image/png;base64,...`` URL of a PIL image (or an RGB uint8 numpy array)."""
    from PIL import Image

    if not isinstance(image, Image.Image):
        image = Image.fromarray(image)
    buf = io.BytesIO()
    image.save(buf, format="PNG")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def to_openai_messages(
    messages: Sequence[dict[str, Any]], image_url: Callable[[Any], str] = png_data_url
) -> list[dict[str, Any]]:
    """Hugging Face chat messages (from :mod:`packlab.vlm.prompt`) -> OpenAI chat messages.

    Images become ``image_url`` parts through ``image_url(image)``; a message whose content is
    text only becomes a plain string (what every OpenAI-compatible server accepts for every role).
    """
    out = []
    for m in messages:
        content = m["content"]
        if isinstance(content, str):
            out.append({"role": m["role"], "content": content})
            continue
        if all(c.get("type") == "text" for c in content):
            out.append({"role": m["role"], "content": "".join(c["text"] for c in content)})
            continue
        parts = []
        for c in content:
            if c.get("type") == "text":
                parts.append({"type": "text", "text": c["text"]})
            elif c.get("type") == "image":
                parts.append({"type": "image_url", "image_url": {"url": image_url(c["image"])}})
            else:
                raise ValueError(f"unsupported content part type {c.get('type')!r}")
        out.append({"role": m["role"], "content": parts})
    return out


def post_json(
    url: str, payload: dict[str, Any], timeout_s: float, headers: dict[str, str] | None = None
) -> dict[str, Any]:
    """POST ``payload`` and return the decoded JSON reply; raises :class:`TransportError`."""
    data = json.dumps(payload).encode("utf-8")
    req = urllib.request.Request(
        url,
        data=data,
        method="POST",
        headers={"Content-Type": "application/json", **(headers or {})},
    )
    try:
        with urllib.request.urlopen(req, timeout=timeout_s) as resp:
            body = resp.read()
    except urllib.error.HTTPError as e:
        try:
            detail = e.read().decode("utf-8", "replace")[:500]
        except (OSError, http.client.HTTPException):  # the status is what matters
            detail = ""
        raise TransportError(
            f"HTTP {e.code}: {detail or e.reason}", status=e.code, retryable=e.code in RETRY_STATUS
        ) from None
    except urllib.error.URLError as e:
        reason = e.reason
        if isinstance(reason, TimeoutError):
            raise TransportError(f"timed out after {timeout_s:g} s") from None
        raise TransportError(f"connection failed: {reason}") from None
    except TimeoutError:
        raise TransportError(f"timed out after {timeout_s:g} s") from None
    except (ConnectionError, http.client.HTTPException, OSError) as e:
        raise TransportError(f"connection failed: {type(e).__name__}: {e}") from None
    try:
        return json.loads(body)
    except ValueError:
        raise TransportError(
            f"response is not JSON: {body[:200]!r}", status=200, retryable=False
        ) from None


def answer_text(reply: dict[str, Any]) -> str:
    """The assistant text of a chat-completions reply; ValueError if there is none."""
    try:
        message = reply["choices"][0]["message"]
    except (KeyError, IndexError, TypeError):
        raise ValueError(
            f"no choices[0].message in the response: {json.dumps(reply)[:200]}"
        ) from None
    content = message.get("content") if isinstance(message, dict) else None
    if isinstance(content, list):  # some servers return content parts
        content = "".join(p.get("text", "") for p in content if isinstance(p, dict))
    if not isinstance(content, str):
        raise ValueError("the response message has no text content")  # noqa: TRY004
    return content


class EndpointPolicy:
    """The packing VLM behind an OpenAI-compatible ``/v1/chat/completions`` server."""

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8000/v1",
        model: str = "default",
        api_key_env: str | None = "OPENAI_API_KEY",
        timeout_s: float = 60.0,
        retries: int = 2,
        backoff_s: float = 0.5,
        max_backoff_s: float = 8.0,
        history: str = "full",
        image: str = "heightmap",
        image_size: int = DEFAULT_IMAGE_SIZE,
        temperature: float = 0.0,
        max_tokens: int = 64,
        seed: int | None = None,
        extra_body: dict[str, Any] | None = None,
        max_consecutive_failures: int = 5,
        max_past_steps: int | None = None,
        name: str = "endpoint",
    ) -> None:
        if not isinstance(base_url, str) or not base_url.startswith(("http://", "https://")):
            raise ConfigError(
                f"base_url = {base_url!r}: expected an http(s) URL such as http://127.0.0.1:8000/v1"
            )
        checks = [
            (timeout_s > 0, "timeout_s", timeout_s, "must be > 0"),
            (isinstance(retries, int) and retries >= 0, "retries", retries, "must be an int >= 0"),
            (backoff_s >= 0 and max_backoff_s >= 0, "backoff_s", backoff_s, "must be >= 0"),
            (temperature >= 0, "temperature", temperature, "must be >= 0"),
            (max_tokens >= 1, "max_tokens", max_tokens, "must be >= 1"),
            (
                max_consecutive_failures >= 1,
                "max_consecutive_failures",
                max_consecutive_failures,
                "must be >= 1",
            ),
        ]
        if max_past_steps is not None:
            checks.append(
                (
                    isinstance(max_past_steps, int) and max_past_steps >= 0,
                    "max_past_steps",
                    max_past_steps,
                    "must be an int >= 0 (or unset for the whole history)",
                )
            )
        for ok, field, value, rule in checks:
            if not ok:
                raise ConfigError(f"{field} = {value!r}: {rule}")
        try:
            self.options = PromptOptions(history, image)  # type: ignore[arg-type]
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        self.name = name
        self.base_url, self.url = base_url, chat_completions_url(base_url)
        self.model = model
        self.api_key_env = api_key_env
        self.timeout_s, self.retries = float(timeout_s), retries
        self.backoff_s, self.max_backoff_s = float(backoff_s), float(max_backoff_s)
        self.image_size = image_size
        self.temperature, self.max_tokens, self.seed = temperature, max_tokens, seed
        self.extra_body = dict(extra_body or {})
        self.max_consecutive_failures = max_consecutive_failures
        # Servers cap the context (vLLM's max_model_len, images per prompt); keep the most recent
        # past steps, by the same rule the trainer uses to fit max_length.
        self.max_past_steps = max_past_steps
        self.step_log: list[dict[str, Any]] = []
        self._renderer: ContextRenderer | None = None
        self._urls: dict[int, tuple[Any, str]] = {}  # id(image) -> (image, data URL)
        self._blank_url: str | None = None
        self._failures = 0

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_renderer"], state["_urls"], state["step_log"] = None, {}, []
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    def config(self) -> dict[str, Any]:
        """The resolved configuration (no secrets), for run records."""
        return {
            "base_url": self.base_url,
            "model": self.model,
            "timeout_s": self.timeout_s,
            "retries": self.retries,
            "temperature": self.temperature,
            "max_tokens": self.max_tokens,
            "options": self.options.to_dict(),
            "image_size": self.image_size,
            "extra_body": self.extra_body,
            "max_past_steps": self.max_past_steps,
        }

    # -- request building ----------------------------------------------------------------------
    def _image_url(self, image: Any) -> str:
        if isinstance(image, str) and image == BLANK_IMAGE:
            if self._blank_url is None:
                from PIL import Image

                self._blank_url = png_data_url(Image.new("RGB", (self.image_size,) * 2))
            return self._blank_url
        # The renderer memoises one PIL image per heightmap, so each past image is encoded once
        # per episode; the entry keeps a reference so that its id cannot be reused meanwhile.
        hit = self._urls.get(id(image))
        if hit is None or hit[0] is not image:
            hit = (image, png_data_url(image))
            self._urls[id(image)] = hit
        return hit[1]

    def payload(self, observation: Observation) -> dict[str, Any]:
        """The chat-completions request body for one observation."""
        if self._renderer is None:
            self._renderer = ContextRenderer(self.options, self.image_size)
        messages = self._renderer.messages(observation)
        if self.max_past_steps is not None:
            messages = keep_last_steps(messages, self.max_past_steps)
        body: dict[str, Any] = {
            "model": self.model,
            "messages": to_openai_messages(messages, self._image_url),
            "temperature": self.temperature,
            "max_tokens": self.max_tokens,
            **({"seed": self.seed} if self.seed is not None else {}),
        }
        body.update(self.extra_body)
        return body

    def _headers(self) -> dict[str, str]:
        key = os.environ.get(self.api_key_env) if self.api_key_env else None
        return {"Authorization": f"Bearer {key}"} if key else {}

    # -- the Policy protocol -------------------------------------------------------------------
    def reset(self, case: Case, seed: int) -> None:
        self._renderer = ContextRenderer(self.options, self.image_size)
        self._urls = {}
        self._failures = 0
        self.step_log = []

    def act(self, observation: Observation) -> Action | Unparsable:
        t0 = time.perf_counter()
        body = self.payload(observation)
        errors: list[str] = []
        last: TransportError | None = None
        reply = None
        attempts = 0
        for attempt in range(self.retries + 1):
            attempts = attempt + 1
            try:
                reply = post_json(self.url, body, self.timeout_s, self._headers())
                break
            except TransportError as e:
                errors.append(str(e))
                last = e
                if e.status in FATAL_STATUS:
                    raise EndpointError(
                        f"endpoint {self.url} (model {self.model!r}): {e}"
                    ) from None
                if not e.retryable or attempt == self.retries:
                    break
                time.sleep(min(self.backoff_s * 2**attempt, self.max_backoff_s))
        log: dict[str, Any] = {
            "step": observation.step_index,
            "attempts": attempts,
            "errors": errors,
        }
        if reply is None:
            # Only transport failures (every attempt timed out / 5xx / refused) count towards
            # giving up; a 400 for one over-long context is that step's problem alone.
            self._failures = self._failures + 1 if last is not None and last.retryable else 0
            log.update(latency_s=round(time.perf_counter() - t0, 6), parsed=False)
            self.step_log.append(log)
            if self._failures >= self.max_consecutive_failures:
                raise EndpointError(
                    f"endpoint {self.url}: {self._failures} steps in a row failed; "
                    f"last error: {errors[-1]}"
                )
            return Unparsable(text="", error=f"endpoint: {errors[-1]} ({attempts} attempt(s))")
        self._failures = 0
        try:
            text = answer_text(reply)
        except ValueError as e:
            log.update(latency_s=round(time.perf_counter() - t0, 6), parsed=False)
            self.step_log.append(log)
            return Unparsable(text=json.dumps(reply)[:1000], error=f"endpoint: {e}")
        action = parse_or_unparsable(text)
        usage = reply.get("usage") if isinstance(reply.get("usage"), dict) else {}
        log.update(
            latency_s=round(time.perf_counter() - t0, 6),
            prompt_tokens=usage.get("prompt_tokens"),
            completion_tokens=usage.get("completion_tokens"),
            finish_reason=(reply.get("choices") or [{}])[0].get("finish_reason"),
            parsed=isinstance(action, Action),
        )
        self.step_log.append(log)
        return action
