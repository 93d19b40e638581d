"""One planning step of a robot cell, free of HTTP: depth images (or detections) in, a placement
out.

``open_session`` makes the state a cell's container needs (its policy, made once, and the
history the policy reads); ``plan_step`` builds the observation packlab's perceived mode would
show (the container heightmap from the container camera, the buffer's boxes from the buffer
camera or from the cell's own detections), asks the policy, and says what the place skill
(``packlab.sim.physics.place_skill``) would do with the answer. The HTTP service
(``packlab.cell.app``) and any other driver (a bench adapter rendering packlab's own cameras)
call these two functions with decoded arrays.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from packlab.cell.buffer import measure_boxes
from packlab.cell.errors import CellInputError
from packlab.cell.geometry import Calibration, buffer_image, container_heightmap, container_image
from packlab.cell.limits import MAX_BOXES
from packlab.core.choices import DEFAULT_SIZE_PRIOR, SizePrior
from packlab.core.errors import ConfigError
from packlab.core.feasibility import footprint_fits, placement_height
from packlab.core.protocols import EpisodeStart, Policy
from packlab.core.types import (
    Action,
    Container,
    HistoryEntry,
    Observation,
    ShownItem,
    Unparsable,
)
from packlab.policies.registry import policy_factory
from packlab.sim.buffer import MEASURED_SIDE_SLACK_MM, episode_rng, size_cells
from packlab.sim.execution import ExecutedDrop, ExecutionNoise, full_faces, place_command
from packlab.sim.execution import seat_sides as skill_seat_sides
from packlab.sim.physics.place_skill import APPROACH_MM, PLACE_RETRIES, PlaceCommand
from packlab.sim.placement import believed_footprint
from packlab.sim.sensing.perception import size_quanta
from packlab.sim.sensing.presets import SensorPreset

#: Why a step sets its box aside instead of placing it: the policy chose to (``set_aside``),
#: or its answer was not a placement in the container (the others; the episode's reasons).
SetAsideReason = Literal[
    "set_aside", "unparsable", "bad_object_id", "bad_rotation", "out_of_bounds"
]


@dataclass(frozen=True, slots=True)
class PickPose:
    """A box's top-face centre and yaw on the buffer, in the buffer's frame (mm, degrees)."""

    x_mm: float
    y_mm: float
    z_mm: float
    yaw_deg: float  # of the box's first side (l) from the frame's x axis


@dataclass(frozen=True, slots=True)
class Detection:
    """A box the cell measured itself: its sides (l, w, h mm) and, if known, its pick pose."""

    size_mm: tuple[int, int, int]
    pick: PickPose | None = None


@dataclass(frozen=True, slots=True)
class CellConfig:
    """What a session is opened with: one container and its cameras."""

    container: Container
    buffer_size: int
    container_camera: Calibration
    buffer_camera: Calibration | None
    sensor: SensorPreset  # what the perception's thresholds assume of the depth noise
    execution: ExecutionNoise  # the place skill's settings (approach, slides, seating)
    policy: str
    policy_options: Mapping[str, Any] = field(default_factory=dict)
    seed: int = 0
    size_prior: SizePrior = DEFAULT_SIZE_PRIOR  # what the measured sizes snap to


@dataclass(slots=True)
class SessionState:
    """A session's mutable state: the config, its policy and what the policy has seen."""

    config: CellConfig
    policy: Policy
    history: list[HistoryEntry] = field(default_factory=list)
    steps: int = 0
    next_seen_id: int = 0  # boxes get fresh ids per observation, as in perceived mode


@dataclass(frozen=True, slots=True)
class StepInput:
    """One step's sensing, decoded: depth arrays in mm with NaN where a pixel has no depth."""

    container_depth_mm: np.ndarray  # (height, width) float32/64, the container camera's image
    buffer_depth_mm: np.ndarray | None = None  # the buffer camera's image, or
    detections: tuple[Detection, ...] | None = None  # the cell's own measurements
    remaining: int | None = None  # boxes still to pack, shown ones included; None: unknown
    #: This step's cameras where they differ from the session's (a camera that moved).
    container_camera: Calibration | None = None
    buffer_camera: Calibration | None = None


@dataclass(frozen=True, slots=True)
class MeasuredBox:
    """A box on the buffer as packlab took it: index (as the answer names it), sides, pose."""

    index: int
    size_mm: tuple[int, int, int]  # (l, w, h); rotation 0 puts l along the container's x
    pick: PickPose | None


