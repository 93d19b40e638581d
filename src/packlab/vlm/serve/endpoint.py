"""The ``endpoint`` policy: the packing VLM behind any OpenAI-compatible chat-completions server
(vLLM, SGLang, a hosted API). Standard library (http.client + json) and PIL; no torch.

The context is rendered exactly as for the local policy (:mod:`packlab.vlm.prompt.context`),
then turned into the OpenAI chat format (:mod:`packlab.vlm.serve.openai_messages`: images as PNG
data URLs). Requests are greedy (``temperature`` 0) by default.

Time: every request has a deadline (``deadline_s``, default 30 s) on its whole exchange:
connecting, sending, waiting and reading the last byte of the answer. A watchdog shuts the socket
at the deadline (:mod:`packlab.vlm.serve.transport`), so a server that accepts and never answers,
or trickles bytes, cannot hold a step longer (host-name lookup is the one part outside it). A
request is tried ``1 + retries`` times (default 3) with exponential backoff between tries
(``backoff_s`` doubling, at most ``max_backoff_s``: 0.5 s then 1 s by default). The worst case
of one request is therefore ``tries * deadline_s + backoffs``
(:attr:`EndpointPolicy.worst_case_request_s`: 91.5 s by default) and, since the first request
that fails ends its episode, it is also the most time an episode can lose to a dead or hung
server; a refused connection fails in milliseconds (1.5 s of backoff).

Outcomes, following DESIGN.md section 4 (a step that cannot get an action is data, a server that
cannot be used is not):

- connection refused or reset, deadline passed, answer cut short, HTTP 5xx: retried; when every
  try failed, :class:`~packlab.core.errors.EndpointUnavailable` is raised with one line naming
  the URL, what failed and the tries (the bench records the episode as a ``transport`` error and its
  circuit breaker counts them);
- HTTP 4xx is never retried: 408 and 429 (the server is busy or slow, which says nothing about
  the policy) raise EndpointUnavailable at once; 401, 403 and 404 (key, URL or model wrong) and
  redirects raise :class:`EndpointError`; any other 4xx (400, 413, 422: this request was refused,
  e.g. a context longer than the served model takes) makes the step :class:`Unparsable` with
  the status and the server's reason;
- a 2xx answer that is not JSON, has no ``choices[0].message`` text, or is larger than
  :data:`MAX_RESPONSE_BYTES`, and an answer text that does not parse, make the step
  :class:`Unparsable` (recorded as an invalid ``unparsable`` step; the episode goes on).

The API key is read at request time from the environment variable named by ``api_key_env``; it is
never stored on the policy (which stays picklable and carries only its configuration).
Concurrency across cases is the bench runner's job: each worker process builds its own policy.

Prompt protocols (``prompt``): ``packlab`` (default) is packlab's own prompt and parser;
``reference`` is the reference implementation's (:mod:`packlab.vlm.serve.reference_turns`):
its system and user text, 224 px blue-to-red heightmaps, the thinking prefill and chat-template
switches, 512 answer tokens unless ``max_tokens`` says otherwise, its lenient parser, an optional
second request after an unusable answer (``reask``), and a seeded forced set-aside of a shown
box in place of an answer it cannot use (``fallback="set_aside"``, the reference's relaxed mode)
or an invalid step (``fallback="invalid"``, its strict mode).

Every answer read is labelled with its format event (``strict_json``, ``extra_text`` or
``parse_fail``, as the protocol's parser sees it) in the step log, and reported to the episode
through :meth:`EndpointPolicy.last_answer_format`, so bench records and tables count them.

``tag_requests`` (off by default) sends the OpenAI ``user`` field as ``<case id>/<run seed>``, so
a server's logs can group the requests of one episode and a scripted test server
(:mod:`packlab.vlm.serve.oracle_answers`) can tell apart episodes whose requests read the same.
It names the case: never turn it on for a model under evaluation.
"""

from __future__ import annotations

import json
import os
import time
from typing import Any

