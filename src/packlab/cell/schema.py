"""The cell service's requests and answers (pydantic; FastAPI writes the OpenAPI schema from
them, ``packlab cell schema``). Lengths in mm, angles in degrees, frames as docs/cell.md draws
them. Requests refuse unknown fields (a misspelt field is an error, not a silent default) and
non-finite numbers."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from packlab.cell.limits import (
    MAX_BOXES,
    MAX_CONTAINER_SIDE_MM,
    MAX_IMAGE_BASE64_CHARS,
    MAX_IMAGE_SIDE,
    MAX_TRANSLATION_MM,
)
from packlab.core.choices import SizePrior
from packlab.core.types import DEFAULT_CELL_XY_MM, DEFAULT_CELL_Z_MM

#: The sensing presets a session may name (``packlab.sim.sensing.presets``).
PresetName = Literal["none", "perfect", "structured-light", "stereo"]

Side = Annotated[int, Field(ge=1, le=MAX_IMAGE_SIDE)]
Coordinate = Annotated[float, Field(ge=-MAX_TRANSLATION_MM, le=MAX_TRANSLATION_MM)]
Length = Annotated[float, Field(gt=0, le=MAX_CONTAINER_SIDE_MM)]
PixelCentre = Annotated[float, Field(ge=-1e6, le=1e6)]
Focal = Annotated[float, Field(ge=1, le=1e6)]
Angle = Annotated[float, Field(ge=-360, le=360)]
Seed = Annotated[int, Field(ge=0, lt=2**63)]
Row = tuple[Coordinate, Coordinate, Coordinate, Coordinate]
Unit = Annotated[float, Field(ge=-1.5, le=1.5)]


class Request(BaseModel):
    """A request body's parts: unknown fields and NaN / infinite numbers are refused."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Answer(BaseModel):
    """An answer's parts."""

    model_config = ConfigDict(extra="forbid")


# -- requests ----------------------------------------------------------------------------------


class PinholeIntrinsics(Request):
    """A pinhole camera (OpenCV's camera matrix): pixel (v, u) at depth d is the camera-frame
    point ((u - cx) d / fx, (v - cy) d / fy, d)."""

    model: Literal["pinhole"]
    fx: Focal
    fy: Focal
    cx: PixelCentre
    cy: PixelCentre
    width: Side
    height: Side


class OrthographicIntrinsics(Request):
    """An orthographic camera (a virtual top-down view, packlab's simulated cameras): pixel
    (v, u) at depth d is ((u - cx) pixel_mm, (v - cy) pixel_mm, d)."""

    model: Literal["orthographic"]
    pixel_mm: Annotated[float, Field(gt=0, le=1000)]
    width: Side
    height: Side
    cx: PixelCentre | None = Field(default=None, description="default: (width - 1) / 2")
    cy: PixelCentre | None = Field(default=None, description="default: (height - 1) / 2")


Intrinsics = Annotated[PinholeIntrinsics | OrthographicIntrinsics, Field(discriminator="model")]


class Pose(Request):
    """The camera-to-frame transform, p_frame = R p_camera + t: a 4 x 4 ``matrix``, or a
    ``translation_mm`` and a unit ``quaternion_wxyz`` (w first)."""

    matrix: tuple[Row, Row, Row, Row] | None = Field(
        default=None, description="4 x 4, row-major, translation in mm"
    )
    translation_mm: tuple[Coordinate, Coordinate, Coordinate] | None = None
    quaternion_wxyz: tuple[Unit, Unit, Unit, Unit] | None = None

    @model_validator(mode="after")
    def _one_form(self) -> Pose:
        quaternion = (self.translation_mm, self.quaternion_wxyz)
        if self.matrix is None and None in quaternion:
            raise ValueError("give matrix, or translation_mm and quaternion_wxyz")
        if self.matrix is not None and quaternion != (None, None):
            raise ValueError("give matrix or translation_mm + quaternion_wxyz, not both")
        return self


class Camera(Request):
    """One depth camera: intrinsics and its pose in the frame it looks at."""

    intrinsics: Intrinsics
    pose: Pose