@dataclass(frozen=True, slots=True)
class Approach:
    """How the place skill would put the box down (``packlab.sim.physics.place_skill``), in the
    container frame: positions are the held box's top-face centre (where a gripper holds it)."""

    start_mm: tuple[float, float, float]  # the guarded descent starts here, above all it sees
    release_mm: tuple[float, float, float]  # the gripper opens here (``release_height_mm`` up)
    release_height_mm: float  # the box's bottom over its rest height when let go
    comply_mm: float  # how far a contact may slide the box on the way down, in all
    seat_sides: tuple[int, int]  # per axis (x, y) the side pushed flush: -1, +1 or 0 (none)
    seat_reach_mm: float  # how far past the target a guarded push may go
    full_faces: tuple[bool, bool]  # per axis, whether that side is a face along the whole box
    retries: int  # descents tried again from above when one stops high
    set_aside_if_stuck: bool  # still stuck after the retries: take it out, set it aside


@dataclass(frozen=True, slots=True)
class Placement:
    """Where the chosen box goes, in the container frame."""

    rotation: int  # 0: l along x; 1: turned 90 degrees, l along y
    cell: tuple[int, int]  # the footprint's minimum cell (the policy's x, y)
    footprint_mm: tuple[float, float]  # (x, y) extent under the rotation
    bottom_z_mm: float  # rest height of the box's bottom: the heightmap's max under it
    target_mm: tuple[float, float, float]  # top-face centre at rest
    yaw_deg: float  # of the box's l side from the container's x axis: 0 or 90
    approach: Approach


@dataclass(frozen=True, slots=True)
class Timings:
    """Milliseconds spent per stage of one step."""

    decode_ms: float = 0.0  # request to arrays (the HTTP layer's share; 0 called directly)
    heightmap_ms: float = 0.0
    segmentation_ms: float = 0.0  # buffer image to boxes (0 with detections)
    policy_ms: float = 0.0
    total_ms: float = 0.0


@dataclass(frozen=True, slots=True)
class StepAnswer:
    """What one step decided, and what it was decided on."""

    step_index: int
    decision: Literal["place", "set_aside"]
    reason: SetAsideReason | None  # why not placed; None when placed
    box: MeasuredBox  # the box to place or set aside
    placement: Placement | None
    boxes: tuple[MeasuredBox, ...]  # every box the step saw, as the policy was shown them
    heightmap: np.ndarray  # (x_cells, y_cells) int32 mm, what the policy was shown
    cell_mm: int  # the heightmap's cell side
    unseen_cells: int  # heightmap cells no pixel saw (each took its nearest seen cell's height)
    dropped_segments: int  # buffer segments left out as not box-like (0 with detections)
    action: Action | Unparsable  # the policy's own answer
    timings: Timings


def open_session(config: CellConfig) -> SessionState:
    """A fresh session: the policy made by name and reset for this container.

    The policy is reset with what a cell knows (:func:`cell_start`); a policy that needs a
    case (the oracle) is refused.
    """
    try:
        factory = policy_factory(config.policy)
    except ConfigError as exc:
        reason = str(exc).removeprefix(f"policy = {config.policy!r}: ")
        raise CellInputError("policy", config.policy, reason) from None
    try:
        policy = factory(**dict(config.policy_options))
    except (ConfigError, TypeError) as exc:  # TypeError: a keyword the factory does not take
        raise CellInputError("policy_options", dict(config.policy_options), str(exc)) from None
    if getattr(policy, "needs_case", False):
        raise CellInputError("policy", config.policy, "replays a case's plan, which a cell has not")
    policy.reset(cell_start(config), config.seed)
    return SessionState(config, policy)


def cell_start(config: CellConfig) -> EpisodeStart:
    """What a session's policy is told at its start: the container, the buffer's size, and
    random streams of its own drawn from the session's seed alone (a cell has no case)."""
    seed = config.seed
    return EpisodeStart(
        container=config.container,
        buffer_size=config.buffer_size,
        streams=lambda stream: episode_rng(stream, seed),
    )


def plan_step(state: SessionState, step: StepInput) -> StepAnswer:
    """Perceive, decide and plan one placement; the session's history grows by the step."""
    started = time.perf_counter()
    config = state.config
    heightmap, unseen = _heightmap(config, step)
    after_heightmap = time.perf_counter()
    boxes, dropped = _boxes(config, step)
    after_boxes = time.perf_counter()
    _check_boxes(config, step, boxes)
    shown = shown_items(boxes, config.container, state.next_seen_id)
    state.next_seen_id += len(shown)
    observation = Observation(
        step_index=state.steps,
        container=config.container,
        heightmap=heightmap.copy(),  # a policy may scribble on its copy
        shown=shown,
        history=tuple(state.history),
        remaining=step.remaining,
    )
    action = state.policy.act(observation)
    after_policy = time.perf_counter()
    reason, index = judge(action, observation)
    placement = None if reason else _placement(config, heightmap, boxes[index], action)
    state.history.append(HistoryEntry(heightmap, shown, action, placement is not None))
    state.steps += 1
    done = time.perf_counter()
    timings = Timings(
        heightmap_ms=1e3 * (after_heightmap - started),
        segmentation_ms=1e3 * (after_boxes - after_heightmap),
        policy_ms=1e3 * (after_policy - after_boxes),
        total_ms=1e3 * (done - started),
    )
    return StepAnswer(
        step_index=observation.step_index,
        decision="set_aside" if reason else "place",
        reason=reason,
        box=boxes[index],
        placement=placement,
        boxes=boxes,
        heightmap=heightmap,
        cell_mm=config.container.cell_xy_mm,
        unseen_cells=unseen,
        dropped_segments=dropped,
        action=action,
        timings=timings,
    )


