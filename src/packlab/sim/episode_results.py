"""What an episode produced, and the records written from it: ``StepResult`` (one step),
``EpisodeResult`` (a finished episode) and their ``to_record`` (``packlab.core.records``'
``StepRecord`` and ``EpisodeOk`` keys).

The loop that fills them is ``packlab.sim.episode``; opt-in modes (perceived observation,
noisy execution) add keys to the records, so exact runs write exactly the exact-mode keys.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from packlab.core.types import Action, InternalId, Pose, ShownItem, Unparsable
from packlab.metrics import EpisodeMetrics
from packlab.sim.execution import ExecutedDrop
from packlab.sim.physics.place_skill import PlaceCommand, SkillReport
from packlab.sim.pose_log import pose_updates
from packlab.sim.replan import Perception

#: Reasons a step can be invalid (``not_first``: the online protocol's action named a shown box
#: other than the first, the only one it may place).
#: Why a step placed nothing. All but ``set_aside`` are errors; ``set_aside`` is a policy's
#: deliberate choice (:meth:`packlab.core.types.Action.set_aside`).
INVALID_REASONS = (
    "bad_object_id",
    "bad_rotation",
    "out_of_bounds",
    "unparsable",
    "not_first",
    "set_aside",
)


@dataclass(frozen=True, slots=True)
class StepResult:
    """What happened at one step."""

    step_index: int
    action: Action | Unparsable
    valid: bool
    reason: str  # "" when valid, else one of INVALID_REASONS
    internal_id: InternalId  # the object processed (placed or set aside), as the case file gives it
    #: The buffer as the policy was shown it (perceived mode: fresh ids, perceived sizes).
    shown: tuple[ShownItem, ...]
    drop_mm: (
        tuple[int, int, int] | None
    )  # footprint minimum corner and Eq. 2 height; None if invalid
    settle_steps: int  # physics steps of this step (the last step adds the final settle's)
    #: The placement's settle ended with every box at rest; False when it hit the per-placement
    #: cap (``PhysicsConfig.max_settle_steps``) and the next step starts from a moving pile.
    #: Invalid steps place nothing and count as settled.
    settled: bool
    wall_time_s: float
    #: Settled poses of *all* boxes after this step, indexed like ``case.objects``: centres
    #: (n, 3) float mm and quaternions (n, 4) wxyz; NaN rows for boxes not in the container
    #: (not yet placed, or set aside). Records keep only their changes from step to step
    #: (``EpisodeResult.to_record``, ``packlab.sim.pose_log``).
    positions_mm: np.ndarray = field(repr=False, compare=False)
    quaternions: np.ndarray = field(repr=False, compare=False)
    #: Largest linear (m/s) and angular (rad/s) speed of any box when the placement's settle
    #: stopped: under the rest thresholds when ``settled``, the residual motion when not.
    max_linear_speed: float = 0.0
    max_angular_speed: float = 0.0
    #: Perceived mode only (else None): the heightmap perceived after this step departed from
    #: its Eq. 2 prediction (``packlab.sim.replan``), a re-plan event.
    replan: bool | None = None
    #: Noisy execution only (else None): how the drop was really executed.
    executed: ExecutedDrop | None = None
    #: Perceived mode only (else None): the perception this step's decision was made on.
    perception: Perception | None = None
    #: Noisy execution only (else None): what the place skill had to do for this placement
    #: (``packlab.sim.physics.place_skill.SkillReport``), and the command it was given.
    skill: SkillReport | None = None
    command: PlaceCommand | None = field(default=None, repr=False, compare=False)
    #: The shown objects' ids as the case file gives them, in shown order (what records and
    #: replays name); empty: those of ``shown`` (exact mode shows the case's own ids).
    shown_ids: tuple[InternalId, ...] = ()

    def to_record(self) -> dict[str, Any]:
        action = (
            self.action.to_dict()
            if isinstance(self.action, Action)
            else {"unparsable": self.action.text, "error": self.action.error}
        )
        return {
            "step": self.step_index,
            "action": action,
            "valid": self.valid,
            "reason": self.reason,
            "internal_id": self.internal_id,
            "shown": list(self.shown_ids) or [s.internal_id for s in self.shown],
            "drop_mm": list(self.drop_mm) if self.drop_mm else None,
            "settle_steps": self.settle_steps,
            "settled": self.settled,
            "max_linear_speed_mps": round(self.max_linear_speed, 6),
            "max_angular_speed_radps": round(self.max_angular_speed, 6),
            "wall_time_s": round(self.wall_time_s, 6),
            # Opt-in modes add keys; exact runs write exactly the keys above.
            **({} if self.replan is None else {"replan": self.replan}),
            **({} if self.executed is None else {"executed": _executed_record(self.executed)}),
            **({} if self.perception is None else {"perception": _errors(self.perception)}),
            **({} if self.skill is None else {"skill": self.skill.counts()}),
        }


def _errors(perception: Perception) -> dict[str, Any]:
    """The perception errors of a step record (lists in shown order; mae None if unknown)."""
    mae = perception.heightmap_mae_mm
    return {
        # None for a missed object (no estimate to compare)
        "dims_error_mm": [_rounded(v, 3) for v in perception.dims_error_mm],
        "yaw_error_deg": [_rounded(v, 4) for v in perception.yaw_error_deg],
        "heightmap_mae_mm": None if mae is None else round(mae, 4),
        **({} if perception.scans is None else {"scans": perception.scans}),
    }


def _rounded(value: float, digits: int) -> float | None:
    return None if math.isnan(value) else round(value, digits)


def _executed_record(drop: ExecutedDrop) -> list[float]:
    """(dx mm, dy mm, extra yaw degrees, release mm), rounded for the record."""
    return [
        round(drop.offset_mm[0], 3),
        round(drop.offset_mm[1], 3),
        round(drop.yaw_deg, 4),
        round(drop.release_mm, 3),
    ]


@dataclass(frozen=True, slots=True)
class OnlineOutcome:
    """What an online-protocol episode adds to its record's metrics."""

    #: Packed volume / container volume (``packlab.metrics.space_utilization``), counting the
    #: boxes inside when the episode ended: at the first box that fits nowhere, or the last.
    space_utilization: float
    #: The box that fitted nowhere (the case's id), None when every box was processed.
    stopped_at: InternalId | None
    #: Boxes never processed: the one that fitted nowhere and every one after it.
    unprocessed: int