class ContainerSpec(Request):
    """The container: inner size and the heightmap's grid."""

    size_mm: tuple[Length, Length, Length] = Field(description="inner X, Y, height")
    cell_mm: int = Field(
        default=DEFAULT_CELL_XY_MM, ge=1, le=1000, description="heightmap cell side"
    )
    height_step_mm: int = Field(
        default=DEFAULT_CELL_Z_MM, ge=1, le=100, description="box heights' grid"
    )


class Sensing(Request):
    """What the perception assumes of the cameras (``packlab.sim.sensing.presets``): their
    noise sets the segmentation's thresholds and the heightmap's flat-top tolerance, and the
    place skill's settings (approach, slides, seating) are the preset's robot's."""

    preset: PresetName = "structured-light"
    size_prior: SizePrior = Field(
        default="grid",
        description="grid: measured sizes snap to the container's cell (l, w) and height step "
        "(h), for cartons made on that grid; none: the measured sizes in whole mm",
    )


class SessionRequest(Request):
    """Open a session for one container (``POST /v1/sessions``)."""

    container: ContainerSpec
    buffer_size: int = Field(ge=1, le=MAX_BOXES, description="boxes the buffer shows at most")
    container_camera: Camera
    buffer_camera: Camera | None = Field(default=None, description="needed to send buffer images")
    sensing: Sensing = Sensing()
    policy: str | None = Field(default=None, max_length=100, description="default: the server's")
    policy_options: dict[str, str | int | float | bool] = Field(default_factory=dict, max_length=32)
    seed: Seed = 0


class DepthImage(Request):
    """A depth image in mm, base64: ``f32`` (little-endian float32) or ``u16`` (little-endian
    uint16, times ``scale_mm``), row-major [height, width]; or ``png16``, a 16-bit greyscale
    PNG. 0 marks a pixel without depth."""

    encoding: Literal["f32", "u16", "png16"]
    shape: tuple[Side, Side] | None = Field(
        default=None, description="[height, width]; png16: optional"
    )
    data: str = Field(max_length=MAX_IMAGE_BASE64_CHARS)
    scale_mm: float = Field(default=1.0, gt=0, le=1000, description="u16 and png16: mm per count")


class PickPose(Request):
    """A box's top-face centre on the buffer and the yaw of its first side (l), buffer frame."""

    x_mm: Coordinate
    y_mm: Coordinate
    z_mm: Coordinate
    yaw_deg: Angle


class Detection(Request):
    """A box the cell measured itself."""

    size_mm: tuple[Length, Length, Length] = Field(description="l, w, h")
    pick: PickPose | None = None


class StepImages(Request):
    """What one step sees: the container image, and the buffer as an image (packlab segments
    and measures the boxes) or as the cell's own detections (exactly one of the two)."""

    container_image: DepthImage
    buffer_image: DepthImage | None = None
    detections: list[Detection] | None = Field(default=None, max_length=MAX_BOXES)
    remaining: int | None = Field(
        default=None, ge=1, le=1_000_000, description="boxes still to pack, shown ones included"
    )


class StepRequest(StepImages):
    """One step of a session (``POST /v1/sessions/{id}/step``). A camera that moves (on the
    arm, or re-framed to the boxes it sees) sends its calibration with the step."""

    container_camera: Camera | None = Field(
        default=None,
        description="this step's container camera, when it moved (default: the session's)",
    )
    buffer_camera: Camera | None = Field(
        default=None,
        description="this step's buffer camera, when it moved (default: the session's)",
    )


class PlanRequest(SessionRequest, StepImages):
    """A session's opening and its one step in a single request (``POST /v1/plan``)."""


# -- answers -----------------------------------------------------------------------------------


class SessionOpened(Answer):
    session_id: str
    policy: str
    heightmap_cells: tuple[int, int] = Field(description="x cells, y cells")
    idle_timeout_s: float = Field(description="closed after idling this long")


class MeasuredPick(Answer):
    x_mm: float
    y_mm: float
    z_mm: float
    yaw_deg: float


