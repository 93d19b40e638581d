"""Between the wire (``packlab.cell.schema``) and the planning step (``packlab.cell.step``):
requests to configs and decoded arrays, answers back to their models."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from packlab.cell import schema
from packlab.cell.errors import CellInputError
from packlab.cell.geometry import (
    Calibration,
    Orthographic,
    Pinhole,
    pose_from_matrix,
    pose_from_quaternion,
)
from packlab.cell.images import decode_depth
from packlab.cell.limits import MAX_CELLS, MAX_TRANSLATION_MM
from packlab.cell.step import (
    CellConfig,
    Detection,
    MeasuredBox,
    PickPose,
    Placement,
    StepAnswer,
    StepInput,
)
from packlab.core.types import Action, Container, Unparsable
from packlab.sim.execution import EXECUTION_PRESETS
from packlab.sim.sensing.presets import sensor_preset


def cell_config(request: schema.SessionRequest, default_policy: str) -> CellConfig:
    """The step's config of a session request (CellInputError for what the schema cannot
    check alone: a pose that is not rigid, a grid with no cell or too many)."""
    container = _container(request.container)
    preset = request.sensing.preset
    # "perfect" is the sensor's alias of "none"; the robot's settings go by the same names.
    execution = EXECUTION_PRESETS["none" if preset == "perfect" else preset]
    return CellConfig(
        container=container,
        buffer_size=request.buffer_size,
        container_camera=calibration(request.container_camera, "container_camera"),
        buffer_camera=None
        if request.buffer_camera is None
        else calibration(request.buffer_camera, "buffer_camera"),
        sensor=sensor_preset(preset),
        execution=execution,
        policy=request.policy or default_policy,
        policy_options=dict(request.policy_options),
        seed=request.seed,
        size_prior=request.sensing.size_prior,
    )


def _container(spec: schema.ContainerSpec) -> Container:
    size = tuple(round(v) for v in spec.size_mm)
    container = Container((size[0], size[1], size[2]), spec.cell_mm, spec.height_step_mm)
    nx, ny = container.cells
    if min(nx, ny) < 1 or nx * ny > MAX_CELLS:
        raise CellInputError(
            "container.size_mm",
            list(spec.size_mm),
            f"{nx} x {ny} cells of {spec.cell_mm} mm: need 1 to {MAX_CELLS} cells",
        )
    return container


def calibration(camera: schema.Camera, field: str) -> Calibration:
    """A camera's ``Calibration``; the pose must be rigid and within the translation limit."""
    i = camera.intrinsics
    intrinsics: Pinhole | Orthographic = (
        Pinhole(i.fx, i.fy, i.cx, i.cy, i.width, i.height)
        if isinstance(i, schema.PinholeIntrinsics)
        else Orthographic(i.pixel_mm, i.width, i.height, i.cx, i.cy)
    )
    pose = camera.pose
    if pose.matrix is not None:
        rotation, translation = pose_from_matrix(np.asarray(pose.matrix), f"{field}.pose.matrix")
    else:
        assert pose.translation_mm is not None and pose.quaternion_wxyz is not None  # the schema
        rotation, translation = pose_from_quaternion(
            np.asarray(pose.translation_mm),
            np.asarray(pose.quaternion_wxyz),
            f"{field}.pose.quaternion_wxyz",
        )
    if np.abs(translation).max() > MAX_TRANSLATION_MM:
        raise CellInputError(
            f"{field}.pose", translation.tolist(), f"translation beyond {MAX_TRANSLATION_MM:g} mm"
        )
    return Calibration(intrinsics, rotation, translation)