def shown_items(
    boxes: tuple[MeasuredBox, ...], container: Container, first_id: int
) -> tuple[ShownItem, ...]:
    """The buffer as perceived mode shows it (``packlab.sim.perceived.seen_items``): measured
    sizes, cells rounded up less ``MEASURED_SIDE_SLACK_MM``, fresh ids ``seen-<n>`` counted from
    ``first_id``, no catalogue type (a camera cannot tell which box it saw at the previous
    step)."""
    return tuple(
        ShownItem(
            shown_index=i,
            internal_id=f"seen-{first_id + i:05d}",
            size_mm=box.size_mm,
            size_cells=size_cells(box.size_mm, container, MEASURED_SIDE_SLACK_MM),
        )
        for i, box in enumerate(boxes)
    )


def judge(
    action: Action | Unparsable, observation: Observation
) -> tuple[SetAsideReason | None, int]:
    """(why the action is not a placement, or None; the index of the box it concerns). An answer
    that names no box concerns box 0, the one the cell then sets aside."""
    if isinstance(action, Unparsable):
        return "unparsable", 0
    object_id = action.object_id
    if not isinstance(object_id, (int, np.integer)) or not 0 <= object_id < len(observation.shown):
        return "bad_object_id", 0
    index = int(object_id)
    if action.sets_aside:
        return "set_aside", index
    if action.rotation not in (0, 1):
        return "bad_rotation", index
    fx, fy = believed_footprint(observation.shown[index], int(action.rotation))
    if not footprint_fits(observation.heightmap.shape, int(action.x), int(action.y), fx, fy):
        return "out_of_bounds", index
    return None, index


def _heightmap(config: CellConfig, step: StepInput) -> tuple[np.ndarray, int]:
    calibration = step.container_camera or config.container_camera
    depth = _check_shape("container_image", step.container_depth_mm, calibration)
    image = container_image(depth, calibration, config.container)
    return container_heightmap(image, config.container, config.sensor.flat_tolerance_mm)


def _boxes(config: CellConfig, step: StepInput) -> tuple[tuple[MeasuredBox, ...], int]:
    """The buffer's boxes, from the buffer image or the detections, and segments dropped."""
    if (step.buffer_depth_mm is None) == (step.detections is None):
        given = "both" if step.detections is not None else "neither"
        raise CellInputError("buffer_image, detections", given, "send exactly one of the two")
    if step.detections is not None:
        return tuple(MeasuredBox(i, d.size_mm, d.pick) for i, d in enumerate(step.detections)), 0
    calibration = step.buffer_camera or config.buffer_camera
    if calibration is None:
        raise CellInputError(
            "buffer_camera",
            None,
            "neither the session nor the step has one: send it, or send detections instead",
        )
    depth = _check_shape("buffer_image", step.buffer_depth_mm, calibration)
    image = buffer_image(depth, calibration, config.sensor.buffer_pixel_mm)
    container = config.container
    grid = size_quanta(config.size_prior, container.cell_xy_mm, container.cell_z_mm)
    found = measure_boxes(image, config.sensor, grid)
    boxes = tuple(
        MeasuredBox(i, e.size_mm, PickPose(*e.top_centre_mm, yaw_deg=e.yaw_deg))
        for i, e in enumerate(found.boxes)
    )
    return boxes, found.dropped


def _check_shape(name: str, depth: np.ndarray | None, calibration: Calibration) -> np.ndarray:
    """``depth`` when its shape is the one the camera's intrinsics give."""
    if depth is None or tuple(depth.shape) != calibration.image_shape:
        raise CellInputError(
            f"{name}.shape",
            None if depth is None else list(depth.shape),
            f"the camera's intrinsics say [height, width] = {list(calibration.image_shape)}",
        )
    return depth


