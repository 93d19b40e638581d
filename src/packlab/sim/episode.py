"""The closed packing loop (DESIGN.md section 4): observe, act, execute, settle, score.

Invalid placements are data, never exceptions: they are recorded with a reason, the affected
object is set aside outside the container (it counts as unpacked) and the episode goes on.

The loop's parts live beside it: what the robot sees in perceived mode
(``packlab.sim.perceived``), how a chosen placement is carried out (``packlab.sim.placement``)
and the results and their records (``packlab.sim.episode_results``, re-exported here).
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Mapping
from typing import Any, cast

import numpy as np

from packlab.core.choices import (
    DEFAULT_SIDES,
    PhysicsBackend,
    SideNames,
    own_rotation,
    require_choice,
)
from packlab.core.errors import ConfigError
from packlab.core.feasibility import fits_somewhere, footprint_fits, placement_height
from packlab.core.packing_protocol import BUFFER, PackingProtocol
from packlab.core.protocols import EpisodeStart
from packlab.core.records import FORMAT_EVENTS
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
from packlab.metrics import EpisodeMetrics, score_final_state, space_utilization
from packlab.sim.buffer import (
    cells_covering,
    episode_rng,
    exact_items,
    shuffled_view,
    visible_window,
)
from packlab.sim.episode_results import (
    INVALID_REASONS,
    EpisodeResult,
    OnlineOutcome,
    StepResult,
    skill_totals,
)
from packlab.sim.execution import NO_GRASP_ERROR, ExecutedDrop, ExecutionNoise, place_command
from packlab.sim.perceived import (
    grasp_error,
    perceive,
    perceived_rotation,
    predicted_after,
    seen_items,
)
from packlab.sim.physics import Transition, TransitionBackend, make_backend
from packlab.sim.placement import (
    Placement,
    arm_redraw,
    believed_footprint,
    carry_out,
    executes_noisy_drops,
    robot_drop,
)
from packlab.sim.replan import Perceiver, Perception, ReplanRule, deviates

#: Looks in a row that fail the robot's own check (as many box-like segments as the buffer holds
#: and no other) before it clears what it could not identify (perceived mode): the first, and
#: two more after the boxes beside it changed. Each look already scans the buffer twice
#: (``sensing.buffer.MAX_SCANS``).
LOOKS_BEFORE_SET_ASIDE = 3

#: The re-plan threshold of perceived-mode episodes (``packlab.sim.replan.ReplanRule``).
DEFAULT_REPLAN = ReplanRule()


class Episode:
    """One closed-loop packing episode over a case on a transition backend.

    Opt-in: a ``perceiver`` makes the observation the perceived one and logs re-plan
    events by ``replan``; ``execution`` noise executes each drop off-plan (mujoco only). Without
    them the episode is exactly the exact-mode loop.

    ``protocol`` (``packlab.core.packing_protocol``): the buffered loop of DESIGN.md
    section 4 by default; ``online`` shows the next ``lookahead`` boxes in arrival order, lets
    only the first be placed and ends the episode at the first box that fits nowhere.
    """

    # Set by reset(): the case and backend of this episode (``case`` and ``backend`` before the
    # first reset are None), the shown objects and the perception they were shown from.
    _case: Case
    _backend: TransitionBackend
    _shown_indices: list[int]
    _buffered: list[int]  # perceived mode: the case indices in the buffer, as it was looked at
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
        protocol: PackingProtocol = BUFFER,
    ) -> None:
        require_choice(sides, SideNames, "sides")
        if protocol.online and perceiver is not None:
            # A camera shows the buffer as a pile, not as a queue; the online protocol is the
            # field's, played on exact observations.
            raise ConfigError("protocol = 'online': exact observation only")
        self._protocol = protocol
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
        if self._execution is not None and not executes_noisy_drops(self._backend):
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
        self.missed = 0  # boxes the robot cleared off the buffer unidentified (perceived mode)
        #: Perceived mode: looks in a row that failed the robot's check of the buffer; at
        #: ``LOOKS_BEFORE_SET_ASIDE`` it clears what it could not identify.
        self._unclear_looks = 0
        self.looked_again = 0  # boxes left in the buffer unidentified for another look
        self._next_seen_id = 0  # the next fresh id a perceived box is shown under
        self._history: list[HistoryEntry] = []
        self.steps = []
        #: Online protocol: the case index of the box that fitted nowhere (the episode ended
        #: there), else None.
        self.stopped_at: int | None = None
        # The latest settle (placement, then the final one): what "at rest" is judged on.
        self._last_settle = Transition(self._heightmap, settle_steps=0, capped=False)
        self.final_settle_steps = 0
        self._reshuffle()
        self._stop_if_stuck()
        return self.observe()

    def _perceive(self) -> None:
        """Perceived mode: look at the buffer (``_shown_indices``, as refilled) and the
        container, and show the boxes the robot lists, in its order (no-op otherwise)."""
        if self._perceiver is None:
            return
        self._buffered = self._shown_indices
        self._perception = perceive(
            self._perceiver,
            self._case,
            self._heightmap,
            self._backend.poses(),
            self._buffered,
            self._perception_rng,
        )
        listed = self._perception.listed_boxes(len(self._buffered))
        self._shown_indices = [self._buffered[p] for p in listed]
        first_id = self._next_seen_id
        self._next_seen_id += len(listed)
        items = exact_items(self._case, self._shown_indices, self._sides)
        self._shown = seen_items(items, self._perception, self._case, first_id)

    def _turned(self, object_id: int, rotation: int) -> int:
        """The box's own rotation that does what the policy chose: the policy's rotation refers
        to the sides it was shown, which perception lists longer first (``axis_swapped``), and
        exact observation as ``sides`` says."""
        if self._perceiver is None:
            size = self._case.objects[self._shown_indices[object_id]].size_mm
            return own_rotation(size, rotation, self._sides)
        return perceived_rotation(self._perception, object_id, rotation)

    @property
    def done(self) -> bool:
        return not self._pending or self.stopped_at is not None

    def _stop_if_stuck(self) -> int:
        """Online protocol: end the episode when the box that must be placed next fits nowhere
        (``core.feasibility.fits_somewhere`` on the true heightmap and the box's true size:
        what the robot could do, not what it believes). Returns the final settle's steps when
        it ended the episode, else 0."""
        if not self._protocol.online or not self._pending or not self._shown_indices:
            return 0
        index = self._shown_indices[0]
        item = exact_items(self._case, [index], self._sides)[0]
        if fits_somewhere(self._heightmap, item, self._case.container.height_mm):
            return 0
        self.stopped_at = index
        settle_steps = self._final_settle()
        self._show_nothing()
        return settle_steps

    @property
    def heightmap(self) -> np.ndarray:
        return self._heightmap

    def _reshuffle(self) -> int:
        """Refill the buffer and show it (perceived mode: look at it).

        In perceived mode the policy is shown the boxes the robot lists. A buffered box it did
        not identify keeps its place in the buffer, unshown, and is looked at again at the next
        observation, when the boxes beside it have changed (a cell picks what it can identify
        and scans again; the buffer refills only for what left it). The robot checks each look
        itself (as many box-like segments as the buffer holds, and no other); after
        ``LOOKS_BEFORE_SET_ASIDE`` looks in a row that fail it, it clears what it could not
        identify: the boxes under its segments that were not box-like leave the buffer (set
        aside, counted as missed); where it saw no such segment and can list nothing, the
        buffer's remaining boxes do (a person clears a buffer the robot cannot read). Returns
        the final settle's steps when that emptied the stream, else 0."""
        while True:
            self._show_window()
            self._perceive()
            if self._perceiver is None:
                return 0
            perception = self._perception
            # A look that lists nothing fails the check too: the buffer's count says otherwise.
            unclear = not (perception.clean and self._shown)
            self._unclear_looks = self._unclear_looks + 1 if unclear else 0
            if self._unclear_looks < LOOKS_BEFORE_SET_ASIDE:
                self.looked_again += len(perception.missed)
                if self._shown:
                    return 0
                continue  # nothing to pick: look again now
            self._unclear_looks = 0
            cleared = [self._buffered[p] for p in perception.cleared]
            if not cleared and not self._shown:
                cleared = [self._buffered[p] for p in perception.missed]
            for index in dict.fromkeys(cleared):  # each box once, in order
                self._set_aside.add(index)
                self._pending.remove(index)
                self.missed += 1
            if not self._pending:
                settle_steps = self._final_settle()
                self._show_nothing()
                return settle_steps
            if not cleared:
                return 0  # listed boxes and nothing to clear: the policy acts on them

    def _show_window(self) -> None:
        """Show the window of the stream: in perceived mode the buffer's boxes, which the
        robot then looks at (``_perceive``)."""
        shown = self._protocol.shown_count(self._case.buffer_size, len(self._pending))
        window = visible_window(self._pending, shown)
        # Online: shown in arrival order (the first is the one to place), no shuffle drawn.
        self._shown_indices = window if self._protocol.online else shuffled_view(window, self._rng)
        self._shown = exact_items(self._case, self._shown_indices, self._sides)

    def _show_nothing(self) -> None:
        """The stream is empty: an empty buffer, still looked at (perceived mode) so the
        observed heightmap is the one after the last placement."""
        self._shown_indices, self._shown = [], ()
        self._perceive()

    def _final_settle(self) -> int:
        """Settle the pile once the last object is processed; returns its physics steps."""
        final = self._last_settle = self._backend.finish()
        self._heightmap = final.heightmap
        self.final_settle_steps = final.settle_steps
        return final.settle_steps

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
            must_place_first=self._protocol.online,
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
        if self._protocol.online and int(action.object_id) != 0:
            return "not_first", self._shown_indices[0]
        index = self._shown_indices[int(action.object_id)]
        if action.sets_aside:
            return "set_aside", index
        if action.rotation not in (0, 1):
            return "bad_rotation", index
        rotation = self._turned(int(action.object_id), int(action.rotation))
        fx, fy = self._footprint_cells(index, rotation)
        if not footprint_fits(self._heightmap.shape, int(action.x), int(action.y), fx, fy):
            return "out_of_bounds", index
        return "", index

    def _random_shown(self) -> int:
        """The box an unusable action sets aside: a seeded draw among the shown ones, or
        online the first (the only one a step may process)."""
        if self._protocol.online:
            return self._shown_indices[0]
        return self._shown_indices[int(self._rng.integers(len(self._shown_indices)))]

    def _footprint_cells(self, index: int, rotation: int) -> tuple[int, int]:
        fx_mm, fy_mm = self._case.objects[index].footprint_mm(rotation)
        cell = self._case.container.cell_xy_mm
        return cells_covering(fx_mm, cell), cells_covering(fy_mm, cell)

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
        placement: Placement | None = None
        if not reason and isinstance(action, Action):  # no reason: an Action
            placement = self._place_chosen(action, index, seen_before, shown_before)
            if placement.skill is not None and placement.skill.set_aside:
                self._set_aside.add(index)  # the skill took it back out (place_skill)
            if self._perceiver is not None:
                item = shown_before[int(action.object_id)]
                chosen, x, y = int(action.rotation), int(action.x), int(action.y)
                predicted = predicted_after(self._perception, item, chosen, x, y)
        else:
            self._set_aside.add(index)
        entry = HistoryEntry(seen_before, shown_before, action, not reason)
        settle_steps, (positions, quaternions) = self._advance(index, entry)
        placed = placement.transition if placement else None
        result = StepResult(
            step_index=len(self.steps),
            action=action,
            valid=not reason,
            reason=reason,
            internal_id=self._case.objects[index].internal_id,
            shown=shown_before,
            drop_mm=placement.drop_mm if placement else None,
            settle_steps=settle_steps + (placed.settle_steps if placed else 0),
            settled=placed.settled if placed else True,
            wall_time_s=time.perf_counter() - started,
            positions_mm=positions,
            quaternions=quaternions,
            max_linear_speed=placed.max_linear_speed if placed else 0.0,
            max_angular_speed=placed.max_angular_speed if placed else 0.0,
            replan=None
            if self._perceiver is None
            else deviates(predicted, self._perception.heightmap, self._replan_rule),
            executed=placement.executed if placement else None,
            perception=perception_before,
            skill=placement.skill if placement else None,
            command=placement.command if placement else None,
            shown_ids=shown_ids,
        )
        self.steps.append(result)
        return result

    def _place_chosen(
        self,
        action: Action,
        index: int,
        seen: np.ndarray,
        shown: tuple[ShownItem, ...],
    ) -> Placement:
        """Carry out a valid ``action`` on case object ``index``, decided on the observed
        heightmap ``seen`` and buffer ``shown``."""
        chosen, x, y = int(action.rotation), int(action.x), int(action.y)
        rotation = self._turned(int(action.object_id), chosen)
        item = shown[int(action.object_id)]
        # Noisy execution: the robot's own belief, the footprint of the size it was shown
        # (perceived mode: the perceived size, named longer first; ``chosen`` refers to it).
        fx, fy = (
            self._footprint_cells(index, rotation)
            if self._execution is None
            else believed_footprint(item, chosen)
        )
        # The release height from what the robot sees (perceived mode: the perceived
        # heightmap; too low, the descent stops on contact).
        z = placement_height(seen, x, y, fx, fy)
        cell = self._case.container.cell_xy_mm
        drop = (x * cell, y * cell, z)
        position = int(action.object_id)
        executed = self._executed_drop(position, (fx, fy), drop)
        command = (
            None if executed is None else place_command(item.size_mm, chosen, drop, seen, executed)
        )
        # A placement the skill tries again draws the arm's noise afresh from the same stream.
        redraw = (
            None
            if self._execution is None
            else arm_redraw(self._execution, self._execution_rng, self._grasp_error(position))
        )
        placed, skill = carry_out(self._backend, index, rotation, drop, executed, command, redraw)
        self._last_settle = placed
        self._heightmap = placed.heightmap
        return Placement(drop, placed, executed, command, skill)

    def _advance(
        self, index: int, entry: HistoryEntry
    ) -> tuple[int, tuple[np.ndarray, np.ndarray]]:
        """After case object ``index`` was processed: the final settle if it was the last one,
        the poses after the step, the history, and the next objects shown. Returns the physics
        steps this added (final settle) and the poses."""
        settle_steps = self._final_settle() if len(self._pending) == 1 else 0
        poses = self._backend.poses()
        self._history.append(entry)
        self._pending.remove(index)
        if self._pending:
            settle_steps += self._reshuffle()
            settle_steps += self._stop_if_stuck()
        else:
            self._show_nothing()
        return settle_steps, poses

    @property
    def observed_heightmap(self) -> np.ndarray:
        """The heightmap the policy sees: the perceived one in perceived mode, else the exact."""
        return self._heightmap if self._perceiver is None else self._perception.heightmap

    def _grasp_error(self, position: int) -> tuple[float, float, float]:
        """The pose-estimate error of the shown box at ``position`` (perceived mode; none
        otherwise)."""
        if self._perceiver is None:
            return NO_GRASP_ERROR
        return grasp_error(self._perception, position)

    def _executed_drop(
        self, position: int, footprint_cells: tuple[int, int], drop: tuple[int, int, int]
    ) -> ExecutedDrop | None:
        """Noisy execution: the drop as the robot executes it (None in exact execution), with,
        in perceived mode, the pose-estimate error of the shown box at ``position``;
        ``footprint_cells`` is the footprint the robot believes in (of the size it was shown)."""
        if self._execution is None:
            return None
        cell = self._case.container.cell_xy_mm
        return robot_drop(
            self._execution,
            self._execution_rng,
            self._grasp_error(position),
            self.observed_heightmap,
            drop,
            footprint_cells,
            cell,
        )

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

    def online_outcome(self, metrics: EpisodeMetrics) -> OnlineOutcome | None:
        """The online protocol's record (None under the buffer protocol): space utilization of
        ``metrics`` (this episode's, taken once it is done), the box it stopped at and the
        boxes left unprocessed."""
        if not self._protocol.online:
            return None
        stopped = self.stopped_at
        return OnlineOutcome(
            space_utilization=space_utilization(metrics.inside_volume_mm3, self._case.container),
            stopped_at=None if stopped is None else self._case.objects[stopped].internal_id,
            unprocessed=len(self._pending),
        )