from packlab.core.choices import HistoryMode, ImageMode
from packlab.core.errors import ConfigError, EndpointUnavailable
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Case, Observation, Unparsable
from packlab.vlm.prompt.context import DEFAULT_IMAGE_SIZE, ContextRenderer
from packlab.vlm.prompt.parse import logged_answer_format, parse_with_format
from packlab.vlm.prompt.reference import EXTRA_BODY as REFERENCE_EXTRA_BODY
from packlab.vlm.prompt.reference import SAMPLING as REFERENCE_SAMPLING
from packlab.vlm.prompt.reference_parse import Fallback, parse_reference
from packlab.vlm.prompt.render import BLANK_IMAGE, PromptOptions, keep_last_steps
from packlab.vlm.serve.openai_messages import (
    blank_png_data_url,
    png_data_url,
    to_openai_messages,
)
from packlab.vlm.serve.reference_turns import ReferenceTurns, check_fallback, reads_sample_id
from packlab.vlm.serve.transport import MAX_RESPONSE_BYTES, HTTPReply, TransportError, http_post

#: Defaults of :class:`EndpointPolicy` (seconds; tries = 1 + retries).
DEFAULT_DEADLINE_S = 30.0
DEFAULT_RETRIES = 2
DEFAULT_BACKOFF_S = 0.5
DEFAULT_MAX_BACKOFF_S = 4.0
#: 4xx that say the server is busy or slow, not that the request is wrong: not retried (4xx never
#: is), but reported as EndpointUnavailable rather than charged to the policy.
BUSY_STATUS = frozenset({408, 429})
#: 4xx that mean the configuration is wrong (key, URL, model name).
FATAL_STATUS = frozenset({401, 403, 404})
#: The prompt protocols (module docstring) and the answer budget each defaults to.
PROMPTS = ("packlab", "reference")
DEFAULT_MAX_TOKENS = {"packlab": 64, "reference": REFERENCE_SAMPLING["max_tokens"]}


class EndpointError(EndpointUnavailable):
    """The endpoint cannot be used as configured (wrong URL, model or key; a redirect).

    A kind of ``EndpointUnavailable``: every episode would fail the same way, so the bench's
    circuit breaker counts it and stops the run instead of recording the same error per episode.
    """


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


def decode_reply(reply: HTTPReply) -> dict[str, Any]:
    """The JSON object of a 2xx answer; ValueError (one line) when it is not one."""
    if reply.oversized:
        raise ValueError(f"response larger than {MAX_RESPONSE_BYTES:,} bytes")
    try:
        value = json.loads(reply.body)
    except (ValueError, RecursionError):  # RecursionError: absurdly nested garbage
        raise ValueError(f"response is not JSON: {reply.body[:200]!r}") from None
    if not isinstance(value, dict):
        raise ValueError(f"response is not a JSON object: {reply.body[:200]!r}")  # noqa: TRY004
    return value


def answer_text(reply: dict[str, Any]) -> str:
    """The assistant text of a chat-completions reply; ValueError if there is none."""
    try:
        message = reply["choices"][0]["message"]
    except (KeyError, IndexError, TypeError):
        # Keys only: dumping a garbage reply whole could be huge (or too deep to dump).
        keys = ", ".join(sorted(str(k)[:40] for k in reply)[:10]) or "none"
        raise ValueError(
            f"no choices[0].message in the response (its keys: {' '.join(keys.split())})"
        ) from None
    content = message.get("content") if isinstance(message, dict) else None
    if isinstance(content, list):  # some servers return content parts
        content = "".join(
            p["text"] for p in content if isinstance(p, dict) and isinstance(p.get("text"), str)
        )
    if not isinstance(content, str):
        raise ValueError("the response message has no text content")  # noqa: TRY004
    return content


def _finite(value: object, low: float, high: float) -> bool:
    return (
        isinstance(value, (int, float))
        and not isinstance(value, bool)
        and low <= value <= high  # also False for NaN
    )


