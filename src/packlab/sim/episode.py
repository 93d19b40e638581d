"""The closed packing loop (DESIGN.md section 4): observe, act, execute, settle, score.

Invalid placements are data, never exceptions: they are recorded with a reason, the affected
object is set aside outside the container (it counts as unpacked) and the episode goes on.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from packlab.core.feasibility import footprint_fits, placement_height
from packlab.core.types import (
    Action,
    Case,
    HistoryEntry,
    InternalId,
    Observation,
    Pose,
    ShownItem,
    Unparsable,
)
from packlab.metrics import EpisodeMetrics, score_final_state
from packlab.sim.buffer import episode_rng, shuffled_view, visible_window
from packlab.sim.physics import Transition, TransitionBackend, make_backend
from packlab.sim.pose_log import pose_updates

#: Reasons a step can be invalid.
INVALID_REASONS = ("bad_object_id", "bad_rotation", "out_of_bounds", "unparsable")


@dataclass(frozen=True, slots=True)
class StepResult:
    """What happened at one step."""

    step_index: int
    action: Action | Unparsable
    valid: bool
    reason: str  # "" when valid, else one of INVALID_REASONS
    internal_id: InternalId  # the object processed (placed or set aside), as the case file gives it
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
    positions_mm: np.ndarray = field(default=None, repr=False, compare=False)
    quaternions: np.ndarray = field(default=None, repr=False, compare=False)
    #: Largest linear (m/s) and angular (rad/s) speed of any box when the placement's settle
    #: stopped: under the rest thresholds when ``settled``, the residual motion when not.
    max_linear_speed: float = 0.0
    max_angular_speed: float = 0.0

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
            "shown": [s.internal_id for s in self.shown],
            "drop_mm": list(self.drop_mm) if self.drop_mm else None,
            "settle_steps": self.settle_steps,
            "settled": self.settled,
            "max_linear_speed_mps": round(self.max_linear_speed, 6),
            "max_angular_speed_radps": round(self.max_angular_speed, 6),
            "wall_time_s": round(self.wall_time_s, 6),
        }


def _cells(mm: int, cell: int) -> int:
    return -(-mm // cell)


class Episode:
    """One closed-loop packing episode over a case on a transition backend."""

    def __init__(self, backend: str | TransitionBackend = "mujoco", physics: Any = None) -> None:
        self._backend_spec = backend
        self._physics = physics
        self.backend: TransitionBackend | None = None
        self.case: Case | None = None
        self.steps: list[StepResult] = []

    # -- lifecycle -------------------------------------------------------------------------
    def reset(self, case: Case, seed: int = 0) -> Observation:
        if isinstance(self._backend_spec, str):
            self.backend = make_backend(self._backend_spec, self._physics)
        else:
            self.backend = self._backend_spec
        self.case = case
        self.seed = seed
        self._rng = episode_rng(case.seed, seed)
        self._heightmap = self.backend.reset(case.container, case.objects)
        self._pending = list(range(len(case.objects)))
        self._set_aside: set[int] = set()
        self._history: list[HistoryEntry] = []
        self.steps = []
        # The latest settle (placement, then the final one): what "at rest" is judged on.
        self._last_settle = Transition(self._heightmap, settle_steps=0, capped=False)
        self.final_settle_steps = 0
        self._reshuffle()
        return self.observe()

    @property
    def done(self) -> bool:
        return not self._pending

    @property
    def heightmap(self) -> np.ndarray:
        return self._heightmap

    def _reshuffle(self) -> None:
        window = visible_window(self._pending, self.case.buffer_size)
        self._shown_indices = shuffled_view(window, self._rng)
        c = self.case.container
        self._shown = tuple(
            ShownItem(
                shown_index=i,
                internal_id=self.case.objects[idx].internal_id,
                size_mm=self.case.objects[idx].size_mm,
                size_cells=(
                    _cells(self.case.objects[idx].size_mm[0], c.cell_xy_mm),
                    _cells(self.case.objects[idx].size_mm[1], c.cell_xy_mm),
                    _cells(self.case.objects[idx].size_mm[2], c.cell_z_mm),
                ),
                type_id=self.case.objects[idx].type_id,
            )
            for i, idx in enumerate(self._shown_indices)
        )

    def observe(self) -> Observation:
        if self.case is None:
            raise RuntimeError("Episode.observe() before reset()")
        return Observation(
            step_index=len(self.steps),
            container=self.case.container,
            heightmap=self._heightmap.copy(),
            shown=self._shown,
            history=tuple(self._history),
            remaining=len(self._pending),
        )

    # -- the transition --------------------------------------------------------------------
    def _check(self, action: Action | Unparsable) -> tuple[str, int]:
        """(invalid reason or "", index of the object this step processes)."""
        if isinstance(action, Unparsable):
            return "unparsable", self._random_shown()
        if not isinstance(action.object_id, (int, np.integer)) or not 0 <= action.object_id < len(
            self._shown
        ):
            return "bad_object_id", self._random_shown()
        index = self._shown_indices[int(action.object_id)]
        if action.rotation not in (0, 1):
            return "bad_rotation", index
        fx, fy = self._footprint_cells(index, int(action.rotation))
        if not footprint_fits(self._heightmap.shape, int(action.x), int(action.y), fx, fy):
            return "out_of_bounds", index
        return "", index

    def _random_shown(self) -> int:
        return self._shown_indices[int(self._rng.integers(len(self._shown_indices)))]

    def _footprint_cells(self, index: int, rotation: int) -> tuple[int, int]:
        fx_mm, fy_mm = self.case.objects[index].footprint_mm(rotation)
        cell = self.case.container.cell_xy_mm
        return _cells(fx_mm, cell), _cells(fy_mm, cell)

    def step(self, action: Action | Unparsable) -> StepResult:
        if self.case is None:
            raise RuntimeError("Episode.step() before reset()")
        if self.done:
            raise RuntimeError(
                f"episode {self.case.episode_id!r} is finished; reset() to start again"
            )
        started = time.perf_counter()
        reason, index = self._check(action)
        heightmap_before = self._heightmap
        drop = None
        placed: Transition | None = None
        if not reason:
            rotation, x, y = int(action.rotation), int(action.x), int(action.y)
            fx, fy = self._footprint_cells(index, rotation)
            z = placement_height(self._heightmap, x, y, fx, fy)
            cell = self.case.container.cell_xy_mm
            drop = (x * cell, y * cell, z)
            placed = self._last_settle = self.backend.place(index, rotation, drop)
            self._heightmap = placed.heightmap
        else:
            self._set_aside.add(index)
        settle_steps = placed.settle_steps if placed else 0
        if len(self._pending) == 1:  # this step processes the last object
            final = self._last_settle = self.backend.finish()
            self._heightmap = final.heightmap
            self.final_settle_steps = final.settle_steps
            settle_steps += final.settle_steps
        positions, quaternions = self.backend.poses()
        result = StepResult(
            step_index=len(self.steps),
            action=action,
            valid=not reason,
            reason=reason,
            internal_id=self.case.objects[index].internal_id,
            shown=self._shown,
            drop_mm=drop,
            settle_steps=settle_steps,
            settled=placed.settled if placed else True,
            wall_time_s=time.perf_counter() - started,
            positions_mm=positions,
            quaternions=quaternions,
            max_linear_speed=placed.max_linear_speed if placed else 0.0,
            max_angular_speed=placed.max_angular_speed if placed else 0.0,
        )
        self._history.append(HistoryEntry(heightmap_before, self._shown, action, not reason))
        self.steps.append(result)
        self._pending.remove(index)
        if self._pending:
            self._reshuffle()
        else:
            self._shown_indices, self._shown = [], ()
        return result

    # -- outcome ---------------------------------------------------------------------------
    def final_poses(self) -> dict[InternalId, Pose | None]:
        """Settled pose of every object by internal id; None for objects never placed."""
        positions, quats = self.backend.poses()
        out: dict[InternalId, Pose | None] = {}
        for i, box in enumerate(self.case.objects):
            if np.isnan(positions[i]).any():
                out[box.internal_id] = None
            else:
                out[box.internal_id] = Pose(
                    tuple(map(float, positions[i])), tuple(map(float, quats[i]))
                )
        return out

    def metrics(self) -> EpisodeMetrics:
        """Scores from the current (final, once done) poses and heightmap, plus counters.

        ``at_rest`` and the residual speeds describe the latest settle: once done, the final
        settle the scores were taken after.
        """
        positions, _ = self.backend.poses()
        centres = [None if np.isnan(p).any() else p for p in positions]
        volumes = [b.volume_mm3 for b in self.case.objects]
        sr, comp, overall, inside_vol, n_inside, max_h = score_final_state(
            self.case.container, volumes, centres, self._heightmap
        )
        reasons = Counter(s.reason for s in self.steps if s.reason)
        return EpisodeMetrics(
            success_ratio=sr,
            compactness=comp,
            overall=overall,
            inside_volume_mm3=inside_vol,
            total_volume_mm3=sum(volumes),
            max_height_mm=max_h,
            n_objects=len(volumes),
            n_inside=n_inside,
            n_set_aside=len(self._set_aside),
            invalid_by_reason=dict(sorted(reasons.items())),
            settle_steps=sum(s.settle_steps for s in self.steps),
            unsettled_steps=sum(not s.settled for s in self.steps),
            final_settle_steps=self.final_settle_steps,
            at_rest=self._last_settle.settled,
            residual_linear_mps=self._last_settle.max_linear_speed,
            residual_angular_radps=self._last_settle.max_angular_speed,
            wall_time_s=sum(s.wall_time_s for s in self.steps),
        )


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

    def to_record(self) -> dict[str, Any]:
        # Per-step poses go in as changes only (packlab.sim.pose_log): a replay shows the pile
        # after every step without records growing by steps x boxes.
        steps = [s.to_record() for s in self.steps]
        if all(s.positions_mm is not None for s in self.steps):
            moved = pose_updates(
                [s.positions_mm for s in self.steps], [s.quaternions for s in self.steps]
            )
            steps = [{**rec, "poses": m} for rec, m in zip(steps, moved)]
        return {
            "case_id": self.case_id,
            "seed": self.seed,
            "policy": self.policy,
            "backend": self.backend,
            "metrics": self.metrics.to_dict(),
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


def run_episode(
    case: Case,
    policy: Any,
    seed: int = 0,
    backend: str | TransitionBackend = "mujoco",
    physics: Any = None,
) -> EpisodeResult:
    """Run ``policy`` (the Policy protocol) on ``case`` to the end and return the result."""
    episode = Episode(backend, physics)
    observation = episode.reset(case, seed)
    policy.reset(case, seed)
    policy_time = 0.0
    while not episode.done:
        t0 = time.perf_counter()
        action = policy.act(observation)
        policy_time += time.perf_counter() - t0
        episode.step(action)
        if not episode.done:
            observation = episode.observe()
    return EpisodeResult(
        case_id=case.episode_id,
        seed=seed,
        policy=getattr(policy, "name", type(policy).__name__),
        backend=episode.backend.name,
        steps=tuple(episode.steps),
        metrics=episode.metrics(),
        poses=episode.final_poses(),
        policy_time_s=policy_time,
    )
