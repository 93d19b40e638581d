"""Replay validation: does a generated plan really pack, step by step, in the closed loop?

Two layers of checks:

1. ``plan_problems`` (pure, instant): the plan replayed on the heightmap with the project's own
   Eq. 2 functions must put every object fully supported (all cells under it at its bottom),
   where its cells say, and end with a flat top at the stack height filling X * Y * H. These
   catch generator bugs, so in a healthy generator they never reject anything.
2. ``replay`` : the oracle replays the plan through ``run_episode`` on the configured backend
   with the bench's buffer and shuffle (mujoco physics by default). A trajectory is kept only
   if every step is valid and Overall >= ``min_overall``.

``check_case`` runs both and returns a ``Verdict`` whose ``reason`` names the first failure
("" when accepted): ``plan_check``, ``invalid_step:<reason>``, ``overall_below_min`` or
``engine_error:<exception>``; the data engine counts rejections by these names.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from packlab.core.choices import DEFAULT_SIDES, SideNames
from packlab.core.feasibility import footprint_fits, placement_height
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Case, Observation, ShownItem, Unparsable
from packlab.datagen.config import ValidationConfig
from packlab.metrics import EpisodeMetrics
from packlab.policies import make_policy
from packlab.sim.episode import run_episode
from packlab.sim.heightmap import place_box


def off_grid(case: Case) -> bool:
    """The case is of the off-grid sizes (``CaseConfig.sizes``): each box smaller than the
    slot its plan step names (``target_box_cells``), as its generator records."""
    return (case.generator or {}).get("sizes") == "off-grid"


def plan_problems(case: Case) -> list[str]:
    """Why ``case.gt_plan`` is not a perfect, fully supported packing (empty when it is).

    Off-grid cases (:func:`off_grid`) are checked on their slots: each box lies within its
    slot's cells (less than a cell smaller across, at most its height), and the slots tile the
    stack cuboid as a grid case's boxes do."""
    if case.gt_plan is None:
        return ["case has no gt_plan"]
    c = case.container
    hm = np.zeros(c.cells, dtype=np.int32)
    problems: list[str] = []
    if [p.internal_id for p in case.gt_plan] != [b.internal_id for b in case.objects]:
        problems.append("arrival order differs from plan order")
    boxes = {b.internal_id: b for b in case.objects}
    slots = off_grid(case)
    filled = 0
    for p in case.gt_plan:
        box = boxes[p.internal_id]
        fx_mm, fy_mm = box.footprint_mm(p.rotation)
        where = f"object {p.internal_id} (plan step {p.gt_index})"
        if slots:
            fx, fy = p.cell_size[0], p.cell_size[1]
            height = p.cell_size[2] * c.cell_z_mm
            inside = (
                (fx - 1) * c.cell_xy_mm < fx_mm <= fx * c.cell_xy_mm
                and (fy - 1) * c.cell_xy_mm < fy_mm <= fy * c.cell_xy_mm
                and box.size_mm[2] <= height
            )
        else:
            fx, fy = fx_mm // c.cell_xy_mm, fy_mm // c.cell_xy_mm
            height = box.size_mm[2]
            inside = (fx, fy, box.size_mm[2] // c.cell_z_mm) == p.cell_size
        if not inside or (p.x, p.y) != p.cell_min[:2]:
            problems.append(
                f"{where}: cells {p.cell_min}+{p.cell_size} disagree with size {box.size_mm}"
            )
            continue
        if not footprint_fits(hm.shape, p.x, p.y, fx, fy):
            problems.append(f"{where}: footprint outside the container")
            continue
        under = hm[p.x : p.x + fx, p.y : p.y + fy]
        z = placement_height(hm, p.x, p.y, fx, fy)
        if z != p.cell_min[2] * c.cell_z_mm or int(under.min()) != z:
            problems.append(
                f"{where}: drops to {z} mm over {int(under.min())}..{z} mm, plan says "
                f"{p.cell_min[2] * c.cell_z_mm} mm"
            )
        hm = place_box(hm, p.x, p.y, fx, fy, z + height)
        filled += fx * fy * c.cell_xy_mm**2 * height
    top = int(hm.max())
    if int(hm.min()) != top:
        problems.append(f"final surface is not flat ({int(hm.min())}..{top} mm)")
    volume = filled if slots else case.total_volume_mm3
    if volume != c.size_mm[0] * c.size_mm[1] * top:
        problems.append("object volumes do not fill X * Y * stack height")
    return problems


def plan_fill(case: Case) -> float:
    """The boxes' volume over their plan slots' volume: 1 for a grid case, less off the grid
    (the Compactness the plan reaches with every box at its slot's height)."""
    if case.gt_plan is None or not off_grid(case):
        return 1.0
    c = case.container
    slots = sum(
        p.cell_size[0] * p.cell_size[1] * c.cell_xy_mm**2 * p.cell_size[2] * c.cell_z_mm
        for p in case.gt_plan
    )
    return case.total_volume_mm3 / slots if slots else 1.0


@dataclass(frozen=True, slots=True)
class SeenStep:
    """What the policy saw at one step of a replay, and what it did."""

    step_index: int
    heightmap: np.ndarray  # (x_cells, y_cells) int32 mm, the observed surface before the action
    shown: tuple[ShownItem, ...]  # the buffer in the order shown this step
    remaining: int  # objects not yet processed, shown ones included
    action: Action | Unparsable  # object_id indexes ``shown``


@dataclass(frozen=True, slots=True)
class Trajectory:
    """A replayed episode: per step what was seen and done, then the final scores."""

    case: Case
    run_seed: int
    backend: str
    steps: tuple[SeenStep, ...]
    valid: tuple[bool, ...]  # per step
    reasons: tuple[str, ...]  # per step, "" when valid
    drops: tuple[tuple[int, int, int] | None, ...]  # per step: footprint min corner and Eq. 2 z, mm
    metrics: EpisodeMetrics


class _Recording:
    """Wraps a policy and keeps every observation it was asked to act on."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.name = inner.name
        self.seen: list[SeenStep] = []

    @property
    def needs_case(self) -> bool:
        return bool(getattr(self.inner, "needs_case", False))

    def reset(self, case: EpisodeStart | Case, seed: int) -> None:
        self.seen = []
        self.inner.reset(case, seed)

    def act(self, obs: Observation) -> Action | Unparsable:
        action = self.inner.act(obs)
        seen = SeenStep(obs.step_index, obs.heightmap, obs.shown, obs.remaining_known(), action)
        self.seen.append(seen)
        return action


#: Options a teacher plays with here: a dataset's actions are placements, which cannot say "set
#: this box aside", so the planner teaches the rim rule they can hold (``overflow=place``,
#: :mod:`packlab.policies.overflow`) instead of setting boxes aside.
TEACHER_OPTIONS: dict[str, dict[str, Any]] = {
    "plan": {"overflow": "place"},
    "plan-lookahead": {"overflow": "place"},
}


def replay(
    case: Case,
    backend: str = "mujoco",
    run_seed: int = 0,
    physics: Any = None,
    teacher: str = "oracle",
    sides: SideNames = DEFAULT_SIDES,
) -> Trajectory:
    """A closed-loop run of ``teacher`` on ``case`` (run_episode with the bench's loop); the
    default, the oracle, replays ``case.gt_plan``. The observations recorded, and so the sizes
    and actions a dataset writes, name sides as ``sides`` says (the oracle turns the plan's
    catalogue rotations to match)."""
    policy = _Recording(make_policy(teacher, **TEACHER_OPTIONS.get(teacher, {})))
    result = run_episode(case, policy, run_seed, backend=backend, physics=physics, sides=sides)
    return Trajectory(
        case=case,
        run_seed=run_seed,
        backend=result.backend,
        steps=tuple(policy.seen),
        valid=tuple(s.valid for s in result.steps),
        reasons=tuple(s.reason for s in result.steps),
        drops=tuple(s.drop_mm for s in result.steps),
        metrics=result.metrics,
    )


@dataclass(frozen=True, slots=True)
class Verdict:
    """Accept or reject one case; ``trajectory`` is the replay when one ran."""

    accepted: bool
    reason: str
    trajectory: Trajectory | None = None


def judge(trajectory: Trajectory, min_overall: float) -> str:
    """The rejection reason of a replay ("" when it is kept). Off the grid the bar is
    ``min_overall`` times the plan's fill (:func:`plan_fill`): the boxes leave their slots'
    clearance empty, so a perfect replay scores that fill, not 1."""
    for valid, reason in zip(trajectory.valid, trajectory.reasons):
        if not valid:
            return f"invalid_step:{reason}"
    if trajectory.metrics.overall < min_overall * plan_fill(trajectory.case):
        return "overall_below_min"
    return ""


def check_case(
    case: Case,
    cfg: ValidationConfig,
    replay_plan: bool = True,
    physics: Any = None,
    sides: SideNames = DEFAULT_SIDES,
) -> Verdict:
    """Plan checks, then (with ``replay_plan``) the closed-loop replay on ``cfg.backend``, its
    observations naming sides as ``sides`` says."""
    if plan_problems(case):
        return Verdict(False, "plan_check")
    if not replay_plan:
        return Verdict(True, "")
    try:
        trajectory = replay(case, cfg.backend, cfg.run_seed, physics, sides=sides)
    except Exception as exc:  # noqa: BLE001 - an engine failure rejects the case; the run goes on
        return Verdict(False, f"engine_error:{type(exc).__name__}")
    reason = judge(trajectory, cfg.min_overall)
    return Verdict(not reason, reason, trajectory)
