"""A served model that answers as the oracle would: for checking a serving path end to end.

An ``endpoint`` run against :func:`oracle_model` should score what the oracle scores in process
(1.0 on every bundled suite): anything lower was lost between the bench and the server (a
request the model could not read, an answer the policy could not parse, a step the protocol
dropped). It also gives a latency benchmark realistic episodes, where every answer places a box.

How it knows the answer without the case: :func:`record_oracle_answers` plays the oracle on each
(case, run seed) in process, asks an :class:`~packlab.vlm.serve.endpoint.EndpointPolicy` with the
run's prompt options for the request it would send at each step, and files the oracle's action
under that request's text (:func:`request_key`: the system and user texts, in order; images and
past answers left out, since they follow from the texts and the oracle's earlier answers).
Two episodes can send the same request (two layered cases of the same boxes in the same
container look alike until their first boxes are placed), so the policy is built with
``tag_requests=True`` and the key also holds the request's ``user`` tag (case and run seed).
A request whose key was not recorded gets a plain-text refusal, which the policy records as an
unparsable step; so a mismatch shows as a score below the oracle's, never as a crash.

The recording runs on the geometric backend: the texts a step shows (the buffer, the container,
the past actions) do not depend on the physics, only on the cases, the run seed and the actions.
"""

from __future__ import annotations

import hashlib
import json
import threading
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from packlab.core.types import Action, Case, Observation
from packlab.policies.oracle import OraclePolicy
from packlab.sim.episode import policy_start, run_episode
from packlab.vlm.prompt import reference
from packlab.vlm.prompt.render import action_text
from packlab.vlm.serve.endpoint import EndpointPolicy
from packlab.vlm.serve.protocol import Reply

#: What the scripted model says to a request it has no answer for (never parses as an action).
UNKNOWN_REQUEST = "No recorded answer for this request."


def _texts(content: Any) -> list[str]:
    if isinstance(content, str):
        return [content]
    return [part.get("text", "") for part in content if part.get("type") == "text"]


def request_key(body: Mapping[str, Any]) -> str:
    """A digest of a chat request's ``user`` tag and its system and user texts, in order."""
    texts: list[Any] = [body.get("user", "")]
    texts += [
        (m["role"], _texts(m["content"]))
        for m in body["messages"]
        if m.get("role") in ("system", "user")
    ]
    return hashlib.sha256(json.dumps(texts).encode("utf-8")).hexdigest()


class _Recorder:
    """The oracle, filing each action under the request the endpoint would send for it."""

    def __init__(self, endpoint: EndpointPolicy, answers: dict[str, str]) -> None:
        self.name = "oracle"
        self.endpoint, self.answers = endpoint, answers
        self.oracle = OraclePolicy()

    needs_case = True  # the oracle's plan

    def reset(self, case: Case, seed: int) -> None:
        self.oracle.reset(case, seed)
        self.endpoint.reset(policy_start(self.endpoint, case, seed), seed)

    def act(self, observation: Observation) -> Action:
        action = self.oracle.act(observation)
        text = (
            reference.answer_text(action)
            if self.endpoint.prompt == "reference"
            else action_text(action)
        )
        self.answers[request_key(self.endpoint.payload(observation))] = text
        return action


#: The option the played ``endpoint`` needs too: ``--policy-arg endpoint:tag_requests=true``.
POLICY_ARGS = {"tag_requests": True}


def record_oracle_answers(
    cases: Iterable[Case], seeds: Iterable[int], policy_args: Mapping[str, Any] | None = None
) -> dict[str, str]:
    """Request key -> the oracle's answer, for every step of every (case, seed) episode, as an
    ``endpoint`` policy built with ``policy_args`` (e.g. ``{"prompt": "reference"}``) and
    :data:`POLICY_ARGS` asks."""
    answers: dict[str, str] = {}
    seeds = list(seeds)
    for case in cases:
        for seed in seeds:
            endpoint = EndpointPolicy(**{**dict(policy_args or {}), **POLICY_ARGS})
            recorder = _Recorder(endpoint, answers)
            run_episode(case, recorder, seed, backend="geometric")
    return answers


@dataclass
class OracleModel:
    """The answer function of a scripted server (:func:`packlab.vlm.serve.server.serve`): the
    recorded answer after ``delay_s``, with counts of what it was asked."""

    answers: Mapping[str, str]
    delay_s: float = 0.0
    requests: int = 0
    unknown: int = 0
    most_in_flight: int = 0
    _in_flight: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def __call__(self, body: dict[str, Any]) -> Reply:
        answer = self.answers.get(request_key(body))
        with self._lock:
            self.requests += 1
            self.unknown += answer is None
            self._in_flight += 1
            self.most_in_flight = max(self.most_in_flight, self._in_flight)
        try:
            # Sleep here rather than in the Reply so the in-flight count covers the wait.
            time.sleep(self.delay_s)
        finally:
            with self._lock:
                self._in_flight -= 1
        return Reply(content=UNKNOWN_REQUEST if answer is None else answer)


def oracle_model(
    cases: Iterable[Case],
    seeds: Iterable[int],
    policy_args: Mapping[str, Any] | None = None,
    delay_s: float = 0.0,
) -> OracleModel:
    """A scripted model answering every request of these episodes as the oracle would."""
    return OracleModel(record_oracle_answers(cases, seeds, policy_args), delay_s)


__all__ = [
    "POLICY_ARGS",
    "UNKNOWN_REQUEST",
    "OracleModel",
    "oracle_model",
    "record_oracle_answers",
    "request_key",
]