@dataclass(frozen=True, slots=True)
class EpisodeResult:
    """A finished episode: its steps, final poses and metrics."""

    case_id: str
    seed: int
    policy: str
    backend: str
    steps: tuple[StepResult, ...]
    metrics: EpisodeMetrics
    poses: dict[InternalId, Pose | None] = field(default_factory=dict)
    policy_time_s: float = 0.0
    #: Each step's decision (the policy's ``act``): wall and process CPU seconds, by step; empty
    #: when the steps were driven by a loop that did not time them.
    decision_s: tuple[float, ...] = ()
    decision_cpu_s: tuple[float, ...] = ()
    #: Perceived mode only (else None): steps with a re-plan event (``StepResult.replan``).
    replans: int | None = None
    #: Perceived mode only (else None): objects perception did not find, set aside unpacked.
    missed: int | None = None
    #: Perceived mode only (else None): times an object was not found and left in the buffer
    #: for another look at the next observation (``sim.episode.LOOKS_BEFORE_SET_ASIDE``).
    looked_again: int | None = None
    #: Noisy execution only (else None): the place skill's counts summed over the steps
    #: (``StepResult.skill``), by kind; what it had to do to recover and how.
    skill: dict[str, int] | None = None
    #: Online protocol only (else None): utilization and where the episode stopped.
    online: OnlineOutcome | None = None
    #: By step: how the policy read its text answer (the ``last_answer_format`` hook,
    #: ``packlab.sim.episode.answer_format``), None where it reported nothing; empty for
    #: policies without the hook.
    answer_formats: tuple[dict[str, Any] | None, ...] = ()

    def to_record(self) -> dict[str, Any]:
        # Per-step poses go in as changes only (packlab.sim.pose_log): a replay shows the pile
        # after every step without records growing by steps x boxes.
        steps = [s.to_record() for s in self.steps]
        if len(self.decision_s) == len(steps):
            steps = [
                {**rec, "decision_s": round(wall, 6), "decision_cpu_s": round(cpu, 6)}
                for rec, wall, cpu in zip(steps, self.decision_s, self.decision_cpu_s)
            ]
        if len(self.answer_formats) == len(steps):  # added keys, only where reported
            steps = [{**rec, **(fmt or {})} for rec, fmt in zip(steps, self.answer_formats)]
        if all(s.positions_mm is not None for s in self.steps):
            moved = pose_updates(
                [s.positions_mm for s in self.steps], [s.quaternions for s in self.steps]
            )
            steps = [{**rec, "poses": m} for rec, m in zip(steps, moved)]
        metrics = self.metrics.to_dict()
        if self.replans is not None:  # added keys, only in perceived mode
            metrics["replans"] = self.replans
        if self.missed is not None:
            metrics["missed"] = self.missed
        if self.looked_again:  # only where it happened: records without misses are unchanged
            metrics["looked_again"] = self.looked_again
        if self.skill is not None:  # noisy execution only
            metrics["skill"] = dict(self.skill)
        if self.online is not None:  # online protocol only: buffer records are unchanged
            metrics["space_utilization"] = self.online.space_utilization
            metrics["stopped_at"] = self.online.stopped_at
            metrics["unprocessed"] = self.online.unprocessed
        return {
            "case_id": self.case_id,
            "seed": self.seed,
            "policy": self.policy,
            "backend": self.backend,
            "metrics": metrics,
            "policy_time_s": round(self.policy_time_s, 6),
            "steps": steps,
            "final_poses": {
                str(k): None
                if p is None
                else {
                    "position_mm": [round(v, 3) for v in p.position_mm],
                    "quaternion": [round(v, 6) for v in p.quaternion],
                }
                for k, p in self.poses.items()
            },
        }


def skill_totals(steps: tuple[StepResult, ...] | list[StepResult]) -> dict[str, int]:
    """The place skill's counts of ``steps`` summed by kind (sorted; kinds never needed are
    left out)."""
    totals: Counter[str] = Counter()
    for step in steps:
        if step.skill is not None:
            totals.update(step.skill.counts())
    return dict(sorted(totals.items()))
