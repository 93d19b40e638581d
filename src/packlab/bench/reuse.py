"""Episodes the bench copies instead of playing: a seed-free policy's other run seeds.

In exact observation with exact execution the run seed reaches an episode only through the
order the buffer is shown in (and the policy, if it reads the seed). A policy whose factory
declares itself seed-free in the run's mode (``packlab.policies.registry.seed_free_modes``)
therefore plays the same episode for every seed: the bench plays it once per case, for the
lowest seed (the *lead*), and writes each other seed's record as a copy of it
(:func:`reused_record`, marked ``reused_from_seed``), unless ``--no-reuse`` asks for every seed
to be played.

A copy is exactly the record playing that seed would write, apart from the times (the played
episode's, kept as they are; ``packlab.bench.summary`` counts times of played episodes only):

* ``"arrival"`` (the online protocol): nothing is shuffled, so the record is the lead's with
  its seed changed.
* ``"shuffled"`` (the buffer and offline protocols): the same boxes are processed in the same
  places, but each step shows its window in that seed's own shuffle. The window of a step is
  the lead's shown boxes in arrival order (case order: the episode shows the first unprocessed
  boxes), and the episode draws one shuffle per observation from ``episode_rng(case seed, run
  seed)`` with ``shuffled_view``, so the copy redraws them in the same sequence and renames
  each action's shown index to where its box stands in the new order.

Only an ok lead is copied, and only when no step drew from the seed's stream for anything else:
an unusable action (``unparsable``, ``bad_object_id``) sets aside a box drawn at random. Errors,
timeouts and such leads are never copied; their other seeds are played.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import msgspec
from msgspec import UNSET

from packlab.bench.options import RunConfig
from packlab.core.records import EpisodeOk, EpisodeRecord, RecordId, StepRecord, to_builtins
from packlab.core.types import Case
from packlab.policies.registry import SeedFreeMode, seed_free_modes
from packlab.sim.buffer import episode_rng, shuffled_view

#: Step reasons whose box the episode draws from the seed's stream (``Episode._random_shown``).
SEEDED_REASONS = frozenset({"unparsable", "bad_object_id"})


def reuse_mode(config: RunConfig) -> SeedFreeMode | None:
    """The seed-free mode a run's episodes are played in, or None where nothing is reused: reuse
    switched off, a single seed, or a perceived or noisy mode (they draw their noise from the
    seed, so every policy's episodes depend on it)."""
    if not config.reuse or len(config.seeds) < 2:
        return None
    if config.observation != "exact" or config.execution != "exact":
        return None
    return "arrival" if config.protocol == "online" else "shuffled"


@dataclass(frozen=True, slots=True)
class ReusePlan:
    """Which episodes of a run are copied: the policies seed-free in its mode, and the seed
    each plays (the lowest); every other seed of those policies is a copy of it."""

    mode: SeedFreeMode | None
    lead: int
    policies: frozenset[str]

    def reuses(self, policy: str, seed: int) -> bool:
        """Whether the episode of ``policy`` at ``seed`` is to be copied from the lead."""
        return self.mode is not None and policy in self.policies and seed != self.lead


def reuse_plan(
    config: RunConfig,
    policies: Sequence[str],
    policy_kwargs: Mapping[str, Mapping[str, Any]],
) -> ReusePlan:
    """The run's :class:`ReusePlan` (no policy when :func:`reuse_mode` is None)."""
    mode = reuse_mode(config)
    lead = min(config.seeds)
    if mode is None:
        return ReusePlan(None, lead, frozenset())
    free = {p for p in policies if mode in seed_free_modes(p, policy_kwargs.get(p, {}))}
    return ReusePlan(mode, lead, frozenset(free))


def copyable(record: EpisodeRecord, mode: SeedFreeMode) -> bool:
    """Whether a lead's record can stand for the other seeds: a played, finished episode none
    of whose steps drew a box from the seed's stream (shuffled mode)."""
    if not isinstance(record, EpisodeOk) or record.reused_from_seed is not UNSET:
        return False
    return mode == "arrival" or not any(s.reason in SEEDED_REASONS for s in record.steps)


def _reshown(played: EpisodeOk, case: Case, seed: int) -> tuple[StepRecord, ...]:
    """The played steps as run seed ``seed`` shows them: each window in that seed's shuffle,
    each action naming its box's index there (module docstring)."""
    arrival = {box.internal_id: i for i, box in enumerate(case.objects)}
    rng = episode_rng(case.seed, seed)
    steps = []
    for step in played.steps:
        window: list[RecordId] = sorted(step.shown, key=arrival.__getitem__)
        # The episode's own draw: shuffled_view of the window's positions is its permutation.
        shown = tuple(window[i] for i in shuffled_view(range(len(window)), rng))
        action = step.action
        if isinstance(action.object_id, int):  # unparsable steps are never copied (copyable)
            chosen = step.shown[action.object_id]
            action = msgspec.structs.replace(action, object_id=shown.index(chosen))
        steps.append(msgspec.structs.replace(step, shown=shown, action=action))
    return tuple(steps)


def reused_record(played: EpisodeOk, case: Case, seed: int, mode: SeedFreeMode) -> EpisodeOk:
    """The record of ``seed`` copied from ``played`` (a :func:`copyable` lead of ``case``)."""
    steps = played.steps if mode == "arrival" else _reshown(played, case, seed)
    return msgspec.structs.replace(played, seed=seed, steps=steps, reused_from_seed=played.seed)


#: Step keys that time the step rather than describe it.
_STEP_TIMES = ("wall_time_s", "decision_s", "decision_cpu_s")


def timeless(record: EpisodeOk) -> dict[str, Any]:
    """A record as JSON without its times and reuse marker: what a copy and the played
    episode of the same seed must agree on."""
    out: dict[str, Any] = to_builtins(record)
    for key in ("timing", "policy_time_s", "reused_from_seed"):
        out.pop(key, None)
    out["metrics"] = {k: v for k, v in out["metrics"].items() if k != "wall_time_s"}
    out["steps"] = [
        {k: v for k, v in step.items() if k not in _STEP_TIMES} for step in out["steps"]
    ]
    return out


__all__ = [
    "SEEDED_REASONS",
    "ReusePlan",
    "copyable",
    "reuse_mode",
    "reuse_plan",
    "reused_record",
    "timeless",
]