def step_input(request: schema.StepImages) -> tuple[StepInput, float]:
    """(the decoded step, ms spent decoding); a ``StepRequest``'s cameras join it."""
    started = time.perf_counter()
    container = _depth("container_image", request.container_image)
    buffer = None if request.buffer_image is None else _depth("buffer_image", request.buffer_image)
    detections = None
    if request.detections is not None:
        detections = tuple(_detection(d) for d in request.detections)
    decoded = StepInput(container, buffer, detections, request.remaining)
    if isinstance(request, schema.StepRequest):
        decoded = replace(
            decoded,
            container_camera=_moved(request.container_camera, "container_camera"),
            buffer_camera=_moved(request.buffer_camera, "buffer_camera"),
        )
    return decoded, 1e3 * (time.perf_counter() - started)


def _moved(camera: schema.Camera | None, field: str) -> Calibration | None:
    return None if camera is None else calibration(camera, field)


def _depth(field: str, image: schema.DepthImage) -> np.ndarray:
    return decode_depth(field, image.encoding, image.data, image.shape, image.scale_mm)


def _detection(detection: schema.Detection) -> Detection:
    l, w, h = (round(v) for v in detection.size_mm)
    pick = detection.pick
    return Detection(
        (l, w, h), None if pick is None else PickPose(pick.x_mm, pick.y_mm, pick.z_mm, pick.yaw_deg)
    )


def answer_model(answer: StepAnswer, session_id: str | None, decode_ms: float) -> schema.StepAnswer:
    """The wire form of a step's answer; ``decode_ms`` joins its timings (and their total)."""
    t = answer.timings
    heightmap = answer.heightmap
    return schema.StepAnswer(
        session_id=session_id,
        step_index=answer.step_index,
        decision=answer.decision,
        reason=answer.reason,
        box=_box(answer.box),
        placement=None if answer.placement is None else _placement(answer.placement),
        boxes=[_box(b) for b in answer.boxes],
        action=_action(answer.action),
        dropped_segments=answer.dropped_segments,
        heightmap=schema.Heightmap(
            cells=(int(heightmap.shape[0]), int(heightmap.shape[1])),
            cell_mm=answer.cell_mm,
            values_mm=heightmap.astype(int).tolist(),
            unseen_cells=answer.unseen_cells,
        ),
        timings_ms=schema.Timings(
            decode=decode_ms,
            heightmap=t.heightmap_ms,
            segmentation=t.segmentation_ms,
            policy=t.policy_ms,
            total=t.total_ms + decode_ms,
        ),
    )


def _action(action: Action | Unparsable) -> schema.PolicyAction | None:
    if isinstance(action, Unparsable):
        return None
    fields = (action.object_id, action.rotation, action.x, action.y)
    if not all(isinstance(v, (int, np.integer)) for v in fields):
        return None  # not a whole-number answer: the judge already named it
    object_id, rotation, x, y = (int(v) for v in fields)
    return schema.PolicyAction(object_id=object_id, rotation=rotation, x=x, y=y)


def _box(box: MeasuredBox) -> schema.Box:
    pick = box.pick
    return schema.Box(
        index=box.index,
        size_mm=box.size_mm,
        pick=None
        if pick is None
        else schema.MeasuredPick(
            x_mm=pick.x_mm, y_mm=pick.y_mm, z_mm=pick.z_mm, yaw_deg=pick.yaw_deg
        ),
    )


def _placement(placement: Placement) -> schema.PlacementPlan:
    a = placement.approach
    x, y, z = placement.target_mm
    return schema.PlacementPlan(
        rotation=placement.rotation,
        cell=placement.cell,
        footprint_mm=placement.footprint_mm,
        bottom_z_mm=placement.bottom_z_mm,
        target=schema.Target(x_mm=x, y_mm=y, z_mm=z, yaw_deg=placement.yaw_deg),
        approach=schema.ApproachPlan(
            start_mm=a.start_mm,
            release_mm=a.release_mm,
            release_height_mm=a.release_height_mm,
            comply_mm=a.comply_mm,
            seat_sides=a.seat_sides,
            seat_reach_mm=a.seat_reach_mm,
            full_faces=a.full_faces,
            retries=a.retries,
            set_aside_if_stuck=a.set_aside_if_stuck,
        ),
    )


__all__ = ["answer_model", "calibration", "cell_config", "step_input"]