def _deadline(deadline_s: float | None, timeout_s: float | None) -> tuple[float, str]:
    """(the request deadline, the name it was given under: ``deadline_s`` or its old name
    ``timeout_s``); ConfigError when both are given."""
    if deadline_s is not None and timeout_s is not None:
        raise ConfigError(
            f"deadline_s = {deadline_s!r} and timeout_s = {timeout_s!r}: timeout_s is the "
            "old name of deadline_s; give one"
        )
    deadline = next((v for v in (deadline_s, timeout_s) if v is not None), DEFAULT_DEADLINE_S)
    return deadline, ("timeout_s" if timeout_s is not None else "deadline_s")


def _check_numbers(
    deadline: tuple[str, float],
    retries: int,
    backoff_s: float,
    max_backoff_s: float,
    temperature: float,
    max_tokens: int,
    max_past_steps: int | None,
) -> None:
    """ConfigError (one line) for the first numeric setting out of its range; ``deadline`` is
    (the name it was given under, its value)."""
    field, value = deadline
    checks = [
        (_finite(value, 1e-3, 86400.0), field, value, "must be seconds in [0.001, 86400]"),
        (
            isinstance(retries, int) and 0 <= retries <= 10,
            "retries",
            retries,
            "must be an int in [0, 10]",
        ),
        (_finite(backoff_s, 0.0, 3600.0), "backoff_s", backoff_s, "must be seconds in [0, 3600]"),
        (
            _finite(max_backoff_s, 0.0, 3600.0),
            "max_backoff_s",
            max_backoff_s,
            "must be seconds in [0, 3600]",
        ),
        (_finite(temperature, 0.0, 100.0), "temperature", temperature, "must be >= 0"),
        (
            isinstance(max_tokens, int) and max_tokens >= 1,
            "max_tokens",
            max_tokens,
            "must be an int >= 1",
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
    for ok, name, bad, rule in checks:
        if not ok:
            raise ConfigError(f"{name} = {bad!r}: {rule}")


class EndpointPolicy:
    """The packing VLM behind an OpenAI-compatible ``/v1/chat/completions`` server.

    ``deadline_s`` is the wall-clock limit of one request (``timeout_s`` is its older name);
    ``retries`` extra tries follow a failed one after ``backoff_s * 2**k`` seconds (at most
    ``max_backoff_s``). See the module's docstring for what each failure does.
    """

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8000/v1",
        model: str = "default",
        api_key_env: str | None = "OPENAI_API_KEY",
        deadline_s: float | None = None,
        retries: int = DEFAULT_RETRIES,
        backoff_s: float = DEFAULT_BACKOFF_S,
        max_backoff_s: float = DEFAULT_MAX_BACKOFF_S,
        history: HistoryMode = "full",
        image: ImageMode = "heightmap",
        image_size: int = DEFAULT_IMAGE_SIZE,
        temperature: float = 0.0,
        max_tokens: int | None = None,
        seed: int | None = None,
        extra_body: dict[str, Any] | None = None,
        max_past_steps: int | None = None,
        name: str | None = None,
        timeout_s: float | None = None,
        prompt: str = "packlab",
        reask: bool = False,
        fallback: Fallback = "set_aside",
        tag_requests: bool = False,
    ) -> None:
        if not isinstance(base_url, str) or not base_url.startswith(("http://", "https://")):
            raise ConfigError(
                f"base_url = {base_url!r}: expected an http(s) URL such as http://127.0.0.1:8000/v1"
            )
        deadline, deadline_field = _deadline(deadline_s, timeout_s)
        if prompt not in PROMPTS:
            raise ConfigError(f"prompt = {prompt!r}: choose one of {', '.join(PROMPTS)}")
        if not isinstance(reask, bool):
            raise ConfigError(f"reask = {reask!r}: must be true or false")
        if not isinstance(tag_requests, bool):
            raise ConfigError(f"tag_requests = {tag_requests!r}: must be true or false")
        check_fallback(fallback, prompt)
        if max_tokens is None:
            max_tokens = DEFAULT_MAX_TOKENS[prompt]
        _check_numbers(
            (deadline_field, deadline),
            retries,
            backoff_s,
            max_backoff_s,
            temperature,
            max_tokens,
            max_past_steps,
        )
        self.options = PromptOptions(history, image)  # which checks the names
        self.prompt, self.reask, self.fallback = prompt, reask, fallback
        # Off by default: the tag names the case, which a model under test must not be told.
        self.tag_requests = tag_requests
        self._tag = ""
        # The protocol is part of what a row measures, so a report can tell the two apart.
        self.name = name or ("endpoint (reference prompt)" if prompt == "reference" else "endpoint")
        self.base_url, self.url = base_url, chat_completions_url(base_url)
        self.model = model
        self.api_key_env = api_key_env
        self.deadline_s, self.retries = float(deadline), retries
        self.backoff_s, self.max_backoff_s = float(backoff_s), float(max_backoff_s)
        self.image_size = image_size
        self.temperature, self.max_tokens, self.seed = temperature, max_tokens, seed
        self.extra_body = dict(extra_body or {})
        # Servers cap the context (vLLM's max_model_len, images per prompt); keep the most recent
        # past steps, by the same rule the trainer uses to fit max_length.
        self.max_past_steps = max_past_steps
        self.step_log: list[dict[str, Any]] = []
        self._renderer: ContextRenderer | None = None
        self._urls: dict[int, tuple[Any, str]] = {}  # id(image) -> (image, data URL)
        self._blank_url: str | None = None
        self._reference: ReferenceTurns | None = None

    @property
    def tries(self) -> int:
        return 1 + self.retries

    def backoff(self, retry: int) -> float:
        """Seconds to wait before retry number ``retry`` (1, 2, ...)."""
        return min(self.backoff_s * 2 ** (retry - 1), self.max_backoff_s)

    @property
    def worst_case_request_s(self) -> float:
        """The longest one request can take before it succeeds or raises (every try hits the
        deadline); also the most time an episode can lose to a dead or hung server, since the
        first unavailable request ends it."""
        return self.tries * self.deadline_s + sum(self.backoff(k) for k in range(1, self.tries))

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_renderer"], state["_urls"], state["step_log"] = None, {}, []
        state["_reference"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    def config(self) -> dict[str, Any]:
        """The resolved configuration (no secrets), for run records."""
        return {
            "base_url": self.base_url,
            "model": self.model,
            "deadline_s": self.deadline_s,
            "retries": self.retries,
            "backoff_s": self.backoff_s,
            "max_backoff_s": self.max_backoff_s,
            "worst_case_request_s": self.worst_case_request_s,
            "temperature": self.temperature,
            "max_tokens": self.max_tokens,
            "options": self.options.to_dict(),
            "image_size": self.image_size,
            "extra_body": self.extra_body,
            "max_past_steps": self.max_past_steps,
            "prompt": self.prompt,
            "reask": self.reask,
            "fallback": self.fallback,
            "tag_requests": self.tag_requests,
        }

    # -- request building ----------------------------------------------------------------------
    def _image_url(self, image: Any) -> str:
        if isinstance(image, str) and image == BLANK_IMAGE:
            if self._blank_url is None:
                self._blank_url = blank_png_data_url(self.image_size)
            return self._blank_url
        # The renderer memoises one PIL image per heightmap, so each past image is encoded once
        # per episode; the entry keeps a reference so that its id cannot be reused meanwhile.
        hit = self._urls.get(id(image))
        if hit is None or hit[0] is not image:
            hit = (image, png_data_url(image))
            self._urls[id(image)] = hit
        return hit[1]

    def _body(self, messages: list[dict[str, Any]], protocol: dict[str, Any]) -> dict[str, Any]:
        """A request body: the messages, sampling, the protocol's extras, then ``extra_body``
        (the user's word wins)."""
        body: dict[str, Any] = {
            "model": self.model,
            "messages": messages,
            "temperature": self.temperature,
            "max_tokens": self.max_tokens,
            **({"seed": self.seed} if self.seed is not None else {}),
            **({"user": self._tag} if self.tag_requests else {}),
            **protocol,
        }
        body.update(self.extra_body)
        return body

    def _turns(self) -> ReferenceTurns:
        if self._reference is None:
            self._reference = ReferenceTurns(
                self.options.history, self.options.image, fallback=self.fallback
            )
        return self._reference

    def _reference_view(self, observation: Observation) -> list[dict[str, Any]]:
        view = self._turns().view(observation)
        if self.max_past_steps is not None:
            view = keep_last_steps(view, self.max_past_steps)
        return view

    def payload(self, observation: Observation) -> dict[str, Any]:
        """The chat-completions request body for one observation."""
        if self.prompt == "reference":
            view = self._reference_view(observation)
            extras = {"top_p": REFERENCE_SAMPLING["top_p"], **REFERENCE_EXTRA_BODY}
            return self._body(ReferenceTurns.request(view), extras)
        if self._renderer is None:
            self._renderer = ContextRenderer(self.options, self.image_size)
        messages = self._renderer.messages(observation)
        if self.max_past_steps is not None:
            messages = keep_last_steps(messages, self.max_past_steps)
        return self._body(to_openai_messages(messages, self._image_url), {})

    def _headers(self) -> dict[str, str]:
        key = os.environ.get(self.api_key_env) if self.api_key_env else None
        auth = {"Authorization": f"Bearer {key}"} if key else {}
        return {"Content-Type": "application/json", "Accept": "application/json", **auth}

    @property
    def needs_case(self) -> bool:
        """Handed the case at reset only where an option reads it: ``tag_requests`` (the case id
        in each request) and the reference protocol's relaxed mode (its forced set-aside is
        seeded by the case's sample id, as the reference seeds it)."""
        return self.tag_requests or reads_sample_id(self.prompt, self.fallback)

    # -- the Policy protocol -------------------------------------------------------------------
    def reset(self, start: EpisodeStart | Case, seed: int) -> None:
        self._renderer = ContextRenderer(self.options, self.image_size)
        self._urls = {}
        self.step_log = []
        # Read only when asked for (needs_case): the case's id is not the policy's to know.
        self._tag = (
            f"{start.episode_id}/{seed}" if isinstance(start, Case) and self.tag_requests else ""
        )
        if self.prompt == "reference":
            self._turns().reset(start)

    def _request(self, body: bytes, log: dict[str, Any]) -> HTTPReply:
        """The first answer that is not a transport failure or a 5xx, trying ``self.tries``
        times; raises EndpointUnavailable when every try failed."""
        t0 = time.monotonic()
        errors: list[str] = log["errors"]
        for attempt in range(self.tries):
            if attempt:
                time.sleep(self.backoff(attempt))
            log["attempts"] = attempt + 1
            try:
                reply = http_post(self.url, body, self.deadline_s, self._headers())
            except TransportError as e:
                errors.append(str(e))
                continue
            if 500 <= reply.status <= 599:
                errors.append(f"HTTP {reply.status}: {reply.server_reason()}")
                continue
            return reply
        log["latency_s"] = round(time.monotonic() - t0, 6)
        raise EndpointUnavailable(
            f"endpoint {self.url}: {errors[-1]} ({self.tries} tries in "
            f"{time.monotonic() - t0:.1f} s, deadline {self.deadline_s:g} s each)"
        )

    def _refusal(self, reply: HTTPReply) -> Unparsable:
        """A 3xx or 4xx answer: raise for what the policy cannot be blamed for, else the step's
        Unparsable (the server refused this request, e.g. a context too long)."""
        what = f"HTTP {reply.status} from {self.url}: {reply.server_reason()}"
        if reply.status in BUSY_STATUS:
            raise EndpointUnavailable(f"endpoint {what} (4xx: not retried)")
        if reply.status in FATAL_STATUS or reply.status < 400:
            raise EndpointError(f"endpoint (model {self.model!r}) {what}")
        return Unparsable(text="", error=f"endpoint: {what}")

    def _exchange(
        self, payload: dict[str, Any], log: dict[str, Any]
    ) -> tuple[str, dict[str, Any]] | Unparsable:
        """(answer text, decoded reply) of one request, or the step's Unparsable."""
        t0 = time.perf_counter()
        reply = self._request(json.dumps(payload).encode("utf-8"), log)
        log.update(latency_s=round(time.perf_counter() - t0, 6), status=reply.status, parsed=False)
        if not 200 <= reply.status <= 299:
            return self._refusal(reply)
        try:
            decoded = decode_reply(reply)
            return answer_text(decoded), decoded
        except ValueError as e:
            # The model said nothing usable: an empty answer in the history, the body in the error.
            return Unparsable(text="", error=f"endpoint: {e}")

    @staticmethod
    def _log_reply(log: dict[str, Any], decoded: dict[str, Any], parsed: bool) -> None:
        raw_usage = decoded.get("usage")
        usage = raw_usage if isinstance(raw_usage, dict) else {}
        choice = decoded["choices"][0]
        log.update(
            prompt_tokens=usage.get("prompt_tokens"),
            completion_tokens=usage.get("completion_tokens"),
            finish_reason=choice.get("finish_reason") if isinstance(choice, dict) else None,
            parsed=parsed,
        )

    def act(self, observation: Observation) -> Action | Unparsable:
        log: dict[str, Any] = {"step": observation.step_index, "attempts": 0, "errors": []}
        self.step_log.append(log)
        if self.prompt == "reference":
            return self._act_reference(observation, log)
        got = self._exchange(self.payload(observation), log)
        if isinstance(got, Unparsable):
            return got
        text, decoded = got
        action, event = parse_with_format(text)
        self._log_reply(log, decoded, isinstance(action, Action))
        log["format_event"] = event
        return action

    def last_answer_format(self) -> dict[str, Any] | None:
        """How the latest :meth:`act` read its answer (the episode's answer-format hook,
        DESIGN.md section 7): format event, re-ask (``reask`` on) and forced set-aside; None
        when no answer came back to read."""
        return logged_answer_format(self.step_log[-1]) if self.step_log else None

    def _act_reference(self, observation: Observation, log: dict[str, Any]) -> Action | Unparsable:
        """One step of the reference's protocol: ask, read leniently, re-ask once if enabled,
        and play a seeded forced set-aside where the answer cannot be used."""
        turns = self._turns()
        view = self._reference_view(observation)
        top_p = {"top_p": REFERENCE_SAMPLING["top_p"]}
        got = self._exchange(
            self._body(ReferenceTurns.request(view), {**top_p, **REFERENCE_EXTRA_BODY}), log
        )
        if isinstance(got, Unparsable):
            turns.record_failure(got.text)
            return got
        text, decoded = got
        parsed = parse_reference(text)
        if self.reask:  # logged where a second ask was possible
            log["reasked"] = False
        if parsed.action is None and self.reask:
            # The reference's second ask: no prefill and no chat-template switches.
            again = self._exchange(self._body(ReferenceTurns.reask(view, text), top_p), log)
            if isinstance(again, Unparsable):
                turns.record_failure(text)
                return again
            text, decoded = again
            parsed = parse_reference(text)
            log["reasked"] = True
        decision = turns.decide(observation, text, parsed)
        self._log_reply(log, decoded, parsed.action is not None)
        log.update(
            format_event=decision.event,
            parse_error=decision.error,
            forced_set_aside=decision.forced,
        )
        return decision.action


def make_endpoint(**kwargs: Any) -> EndpointPolicy:
    """``endpoint``: an OpenAI-compatible ``/v1/chat/completions`` server (vLLM, SGLang, ...)."""
    return EndpointPolicy(**kwargs)
