"""The closed packing loop (DESIGN.md section 4): observe, act, execute, settle, score.

Invalid placements are data, never exceptions: they are recorded with a reason, the affected
object is set aside outside the container (it counts as unpacked) and the episode goes on.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, cast

import numpy as np

from packlab.core.choices import (
    DEFAULT_SIDES,
    PhysicsBackend,
    SideNames,
    named_size,
    require_choice,
)
from packlab.core.errors import ConfigError
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
from packlab.sim.execution import (
    NO_GRASP_ERROR,
    ExecutedDrop,
    ExecutionNoise,
    perturb_drop,
    place_command,
    seat_sides,
)
from packlab.sim.physics import Transition, TransitionBackend, make_backend
from packlab.sim.physics.place_skill import PlaceCommand, SkillReport
from packlab.sim.pose_log import pose_updates
from packlab.sim.replan import (
    Perceiver,
    Perception,
    ReplanRule,
    Scene,
    deviates,
    predict_heightmap,
)

#: The re-plan threshold of perceived-mode episodes (``packlab.sim.replan.ReplanRule``).
DEFAULT_REPLAN = ReplanRule()
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


def _cells(mm: int, cell: int) -> int:
    return -(-mm // cell)


class _NoisyBackend(TransitionBackend, Protocol):
    """A backend that executes a robot's placement (``supports_noisy_execution``: mujoco)."""

    def execute(
        self,
        index: int,
        rotation: int,
        command: PlaceCommand,
        offset_mm: tuple[float, float],
        yaw_deg: float,
    ) -> tuple[Transition, SkillReport]: ...


