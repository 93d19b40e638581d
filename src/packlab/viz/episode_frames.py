"""An episode as a sequence of frames, one per step: what a viewer draws at each step.

Two sources give the same frames:

* ``live_frames``: run a policy on a case and yield each step as it happens (the policy's
  decision time measured around ``act``), so a viewer can follow a running episode.
* ``replay_frames``: a bench record's episode, step by step, from what the record holds:

  - records that carry each step's pose changes (``StepRecord.poses``) give the
    boxes' poses after every step as recorded (to the records' 0.5 mm / 1e-3 tolerance), and
    the heightmaps rasterised from those poses; no engine runs, so a MuJoCo record shows what
    was scored whatever engine version reads it;
  - older records keep actions and final poses only: their actions are stepped again through a
    fresh episode on the record's backend. That is exact on the geometric backend; on MuJoCo it
    is exact when the engine version and physics settings equal the run's (the episode is
    deterministic in case, seed, actions, backend and settings). ``Replay.exact`` says whether
    the replay reproduced the record's steps, scores and final poses.

  Records keep the policy's total decision time only, so a replay's frames carry no per-step
  latency (``policy_s`` is None) and ``Replay.mean_policy_s`` is the mean per decision.

Frames hold numpy arrays and the step's ``StepResult``; no viewer library is needed here.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from msgspec import UNSET, UnsetType

from packlab.core.choices import DEFAULT_SIDES, SideNames, named_size
from packlab.core.errors import ConfigError
from packlab.core.packing_protocol import BUFFER, PackingProtocol
from packlab.core.records import EpisodeOk, StepRecord, to_builtins
from packlab.core.types import Case, InternalId, ShownItem
from packlab.metrics import EpisodeMetrics
from packlab.sim.episode import Episode, StepResult, policy_start
from packlab.sim.heightmap import rasterise_poses

#: Largest distance (mm) between a re-simulated and a recorded final box centre still called
#: the same: records round final positions to 1e-3 mm, so more than rounding is another episode.
SAME_POSE_MM = 0.01
#: The same for frames from a record's per-step poses: a box is written again only once it
#: moved 0.5 mm along an axis (``packlab.sim.pose_log``), so its shown centre may be that far
#: off on each axis, plus the 0.1 mm rounding.
RECORD_POSE_MM = 0.6 * math.sqrt(3)
#: How a replay got its frames.
RECORDED_POSES, RESIMULATED = "recorded poses", "re-simulated"


@dataclass(frozen=True, slots=True)
class Frame:
    """One step of an episode as a viewer shows it."""

    step: StepResult  # action, validity, shown buffer, and the poses of all boxes after it
    heightmap: np.ndarray  # (x_cells, y_cells) int32 mm after this step
    policy_s: float | None  # the policy's decision time of this step; None: not recorded
    metrics: EpisodeMetrics | None  # the episode's scores, on the last frame only


@dataclass(frozen=True, slots=True)
class Replay:
    """A record replayed as frames, and how well the replay matches the record."""

    frames: tuple[Frame, ...]
    method: str  # RECORDED_POSES, or RESIMULATED: the actions stepped again on the backend
    same_steps: bool  # every step processed the recorded object with the recorded validity
    same_scores: bool  # replayed Overall, Success Ratio and Compactness equal the recorded ones
    max_pose_error_mm: float  # largest shown-vs-recorded final centre distance (nan: none)
    mean_policy_s: float  # the record's policy time per decision

    @property
    def exact(self) -> bool:
        """The frames are the recorded episode (same steps, scores and final poses)."""
        error = self.max_pose_error_mm
        tolerance = RECORD_POSE_MM if self.method == RECORDED_POSES else SAME_POSE_MM
        return self.same_steps and self.same_scores and (math.isnan(error) or error <= tolerance)


def _frame(episode: Episode, result: StepResult, policy_s: float | None) -> Frame:
    return Frame(
        result,
        episode.heightmap.copy(),
        policy_s,
        episode.metrics() if episode.done else None,
    )


def live_frames(
    case: Case, policy: Any, seed: int = 0, backend: str = "mujoco", physics: Any = None
) -> Iterator[Frame]:
    """Run ``policy`` (the Policy protocol) on ``case``, yielding each step as it is taken."""
    episode = Episode(backend, physics)
    observation = episode.reset(case, seed)
    policy.reset(policy_start(policy, case, seed), seed)
    while not episode.done:
        started = time.perf_counter()
        action = policy.act(observation)
        policy_s = time.perf_counter() - started
        result = episode.step(action)
        yield _frame(episode, result, policy_s)
        if not episode.done:
            observation = episode.observe()


def _pose_error_mm(case: Case, record: EpisodeOk, last: StepResult) -> float:
    """Largest distance between shown and recorded final centres (nan when none compare)."""
    errors = []
    for i, box in enumerate(case.objects):
        recorded = record.final_poses.get(str(box.internal_id))
        shown = last.positions_mm[i]
        if recorded is None or np.isnan(shown).any():
            if (recorded is None) != bool(np.isnan(shown).any()):
                return math.inf  # placed in one and not in the other
            continue
        errors.append(float(np.linalg.norm(shown - np.asarray(recorded.position_mm))))
    return max(errors, default=math.nan)


def has_step_poses(record: EpisodeOk) -> bool:
    """Whether every step of the record carries its pose changes (older records lack them)."""
    return bool(record.steps) and all(getattr(s, "poses", UNSET) is not UNSET for s in record.steps)


def _shown_items(
    case: Case, ids: tuple[InternalId, ...], sides: SideNames
) -> tuple[ShownItem, ...]:
    """A step record's shown ids as the ShownItems the policy saw (sizes from the case, named
    as the run named them)."""
    cell_xy, cell_z = case.container.cell_xy_mm, case.container.cell_z_mm
    items = []
    for index, iid in enumerate(ids):
        box = case.box_by_id(iid)
        size = named_size(box.size_mm, sides)
        l, w, h = size
        cells = (-(-l // cell_xy), -(-w // cell_xy), -(-h // cell_z))
        items.append(ShownItem(index, iid, size, cells, box.type_id))
    return tuple(items)


def _recorded_step(
    case: Case, step: StepRecord, pos: np.ndarray, quat: np.ndarray, sides: SideNames
) -> StepResult:
    return StepResult(
        step_index=step.step,
        action=step.action.to_action(),
        valid=step.valid,
        reason=step.reason,
        internal_id=step.internal_id,
        shown=_shown_items(case, step.shown, sides),
        drop_mm=step.drop_mm,
        settle_steps=step.settle_steps,
        settled=step.settled,
        wall_time_s=step.wall_time_s,
        positions_mm=pos.copy(),
        quaternions=quat.copy(),
        max_linear_speed=step.max_linear_speed_mps,
        max_angular_speed=step.max_angular_speed_radps,
    )


def _recorded_frames(case: Case, record: EpisodeOk, sides: SideNames) -> tuple[Frame, ...]:
    """Frames from a record's own per-step poses; heightmaps rasterised from them."""
    n = len(case.objects)
    pos, quat = np.full((n, 3), np.nan), np.full((n, 4), np.nan)
    sizes = np.array([b.size_mm for b in case.objects], dtype=np.float64).reshape(n, 3)
    container = case.container
    frames = []
    for k, step in enumerate(record.steps):
        assert not isinstance(step.poses, UnsetType), "has_step_poses(record) first"
        for entry in step.poses:
            i = int(entry[0])
            if not 0 <= i < n:
                raise ConfigError(
                    f"record {record.case_id}/{record.policy}/seed {record.seed}: step "
                    f"{step.step} field 'poses' = {entry!r}: object index {i} not in the case"
                )
            pos[i], quat[i] = entry[1:4], entry[4:8]
        placed = ~np.isnan(pos).any(axis=1)
        heightmap = rasterise_poses(
            container.cells, container.cell_xy_mm, sizes[placed], pos[placed], quat[placed]
        )
        last = k == len(record.steps) - 1
        metrics = _episode_metrics(record) if last else None
        frames.append(Frame(_recorded_step(case, step, pos, quat, sides), heightmap, None, metrics))
    return tuple(frames)