def _check_boxes(config: CellConfig, step: StepInput, boxes: tuple[MeasuredBox, ...]) -> None:
    """Refuse a buffer the policy cannot act on: empty, detections over the session's buffer
    size, a detection that fits the container in no rotation, or fewer boxes to come than are
    shown. What packlab measured itself in a buffer image is not the cell's error where it is
    more segments than the buffer holds (a box cut in two) or a segment too large (boxes
    touching, merged into one): the segments are listed, as the simulated robot lists them,
    and the policy sets one aside or places another box."""
    source = "detections" if step.detections is not None else "buffer_image"
    if not boxes:
        seen = "no box-like segment found" if source == "buffer_image" else "an empty list"
        raise CellInputError(source, 0, f"{seen}: the buffer must show at least one box")
    # A box cut in two by the segmentation is listed twice, as the simulated robot lists it.
    most = MAX_BOXES if source == "buffer_image" else min(config.buffer_size, MAX_BOXES)
    if len(boxes) > most:
        raise CellInputError(
            source, len(boxes), f"more boxes than the session's buffer_size {config.buffer_size}"
        )
    x, y, z = config.container.size_mm
    for box in boxes:
        l, w, h = box.size_mm
        if min(l, w, h) <= 0:
            where = f"{source}[{box.index}].size_mm"
            raise CellInputError(where, list(box.size_mm), "sides must be > 0")
        if source == "buffer_image":
            continue
        if h > z or not ((l <= x and w <= y) or (w <= x and l <= y)):
            raise CellInputError(
                f"{source}[{box.index}].size_mm",
                list(box.size_mm),
                f"larger than the container {x} x {y} x {z} mm in either rotation",
            )
    if step.remaining is not None and step.remaining < len(boxes):
        raise CellInputError(
            "remaining", step.remaining, f"fewer than the {len(boxes)} boxes in the buffer"
        )


def _placement(
    config: CellConfig, heightmap: np.ndarray, box: MeasuredBox, action: Action | Unparsable
) -> Placement:
    """The target pose and the place skill's approach for a valid placement of ``box``."""
    assert isinstance(action, Action)  # judge() let it through
    rotation, x, y = int(action.rotation), int(action.x), int(action.y)
    item = ShownItem(
        0, "chosen", box.size_mm, size_cells(box.size_mm, config.container, MEASURED_SIDE_SLACK_MM)
    )
    fx, fy = believed_footprint(item, rotation)
    bottom = placement_height(heightmap, x, y, fx, fy)
    cell = config.container.cell_xy_mm
    drop = (x * cell, y * cell, bottom)
    skill = _skill(config, heightmap, drop, (fx, fy))
    command = place_command(box.size_mm, rotation, drop, heightmap, skill)
    top = command.bottom_mm + command.height_mm
    return Placement(
        rotation=rotation,
        cell=(x, y),
        footprint_mm=command.footprint_mm,
        bottom_z_mm=command.bottom_mm,
        target_mm=(*command.centre_mm, top),
        yaw_deg=90.0 * rotation,
        approach=approach(command),
    )


def _skill(
    config: CellConfig, heightmap: np.ndarray, drop: tuple[int, int, int], cells: tuple[int, int]
) -> ExecutedDrop:
    """The skill's settings for this drop, with no noise: the robot's side of
    ``packlab.sim.placement.robot_drop`` (the seat sides read from the observed heightmap)."""
    noise = config.execution
    sides, full = (0, 0), (True, True)
    if noise.seat_mm > 0:
        x, y = drop[0] // config.container.cell_xy_mm, drop[1] // config.container.cell_xy_mm
        sides = skill_seat_sides(heightmap, x, y, cells, drop[2])
        full = full_faces(heightmap, x, y, cells, drop[2], sides)
    return ExecutedDrop(
        (0.0, 0.0),
        0.0,
        noise.release_mm,
        noise.comply_mm,
        noise.seat_mm,
        seat_sides=sides,
        full_faces=full,
        set_aside_stuck=noise.set_aside_stuck,
    )


def approach(command: PlaceCommand) -> Approach:
    """The skill's path for ``command``: down from ``APPROACH_MM`` over the highest point seen
    to the release pose, guarded, then the seating pushes, then release."""
    x, y = command.centre_mm
    start = command.seen_top_mm + APPROACH_MM + command.height_mm
    release = command.bottom_mm + command.release_mm + command.height_mm
    return Approach(
        start_mm=(x, y, max(start, release)),
        release_mm=(x, y, release),
        release_height_mm=command.release_mm,
        comply_mm=command.comply_mm,
        seat_sides=command.seat_sides,
        seat_reach_mm=command.seat_mm,
        full_faces=command.full_faces,
        retries=PLACE_RETRIES,
        set_aside_if_stuck=command.set_aside_stuck,
    )


__all__ = [
    "Approach",
    "CellConfig",
    "Detection",
    "MeasuredBox",
    "PickPose",
    "Placement",
    "SessionState",
    "SetAsideReason",
    "StepAnswer",
    "StepInput",
    "Timings",
    "approach",
    "cell_start",
    "judge",
    "open_session",
    "plan_step",
    "shown_items",
]