class Episode:
    """One closed-loop packing episode over a case on a transition backend.

    Opt-in (issue 15): a ``perceiver`` makes the observation the perceived one and logs re-plan
    events by ``replan``; ``execution`` noise executes each drop off-plan (mujoco only). Without
    them the episode is exactly the exact-mode loop.
    """

    # Set by reset(): the case and backend of this episode (``case`` and ``backend`` before the
    # first reset are None), the shown objects and the perception they were shown from.
    _case: Case
    _backend: TransitionBackend
    _shown_indices: list[int]
    _shown: tuple[ShownItem, ...]
    _perception: Perception

    def __init__(
        self,
        backend: str | TransitionBackend = "mujoco",
        physics: Any = None,
        *,
        perceiver: Perceiver | None = None,
        execution: ExecutionNoise | None = None,
        replan: ReplanRule = DEFAULT_REPLAN,
        sides: SideNames = DEFAULT_SIDES,
        show_remaining: bool = True,
    ) -> None:
        require_choice(sides, SideNames, "sides")
        self._sides = sides
        #: ``Observation.remaining``, the count of boxes still to come, is an extension of the
        #: reference's observation (a robot cell knows its order's size); False hides it (None).
        self._show_remaining = show_remaining
        self._backend_spec = backend
        self._physics = physics
        self._perceiver = perceiver
        self._execution = execution
        self._replan_rule = replan
        self.backend: TransitionBackend | None = None
        self.case: Case | None = None
        self.steps: list[StepResult] = []

    # -- lifecycle -------------------------------------------------------------------------
    def reset(self, case: Case, seed: int = 0) -> Observation:
        if isinstance(self._backend_spec, str):
            # make_backend refuses a name that is not a PhysicsBackend.
            name = cast(PhysicsBackend, self._backend_spec)
            self.backend = self._backend = make_backend(name, self._physics)
        else:
            self.backend = self._backend = self._backend_spec
        if self._execution is not None and not getattr(
            self.backend, "supports_noisy_execution", False
        ):
            raise ConfigError(
                f"execution = 'noisy': the {self._backend.name} backend places boxes on whole "
                "cells and cannot execute noisy drops; use the mujoco backend"
            )
        self.case = self._case = case
        self.seed = seed
        self._rng = episode_rng(case.seed, seed)
        # Own streams for execution noise and perception, spawned from the episode's seeds so
        # the buffer shuffle (self._rng) stays the exact-mode sequence.
        execution_seed, perception_seed = np.random.SeedSequence(
            [int(case.seed) & 0xFFFFFFFF, int(seed) & 0xFFFFFFFF]
        ).spawn(2)
        self._execution_rng = np.random.default_rng(execution_seed)
        self._perception_rng = np.random.default_rng(perception_seed)
        self._heightmap = self._backend.reset(case.container, case.objects)
        self._pending = list(range(len(case.objects)))
        self._set_aside: set[int] = set()
        self.missed = 0  # objects perception did not find, set aside (perceived mode)
        self._next_seen_id = 0  # the next fresh id a perceived box is shown under
        self._history: list[HistoryEntry] = []
        self.steps = []
        # The latest settle (placement, then the final one): what "at rest" is judged on.
        self._last_settle = Transition(self._heightmap, settle_steps=0, capped=False)
        self.final_settle_steps = 0
        self._reshuffle()
        return self.observe()

    def _perceive(self) -> list[int]:
        """Perceived mode: look at the scene after the buffer was refilled (no-op otherwise).
        Returns the case indices of the shown objects perception missed."""
        if self._perceiver is None:
            return []
        positions, quaternions = self._backend.poses()
        scene = Scene(
            container=self._case.container,
            sizes_mm=np.array([b.size_mm for b in self._case.objects], dtype=np.int64),
            positions_mm=positions,
            quaternions=quaternions,
            heightmap=self._heightmap,
            shown=tuple(self._shown_indices),
        )
        self._perception = self._perceiver(scene, self._perception_rng)
        if len(self._perception.sizes_mm) != len(self._shown):
            raise ValueError(
                f"perceiver returned {len(self._perception.sizes_mm)} sizes for "
                f"{len(self._shown)} shown objects"
            )
        # The policy is shown the perceived sizes (cells rounded up, as for exact sizes), under
        # ids fresh at every observation and no catalogue type: a camera tells a box from its
        # neighbours in one image, not which box of the layout it is, nor that it is the box it
        # saw at the previous step (the case's ids are layout positions and would say both).
        c = self._case.container
        first_id = self._next_seen_id
        self._next_seen_id += len(self._shown)
        self._shown = tuple(
            replace(
                item,
                internal_id=f"seen-{first_id + i:05d}",  # zero-padded: sorts as counted
                type_id=0,
                size_mm=(int(size[0]), int(size[1]), int(size[2])),
                size_cells=(
                    _cells(int(size[0]), c.cell_xy_mm),
                    _cells(int(size[1]), c.cell_xy_mm),
                    _cells(int(size[2]), c.cell_z_mm),
                ),
            )
            for i, (item, size) in enumerate(zip(self._shown, self._perception.sizes_mm))
        )
        return [self._shown_indices[i] for i in self._perception.missed]

    def _turned(self, object_id: int, rotation: int) -> int:
        """The box's own rotation that does what the policy chose: the policy's rotation refers
        to the sides it was shown, which perception lists longer first (``axis_swapped``), and
        exact observation as ``sides`` says."""
        if self._perceiver is None:
            l, w, _ = self._case.objects[self._shown_indices[object_id]].size_mm
            return rotation ^ int(self._sides == "longer-first" and l < w)
        if not self._perception.axis_swapped:
            return rotation
        return rotation ^ int(self._perception.axis_swapped[object_id])

    @property
    def done(self) -> bool:
        return not self._pending

    @property
    def heightmap(self) -> np.ndarray:
        return self._heightmap

    def _reshuffle(self) -> int:
        """Show the next objects and perceive them. Objects perception missed are set aside
        (as a robot cell passes them on) and the buffer refilled until none is missed; returns
        the final settle's steps when that emptied the stream, else 0."""
        while True:
            self._show_window()
            missed = self._perceive()
            if not missed:
                return 0
            for index in missed:
                self._set_aside.add(index)
                self._pending.remove(index)
            self.missed += len(missed)
            if not self._pending:
                final = self._last_settle = self._backend.finish()
                self._heightmap = final.heightmap
                self.final_settle_steps = final.settle_steps
                self._shown_indices, self._shown = [], ()
                self._perceive()
                return final.settle_steps

    def _show_window(self) -> None:
        window = visible_window(self._pending, self._case.buffer_size)
        self._shown_indices = shuffled_view(window, self._rng)
        c = self._case.container
        sizes = [self._named(self._case.objects[idx].size_mm) for idx in self._shown_indices]
        self._shown = tuple(
            ShownItem(
                shown_index=i,
                internal_id=self._case.objects[idx].internal_id,
                size_mm=size,
                size_cells=(
                    _cells(size[0], c.cell_xy_mm),
                    _cells(size[1], c.cell_xy_mm),
                    _cells(size[2], c.cell_z_mm),
                ),
                type_id=self._case.objects[idx].type_id,
            )
            for (i, idx), size in zip(enumerate(self._shown_indices), sizes)
        )

    def _named(self, size: tuple[int, int, int]) -> tuple[int, int, int]:
        """A box's sides as exact observation names them (``sides``)."""
        return named_size(size, self._sides)

    def observe(self) -> Observation:
        if self.case is None:
            raise RuntimeError("Episode.observe() before reset()")
        return Observation(
            step_index=len(self.steps),
            container=self._case.container,
            heightmap=self.observed_heightmap.copy(),
            shown=self._shown,
            history=tuple(self._history),
            remaining=len(self._pending) if self._show_remaining else None,
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
        rotation = self._turned(int(action.object_id), int(action.rotation))
        fx, fy = self._footprint_cells(index, rotation)
        if not footprint_fits(self._heightmap.shape, int(action.x), int(action.y), fx, fy):
            return "out_of_bounds", index
        return "", index

    def _random_shown(self) -> int:
        return self._shown_indices[int(self._rng.integers(len(self._shown_indices)))]

    def _footprint_cells(self, index: int, rotation: int) -> tuple[int, int]:
        fx_mm, fy_mm = self._case.objects[index].footprint_mm(rotation)
        cell = self._case.container.cell_xy_mm
        return _cells(fx_mm, cell), _cells(fy_mm, cell)

    def step(self, action: Action | Unparsable) -> StepResult:
        if self.case is None:
            raise RuntimeError("Episode.step() before reset()")
        if self.done:
            raise RuntimeError(
                f"episode {self._case.episode_id!r} is finished; reset() to start again"
            )
        started = time.perf_counter()
        reason, index = self._check(action)
        seen_before, shown_before = self.observed_heightmap, self._shown
        shown_ids = tuple(self._case.objects[i].internal_id for i in self._shown_indices)
        perception_before = self._perception if self._perceiver is not None else None
        predicted = seen_before  # what the policy expects to see next (perceived mode)
        drop = executed = command = skill = None
        placed: Transition | None = None
        if not reason and isinstance(action, Action):  # no reason: an Action
            chosen, x, y = int(action.rotation), int(action.x), int(action.y)
            rotation = self._turned(int(action.object_id), chosen)
            fx, fy = self._footprint_cells(index, rotation)
            item = shown_before[int(action.object_id)]
            if self._execution is not None:
                # The robot's own belief: the footprint of the size it was shown (perceived
                # mode: the perceived size, named longer first; ``chosen`` refers to it).
                l_cells, w_cells, _ = item.size_cells
                fx, fy = (w_cells, l_cells) if chosen == 1 else (l_cells, w_cells)
            # The release height from what the robot sees (perceived mode: the perceived
            # heightmap; too low, the descent stops on contact).
            z = placement_height(seen_before, x, y, fx, fy)
            cell = self._case.container.cell_xy_mm
            drop = (x * cell, y * cell, z)
            executed = self._executed_drop(index, (fx, fy), drop)
            command = (
                None
                if executed is None
                else place_command(item.size_mm, chosen, drop, seen_before, executed)
            )
            placed, skill = self._place(index, rotation, drop, executed, command)
            self._last_settle = placed
            self._heightmap = placed.heightmap
            if self._perceiver is not None:
                predicted = self._predicted(shown_before[int(action.object_id)], chosen, x, y)
        else:
            self._set_aside.add(index)
        settle_steps = placed.settle_steps if placed else 0
        if len(self._pending) == 1:  # this step processes the last object
            final = self._last_settle = self._backend.finish()
            self._heightmap = final.heightmap
            self.final_settle_steps = final.settle_steps
            settle_steps += final.settle_steps
        positions, quaternions = self._backend.poses()
        self._history.append(HistoryEntry(seen_before, shown_before, action, not reason))
        self._pending.remove(index)
        if self._pending:
            settle_steps += self._reshuffle()
        else:
            self._shown_indices, self._shown = [], ()
            self._perceive()
        result = StepResult(
            step_index=len(self.steps),
            action=action,
            valid=not reason,
            reason=reason,
            internal_id=self._case.objects[index].internal_id,
            shown=shown_before,
            drop_mm=drop,
            settle_steps=settle_steps,
            settled=placed.settled if placed else True,
            wall_time_s=time.perf_counter() - started,
            positions_mm=positions,
            quaternions=quaternions,
            max_linear_speed=placed.max_linear_speed if placed else 0.0,
            max_angular_speed=placed.max_angular_speed if placed else 0.0,
            replan=None
            if self._perceiver is None
            else deviates(predicted, self._perception.heightmap, self._replan_rule),
            executed=executed,
            perception=perception_before,
            skill=skill,
            command=command,
            shown_ids=shown_ids,
        )
        self.steps.append(result)
        return result

    @property
    def observed_heightmap(self) -> np.ndarray:
        """The heightmap the policy sees: the perceived one in perceived mode, else the exact."""
        return self._heightmap if self._perceiver is None else self._perception.heightmap

    def _executed_drop(
        self, index: int, footprint_cells: tuple[int, int], drop: tuple[int, int, int]
    ) -> ExecutedDrop | None:
        """Noisy execution: the drop as the robot executes it (None in exact execution): the
        arm's noise plus, in perceived mode, the grasped box's pose-estimate error, and the
        sides the place skill seats it toward, read from the observed heightmap around the
        footprint the robot believes in (``footprint_cells``, of the size it was shown)."""
        if self._execution is None:
            return None
        executed = perturb_drop(self._execution, self._execution_rng, self._grasp_error(index))
        if executed.is_exact or executed.seat_mm == 0:
            return executed
        cell = self._case.container.cell_xy_mm
        sides = seat_sides(
            self.observed_heightmap, drop[0] // cell, drop[1] // cell, footprint_cells, drop[2]
        )
        return replace(executed, seat_sides=sides)

    def _grasp_error(self, index: int) -> tuple[float, float, float]:
        """Perceived mode: the error of the estimated pose of shown object ``index`` (case
        index), from the perception the decision was made on; zeros when none is reported."""
        if self._perceiver is None or index not in self._shown_indices:
            return NO_GRASP_ERROR
        errors = self._perception.grasp_errors
        shown = list(self._shown_indices).index(index)
        if shown >= len(errors):
            return NO_GRASP_ERROR
        dx, dy, dyaw = errors[shown]
        return (dx, dy, dyaw)

    def _place(
        self,
        index: int,
        rotation: int,
        drop: tuple[int, int, int],
        executed: ExecutedDrop | None,
        command: PlaceCommand | None,
    ) -> tuple[Transition, SkillReport | None]:
        """Execute the placement: exactly as planned (exact execution, or a noisy draw that
        came out exact), else by the robot's place skill from ``command``."""
        if executed is None or executed.is_exact or command is None:
            return self._backend.place(index, rotation, drop), None
        # reset() refused an execution noise for a backend without supports_noisy_execution.
        noisy = cast(_NoisyBackend, self._backend)
        return noisy.execute(index, rotation, command, executed.offset_mm, executed.yaw_deg)

    def _predicted(self, item: ShownItem, rotation: int, x: int, y: int) -> np.ndarray:
        """Eq. 2 prediction of the intended placement on the perceived heightmap it was chosen
        on, with the perceived size the policy was shown."""
        l, w, _ = item.size_cells
        footprint = (w, l) if rotation == 1 else (l, w)
        return predict_heightmap(self._perception.heightmap, x, y, footprint, item.size_mm[2])

    # -- outcome ---------------------------------------------------------------------------
    def final_poses(self) -> dict[InternalId, Pose | None]:
        """Settled pose of every object by internal id; None for objects never placed."""
        positions, quats = self._backend.poses()
        out: dict[InternalId, Pose | None] = {}
        for i, box in enumerate(self._case.objects):
            if np.isnan(positions[i]).any():
                out[box.internal_id] = None
            else:
                (x, y, z), (qw, qx, qy, qz) = map(float, positions[i]), map(float, quats[i])
                out[box.internal_id] = Pose((x, y, z), (qw, qx, qy, qz))
        return out

    def metrics(self) -> EpisodeMetrics:
        """Scores from the current (final, once done) poses and heightmap, plus counters.

        ``at_rest`` and the residual speeds describe the latest settle: once done, the final
        settle the scores were taken after.
        """
        positions, _ = self._backend.poses()
        centres = [None if np.isnan(p).any() else p for p in positions]
        volumes = [b.volume_mm3 for b in self._case.objects]
        sr, comp, overall, inside_vol, n_inside, max_h = score_final_state(
            self._case.container, volumes, centres, self._heightmap
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
    #: Each step's decision (the policy's ``act``): wall and process CPU seconds, by step; empty
    #: when the steps were driven by a loop that did not time them.
    decision_s: tuple[float, ...] = ()
    decision_cpu_s: tuple[float, ...] = ()
    #: Perceived mode only (else None): steps with a re-plan event (``StepResult.replan``).
    replans: int | None = None
    #: Perceived mode only (else None): objects perception did not find, set aside unpacked.
    missed: int | None = None
    #: Noisy execution only (else None): the place skill's counts summed over the steps
    #: (``StepResult.skill``), by kind; what it had to do to recover and how.
    skill: dict[str, int] | None = None

    def to_record(self) -> dict[str, Any]:
        # Per-step poses go in as changes only (packlab.sim.pose_log): a replay shows the pile
        # after every step without records growing by steps x boxes.
        steps = [s.to_record() for s in self.steps]
        if len(self.decision_s) == len(steps):
            steps = [
                {**rec, "decision_s": round(wall, 6), "decision_cpu_s": round(cpu, 6)}
                for rec, wall, cpu in zip(steps, self.decision_s, self.decision_cpu_s)
            ]
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
        if self.skill is not None:  # noisy execution only
            metrics["skill"] = dict(self.skill)
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


def run_episode(
    case: Case,
    policy: Any,
    seed: int = 0,
    backend: str | TransitionBackend = "mujoco",
    physics: Any = None,
    *,
    perceiver: Perceiver | None = None,
    execution: ExecutionNoise | None = None,
    sides: SideNames = DEFAULT_SIDES,
    show_remaining: bool = True,
) -> EpisodeResult:
    """Run ``policy`` (the Policy protocol) on ``case`` to the end and return the result.

    ``perceiver`` and ``execution`` select the opt-in modes (see ``Episode``;
    ``packlab.sim.modes.episode_modes`` builds them by name).
    """
    episode = Episode(
        backend,
        physics,
        perceiver=perceiver,
        execution=execution,
        sides=sides,
        show_remaining=show_remaining,
    )
    observation = episode.reset(case, seed)
    policy.reset(case, seed)
    decision_wall: list[float] = []
    decision_cpu: list[float] = []
    while not episode.done:
        t0, c0 = time.perf_counter(), time.process_time()
        action = policy.act(observation)
        decision_wall.append(time.perf_counter() - t0)
        decision_cpu.append(time.process_time() - c0)
        episode.step(action)
        if not episode.done:
            observation = episode.observe()
    return EpisodeResult(
        case_id=case.episode_id,
        seed=seed,
        policy=getattr(policy, "name", type(policy).__name__),
        backend=episode._backend.name,
        steps=tuple(episode.steps),
        metrics=episode.metrics(),
        poses=episode.final_poses(),
        policy_time_s=math.fsum(decision_wall),
        decision_s=tuple(decision_wall),
        decision_cpu_s=tuple(decision_cpu),
        replans=None if perceiver is None else sum(bool(s.replan) for s in episode.steps),
        missed=None if perceiver is None else episode.missed,
        skill=None if execution is None else skill_totals(episode.steps),
    )


def skill_totals(steps: tuple[StepResult, ...] | list[StepResult]) -> dict[str, int]:
    """The place skill's counts of ``steps`` summed by kind (sorted; kinds never needed are
    left out)."""
    totals: Counter[str] = Counter()
    for step in steps:
        if step.skill is not None:
            totals.update(step.skill.counts())
    return dict(sorted(totals.items()))