def episode_start(case: Case, seed: int) -> EpisodeStart:
    """What a policy is told at the start of an episode of ``case`` with run seed ``seed``: the
    container, the buffer size, and random streams derived as the episode's own shuffle is
    (stream k from the case seed plus k), so a policy's draws are reproducible per case and run
    seed while the seed itself never reaches it."""
    return EpisodeStart(
        container=case.container,
        buffer_size=case.buffer_size,
        streams=lambda stream: episode_rng(case.seed + stream, seed),
    )


def policy_start(policy: Any, case: Case, seed: int) -> Any:
    """What ``policy.reset`` is handed: the case itself only for a policy that declares
    ``needs_case = True`` (the oracle, which replays the case's plan), otherwise
    :func:`episode_start`. Every episode loop hands a policy its start through this. Typed
    ``Any``: which of the two a policy takes is the policy's own declaration."""
    return case if getattr(policy, "needs_case", False) else episode_start(case, seed)


def answer_format(policy: Any) -> dict[str, Any] | None:
    """How ``policy`` read the answer its latest ``act`` returned, for the step's record: the
    optional hook ``policy.last_answer_format()`` (DESIGN.md section 7) of policies that read a
    model's text answer. It returns None (no answer was read: a refused request, or the policy
    reads no text) or a mapping with ``format_event`` (``strict_json`` | ``extra_text`` |
    ``parse_fail``) and, where they apply, ``reasked`` (bool) and ``forced`` (why a forced
    set-aside replaced the answer). None for a policy without the hook; ValueError naming the
    policy, key and value for anything else."""
    hook = getattr(policy, "last_answer_format", None)
    found = None if hook is None else hook()
    if found is None:
        return None
    who = f"policy {getattr(policy, 'name', type(policy).__name__)!r}: last_answer_format()"
    if not isinstance(found, Mapping):
        raise ValueError(f"{who} = {found!r}: expected a mapping or None")  # noqa: TRY004
    unknown = sorted(set(found) - {"format_event", "reasked", "forced"})
    if unknown:
        raise ValueError(f"{who}: unknown key(s) {', '.join(map(repr, unknown))}")
    event, reasked, forced = found.get("format_event"), found.get("reasked"), found.get("forced")
    if event not in FORMAT_EVENTS:
        events = ", ".join(FORMAT_EVENTS)
        raise ValueError(f"{who}: format_event = {event!r}: expected one of {events}")
    if "reasked" in found and not isinstance(reasked, bool):
        raise ValueError(f"{who}: reasked = {reasked!r}: expected true or false")
    if "forced" in found and not (isinstance(forced, str) and forced):
        raise ValueError(f"{who}: forced = {forced!r}: expected the reason, a non-empty string")
    return {k: found[k] for k in ("format_event", "reasked", "forced") if k in found}


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
    protocol: PackingProtocol = BUFFER,
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
        protocol=protocol,
    )
    observation = episode.reset(case, seed)
    policy.reset(policy_start(policy, case, seed), seed)
    decision_wall: list[float] = []
    decision_cpu: list[float] = []
    formats: list[dict[str, Any] | None] = []
    while not episode.done:
        t0, c0 = time.perf_counter(), time.process_time()
        action = policy.act(observation)
        decision_wall.append(time.perf_counter() - t0)
        decision_cpu.append(time.process_time() - c0)
        formats.append(answer_format(policy))
        episode.step(action)
        if not episode.done:
            observation = episode.observe()
    metrics = episode.metrics()
    return EpisodeResult(
        case_id=case.episode_id,
        seed=seed,
        policy=getattr(policy, "name", type(policy).__name__),
        backend=episode._backend.name,
        steps=tuple(episode.steps),
        metrics=metrics,
        poses=episode.final_poses(),
        policy_time_s=math.fsum(decision_wall),
        decision_s=tuple(decision_wall),
        decision_cpu_s=tuple(decision_cpu),
        replans=None if perceiver is None else sum(bool(s.replan) for s in episode.steps),
        missed=None if perceiver is None else episode.missed,
        looked_again=None if perceiver is None else episode.looked_again,
        skill=None if execution is None else skill_totals(episode.steps),
        online=episode.online_outcome(metrics),
        answer_formats=tuple(formats) if any(formats) else (),
    )


__all__ = [
    "DEFAULT_REPLAN",
    "INVALID_REASONS",
    "Episode",
    "EpisodeResult",
    "OnlineOutcome",
    "StepResult",
    "answer_format",
    "run_episode",
    "skill_totals",
]
