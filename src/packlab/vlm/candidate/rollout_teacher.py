"""A privileged rollout teacher: each listed line played to the episode's end on the case's true
future (a training-time label source; no policy may read the future at play time).

Where the planner is a weak teacher its labels cannot lift a student above it. On boxes of
independent sizes (the ``random`` family) `plan` restricted to the 16 listed lines scores below
the proposer whose list it picks from (docs/history/vlm.md), so a student trained on its
labels there learns to tie the proposer at best. This teacher instead measures each line: the
episode is copied, the line is played, and a base policy (default: the proposer) plays every
box still to come, the real ones of the case, to the end; the line's value is the Overall the
copy ends with. The label is the best line; the soft target spreads the mass over lines by
``softmax(value / temperature)``, so lines within about a temperature of the best share it
(many lines tie late in an episode, where every choice ends the same).

This is one step of policy improvement by rollouts over the base policy, with the future
known: a clairvoyant teacher (on 24 generated random cases, seed 7351, geometric: 0.708 against
`plan`'s 0.655 and the proposer's 0.624). Rows name it (``teacher``: ``mc-proposer``,
Monte-Carlo) so a model card says which states were labelled this way. Geometric backend only:
the copies must be cheap and exact.

The shipped pointer LM is not trained on these labels: on random-box states, the student trained
on them scored *lower* on random boxes than the one trained on the planner's (docs/history/vlm.md).
A label that depends on boxes not yet shown is noise to a student that cannot see them.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from packlab.cases.fingerprint import case_fingerprint
from packlab.core.errors import ConfigError
from packlab.core.feasibility import observation_candidates
from packlab.core.types import Case
from packlab.policies.candidates import Candidate, ProposerConfig, propose_from
from packlab.policies.registry import make_policy
from packlab.sim.episode import Episode, policy_start
from packlab.vlm.candidate.collect import (
    DEFAULT_PROPOSER,
    ActorSpec,
    done_cases,
    play_and_append,
)
from packlab.vlm.candidate.states import LabelledState, make_state

#: Overall units: lines within about this of the best share the soft target's mass.
DEFAULT_TEMPERATURE = 0.01
#: The policy that plays out each line's future (a name in the policy registry).
DEFAULT_BASE = "proposer"


def teacher_name(base: str) -> str:
    """The ``teacher`` field of the rows this teacher labels."""
    return f"mc-{base}"


def play_out(env: Episode, base: Callable) -> float:
    """The Overall ``env`` ends with when ``base`` (a policy's ``act``) plays every step left."""
    while not env.done:
        env.step(base(env.observe()))
    return env.metrics().overall


def line_values(
    env: Episode, listed: Sequence[Candidate], new_base: Callable[[], Callable]
) -> list[float]:
    """Each listed line's value: a copy of ``env`` plays it, then a fresh base policy
    (``new_base()``, its ``act``) plays to the end. Fresh per line: a policy that keeps episode
    state (the planner's filling) must not carry one branch's into the next."""
    values = []
    for line in listed:
        branch = copy.deepcopy(env)
        branch.step(line.action)
        values.append(play_out(branch, new_base()))
    return values


def soft_target(values: Sequence[float], temperature: float) -> tuple[float, ...]:
    """``softmax(values / temperature)``, as the rows' ``soft`` field (sums to 1)."""
    v = np.asarray(values, dtype=np.float64)
    w = np.exp((v - v.max()) / temperature)
    return tuple(float(x) for x in w / w.sum())


@dataclass(frozen=True)
class _Job:
    case: Case
    source: str
    actor: ActorSpec
    base: str
    temperature: float
    proposer: ProposerConfig


def _play(job: _Job) -> tuple[str, list[LabelledState], float]:
    """Play one case with the actor (or the base policy) and label every state it reaches."""
    case = job.case

    def new_base() -> Callable:
        policy = make_policy(job.base)
        policy.reset(policy_start(policy, case, 0), 0)
        return policy.act

    spec = job.actor if job.actor is not None else (job.base, {})
    actor = make_policy(spec[0], **spec[1])
    actor.reset(policy_start(actor, case, 0), 0)
    fingerprint = case_fingerprint(case)
    env = Episode("geometric")
    observation = env.reset(case, 0)
    rows: list[LabelledState] = []
    while not env.done:
        listed = propose_from(observation_candidates(observation), job.proposer)
        if listed:
            values = line_values(env, listed, new_base)
            label, soft = int(np.argmax(values)), soft_target(values, job.temperature)
            row = make_state(
                case.episode_id, case.difficulty, observation, listed, teacher_name(job.base),
                label, job.source, soft, False, fingerprint,
            )  # fmt: skip
            rows.append(row)
        env.step(actor.act(observation))
        if not env.done:
            observation = env.observe()
    return case.episode_id, rows, env.metrics().overall


def collect_rollout_labels(
    cases: Sequence[Case],
    out: Path,
    source: str,
    actor: ActorSpec = None,
    base: str = DEFAULT_BASE,
    temperature: float = DEFAULT_TEMPERATURE,
    proposer: ProposerConfig = DEFAULT_PROPOSER,
    workers: int = 2,
    progress: bool = True,
) -> int:
    """Play every case not yet in ``out`` (the actor acting; without one, the base policy) and
    append its states labelled by this teacher; the number appended. Resumes like
    :func:`packlab.vlm.candidate.collect.collect`."""
    if not temperature > 0:
        raise ConfigError(f"rollout teacher: temperature = {temperature!r}: must be > 0")
    make_policy(base)  # refuse an unknown base policy before starting workers
    done = done_cases(out)
    jobs = [
        _Job(c, source, actor, base, temperature, proposer)
        for c in cases
        if c.episode_id not in done
    ]
    return play_and_append(_play, jobs, out, f"mc labels {source}", workers, progress)