def _episode_metrics(record: EpisodeOk) -> EpisodeMetrics:
    """The metrics an episode record holds, as the episode computed them."""
    fields: dict[str, Any] = to_builtins(record.metrics)  # EpisodeMetrics' fields, JSON values
    return EpisodeMetrics(**fields)


def _resimulated_frames(
    case: Case, record: EpisodeOk, physics: Any, sides: SideNames, protocol: PackingProtocol
) -> tuple[tuple[Frame, ...], bool, bool]:
    """(frames, same steps, same scores) of the record's actions stepped again, under the side
    names the run showed (a recorded rotation refers to them)."""
    episode = Episode(record.backend, physics, sides=sides, protocol=protocol)
    episode.reset(case, record.seed)
    frames: list[Frame] = []
    same_steps = True
    for step in record.steps:
        if episode.done:  # more recorded steps than objects: not this case's episode
            return tuple(frames), False, False
        result = episode.step(step.action.to_action())
        same_steps &= result.internal_id == step.internal_id and result.valid == step.valid
        frames.append(_frame(episode, result, None))
    m, rec = episode.metrics(), record.metrics
    same_scores = episode.done and all(
        abs(getattr(m, k) - float(getattr(rec, k))) <= 1e-6
        for k in ("overall", "success_ratio", "compactness")
    )
    return tuple(frames), bool(same_steps), bool(same_scores)


def replay_frames(
    case: Case,
    record: EpisodeOk,
    physics: Any = None,
    resimulate: bool = False,
    sides: SideNames = DEFAULT_SIDES,
    protocol: PackingProtocol = BUFFER,
) -> Replay:
    """A record's episode as frames: from its per-step poses when it has them, else (or with
    ``resimulate``) by stepping its actions again on its backend with ``physics``. ``sides``:
    the side names the run showed (``packlab.bench.config.run_sides``); ``protocol``: the
    protocol it ran under (a recorded object index refers to the buffer that showed)."""
    if record.case_id != case.episode_id:
        raise ConfigError(
            f"record case_id = {record.case_id!r} does not match case {case.episode_id!r}"
        )
    if not record.steps:
        raise ConfigError(f"record {record.case_id}/{record.policy}/seed {record.seed}: no steps")
    if has_step_poses(record) and not resimulate:
        method, frames = RECORDED_POSES, _recorded_frames(case, record, sides)
        same_steps = same_scores = True  # the record's own steps and scores
    else:
        method = RESIMULATED
        frames, same_steps, same_scores = _resimulated_frames(
            case, record, physics, sides, protocol
        )
    return Replay(
        frames,
        method,
        same_steps,
        same_scores,
        _pose_error_mm(case, record, frames[-1].step),
        record.policy_time_s / len(record.steps),
    )


__all__ = [
    "RECORDED_POSES",
    "RESIMULATED",
    "SAME_POSE_MM",
    "Frame",
    "Replay",
    "has_step_poses",
    "live_frames",
    "replay_frames",
]