class Box(Answer):
    """A box on the buffer as packlab took it; ``index`` is its place in ``boxes`` (the
    detections' order, or the segments' in the image)."""

    index: int
    size_mm: tuple[int, int, int] = Field(description="l, w, h; rotation 0 puts l along x")
    pick: MeasuredPick | None = Field(
        default=None, description="top-face centre and yaw, buffer frame"
    )


class Target(Answer):
    """The box's top-face centre at rest and its yaw, container frame."""

    x_mm: float
    y_mm: float
    z_mm: float
    yaw_deg: float


class ApproachPlan(Answer):
    """How the place skill puts the box down: positions of the held box's top-face centre."""

    start_mm: tuple[float, float, float] = Field(description="the guarded descent starts here")
    release_mm: tuple[float, float, float] = Field(description="the gripper opens here")
    release_height_mm: float = Field(description="bottom over its rest height when let go")
    comply_mm: float = Field(description="how far contacts may slide the box on the way down")
    seat_sides: tuple[int, int] = Field(description="per axis x, y: side pushed flush (-1/0/+1)")
    seat_reach_mm: float = Field(description="how far past the target a guarded push may go")
    full_faces: tuple[bool, bool] = Field(description="per axis: the seat side is a whole face")
    retries: int = Field(description="descents tried again from above when one stops high")
    set_aside_if_stuck: bool


class PlacementPlan(Answer):
    rotation: int = Field(description="0: l along x; 1: l along y")
    cell: tuple[int, int] = Field(description="the footprint's minimum heightmap cell")
    footprint_mm: tuple[float, float]
    bottom_z_mm: float = Field(description="rest height of the bottom: heightmap max under it")
    target: Target
    approach: ApproachPlan


class PolicyAction(Answer):
    """The policy's own answer, as it gave it: ``object_id`` indexes ``boxes``; x = y = -1 sets
    that box aside on purpose."""

    object_id: int
    rotation: int
    x: int = Field(description="the footprint's minimum cell along x")
    y: int = Field(description="the footprint's minimum cell along y")


class Heightmap(Answer):
    cells: tuple[int, int]
    cell_mm: int
    values_mm: list[list[int]] = Field(description="[x][y], top surface over each cell")
    unseen_cells: int = Field(description="cells no pixel saw; each took its nearest's height")


class Timings(Answer):
    """Milliseconds per stage of the step, in the server."""

    decode: float = Field(description="the request's images to arrays")
    heightmap: float = Field(description="container image to heightmap")
    segmentation: float = Field(description="buffer image to boxes (0 with detections)")
    policy: float = Field(description="the policy's decision")
    total: float = Field(description="all of the step, the stages above included")


class StepAnswer(Answer):
    session_id: str | None = Field(description="None for POST /v1/plan")
    step_index: int
    decision: Literal["place", "set_aside"]
    reason: str | None = Field(description="why set aside: the policy's choice or a bad answer")
    box: Box
    placement: PlacementPlan | None
    boxes: list[Box]
    action: PolicyAction | None = Field(
        default=None, description="the policy's own answer; None: it gave none that could be read"
    )
    dropped_segments: int = Field(description="buffer segments not box-like, left out")
    heightmap: Heightmap
    timings_ms: Timings


class Health(Answer):
    status: Literal["ok"]
    version: str
    sessions: int
    workers: int


class PolicyList(Answer):
    default: str
    policies: list[str]


class ErrorAnswer(Answer):
    error: str = Field(description="one line: the field, its value and what is wrong")


__all__ = [
    "ApproachPlan",
    "Box",
    "Camera",
    "ContainerSpec",
    "DepthImage",
    "Detection",
    "ErrorAnswer",
    "Health",
    "Heightmap",
    "MeasuredPick",
    "OrthographicIntrinsics",
    "PickPose",
    "PinholeIntrinsics",
    "PlacementPlan",
    "PlanRequest",
    "PolicyAction",
    "PolicyList",
    "Pose",
    "PresetName",
    "Sensing",
    "SessionOpened",
    "SessionRequest",
    "StepAnswer",
    "StepImages",
    "StepRequest",
    "Target",
    "Timings",
]
