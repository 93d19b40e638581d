"""Draw an episode's frames into a Rerun recording (rerun-sdk, the ``viewer`` extra).

rerun is imported only when a logger is made (:func:`rerun_module`), so packlab imports and
runs without the extra. What a recording holds (lengths in metres, one ``step`` timeline whose
value is the step index; step i shows the buffer step i chose from, its action, and the state
after it):

==========================  =======================================================================
entity                      content
==========================  =======================================================================
``world``                   right-handed, z up (static)
``world/container``         the container as a wire box (static)
``world/boxes/<id>``        one entity per box of the case: a solid box at its settled pose,
                            logged when it is placed and again whenever it moves; a box set aside
                            (invalid step) stands red on a shelf beside the container (+x side)
``world/buffer``            the shown buffer in shown order on a row in front of the container
                            (y < 0; shrunk to the container's length if longer), labelled
                            ``#index id``, the chosen one in orange
``world/target``            the chosen placement's footprint and drop height (wire box); cleared
                            on an invalid step
``heightmap/image``         the heightmap after the step as the VLM sees it (``sim.raster``; PNG)
``heightmap/tensor``        the same heightmap as an int32 tensor (x, y) in mm
``timing/policy_ms``        the policy's decision time of the step (live episodes); replays of
                            records show ``timing/policy_ms_mean`` (records keep only the total)
``timing/step_ms``          the environment's wall time of the step (placement and settle)
``episode/max_height_mm``   the heightmap's maximum after the step
``log``                     one text line per step: action, validity or reason, latency
``buffer``                  the shown buffer as a table (markdown)
``case``, ``summary``       the case and run (static); final scores on the last step
==========================  =======================================================================
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

from packlab.core.errors import ConfigError
from packlab.core.types import Action, Case, Container, ShownItem
from packlab.metrics import EpisodeMetrics
from packlab.sim.episode import StepResult
from packlab.sim.raster import DEFAULT_SIZE as IMAGE_SIZE
from packlab.sim.raster import heightmap_to_image
from packlab.viz.episode_frames import RECORDED_POSES, Frame, Replay
from packlab.viz.render import type_colour

if TYPE_CHECKING:
    import rerun as rr

INSTALL_HINT = "pip install 'packlab[viewer]' (rerun-sdk)"
MM = 1e-3  # metres per millimetre: the viewer's lengths are metres
SET_ASIDE_RGB = (214, 39, 40)
CHOSEN_RGB = (255, 127, 14)
CONTAINER_RGB = (90, 90, 90)
#: A box counts as moved (and is logged again) past these changes of centre and quaternion.
MOVED_MM, MOVED_QUAT = 0.1, 1e-4


def rerun_module() -> ModuleType:
    """The rerun package, or a ConfigError saying how to install it."""
    try:
        import rerun
    except ImportError:
        raise ConfigError(f"the Rerun export needs rerun-sdk: {INSTALL_HINT}") from None
    return rerun


def blueprint(rr: ModuleType, container: Container) -> Any:
    """The layout a viewer opens with: the 3D scene left (looking at the container from the
    front right, where the buffer row and the set-aside shelf are), heightmap, timings, text."""
    rrb = rr.blueprint
    x, y, z = (v * MM for v in container.size_mm)
    far = max(x, y, z)
    eye = rrb.EyeControls3D(
        position=[x / 2 + 1.3 * far, y / 2 - 1.8 * far, 1.5 * far],
        look_target=[x / 2, y / 2 - 0.2 * far, 0.2 * z],
        eye_up=[0.0, 0.0, 1.0],
    )
    # The heightmap tensor drawn like the image: x along columns, y along rows.
    tensor_axes = rrb.TensorSliceSelection(width=0, height=1)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="packing", eye_controls=eye),
            rrb.Vertical(
                rrb.Horizontal(
                    rrb.Spatial2DView(
                        origin="heightmap/image",
                        name="heightmap",
                        visual_bounds=rrb.VisualBounds2D(
                            x_range=[0, IMAGE_SIZE], y_range=[0, IMAGE_SIZE]
                        ),
                    ),
                    rrb.TensorView(
                        origin="heightmap/tensor",
                        name="heightmap (mm)",
                        slice_selection=tensor_axes,
                        view_fit="FillKeepAspectRatio",
                    ),
                ),
                rrb.TimeSeriesView(origin="timing", name="timing (ms)"),
                rrb.Tabs(
                    rrb.TextLogView(origin="log", name="steps"),
                    rrb.TextDocumentView(origin="buffer", name="buffer"),
                    rrb.TextDocumentView(origin="summary", name="summary"),
                    rrb.TextDocumentView(origin="case", name="case"),
                ),
                row_shares=[2, 1, 1],
            ),
            column_shares=[3, 2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        # Two steps a second when played: each step is one placement worth looking at.
        rrb.TimePanel(state="expanded", timeline="step", fps=2.0),
    )


# -- geometry ----------------------------------------------------------------------------------


def rgb(hex_colour: str) -> tuple[int, int, int]:
    """``"#8DB3E2"`` -> (141, 179, 226)."""
    h = hex_colour.lstrip("#")
    return int(h[0:2], 16), int(h[2:4], 16), int(h[4:6], 16)


def heightmap_png(heightmap: np.ndarray, container: Container) -> bytes:
    """The heightmap image as a palette PNG: a few kB a step where raw RGB takes 150 kB."""
    buffer = io.BytesIO()
    heightmap_to_image(heightmap, container, mode="P").save(buffer, format="PNG")
    return buffer.getvalue()


def xyzw(quaternion_wxyz: np.ndarray) -> list[float]:
    """A packlab quaternion (w, x, y, z) in rerun's order (x, y, z, w)."""
    w, x, y, z = (float(v) for v in quaternion_wxyz)
    return [x, y, z, w]


def gap_mm(case: Case) -> float:
    """Space between the container and the buffer row or the set-aside shelf."""
    return max(50.0, case.container.size_mm[0] / 20)


def buffer_row(case: Case, shown: tuple[ShownItem, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(centres, half sizes), (k, 3) mm: the shown items at rotation 0 in a row along x in
    front of the container (y < 0), in shown order; shrunk to the container's length when the
    row would be longer (a buffer of 10 large boxes would otherwise fill the view)."""
    gap = gap_mm(case)
    sizes = np.array([s.size_mm for s in shown], dtype=float).reshape(-1, 3)
    length = sizes[:, 0].sum() + gap / 2 * max(len(shown) - 1, 0)
    scale = min(1.0, case.container.size_mm[0] / length) if length else 1.0
    sizes *= scale
    starts = np.concatenate([[0.0], np.cumsum(sizes[:, 0] + gap / 2 * scale)[:-1]])
    centres = np.stack(
        [starts + sizes[:, 0] / 2, -gap - sizes[:, 1] / 2, sizes[:, 2] / 2], axis=1
    ).reshape(-1, 3)
    return centres, sizes / 2


# -- the logger --------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class EpisodeInfo:
    """What the recording is of (shown in the ``case`` document)."""

    case: Case
    policy: str
    seed: int
    backend: str
    source: str  # "live" or the records file a replay came from


class EpisodeLogger:
    """Logs one episode's frames to an open recording, one ``step`` per frame."""

    def __init__(self, stream: rr.RecordingStream, info: EpisodeInfo) -> None:
        self.rr = rerun_module()
        self.stream = stream
        self.info = info
        case = info.case
        self._index = {b.internal_id: i for i, b in enumerate(case.objects)}
        self._logged: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # index -> (centre, quat)
        self._shelf_y = 0.0  # next free y (mm) on the set-aside shelf
        self.frames = 0

    def log_case(self) -> None:
        """The static part: axes, the container, and the case and run as text."""
        rr, info = self.rr, self.info
        c = info.case.container
        self.stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.stream.log(
            "world/container",
            rr.Boxes3D(
                centers=[[v * MM / 2 for v in c.size_mm]],
                half_sizes=[[v * MM / 2 for v in c.size_mm]],
                colors=[CONTAINER_RGB],
                labels=[info.case.episode_id],
                fill_mode="MajorWireframe",
            ),
            static=True,
        )
        text = rr.TextDocument(case_markdown(info), media_type="text/markdown")
        self.stream.log("case", text, static=True)

    def log_frame(self, frame: Frame) -> None:
        """One step: boxes that moved, buffer, target, heightmap, timings and a log line."""
        rr, step = self.rr, frame.step
        self.stream.set_time("step", sequence=step.step_index)
        self._log_boxes(step)
        self._log_buffer(step)
        self._log_target(step)
        hm = frame.heightmap
        png = heightmap_png(hm, self.info.case.container)
        self.stream.log("heightmap/image", rr.EncodedImage(contents=png, media_type="image/png"))
        self.stream.log("heightmap/tensor", rr.Tensor(hm, dim_names=["x", "y"]))
        self.stream.log("episode/max_height_mm", rr.Scalars(float(hm.max(initial=0))))
        self.stream.log("timing/step_ms", rr.Scalars(step.wall_time_s * 1e3))
        if frame.policy_s is not None:
            self.stream.log("timing/policy_ms", rr.Scalars(frame.policy_s * 1e3))
        level = "INFO" if step.valid else "WARN"
        self.stream.log("log", rr.TextLog(step_line(self.info.case, frame), level=level))
        self.frames += 1

    def log_mean_policy_ms(self, step_index: int, mean_s: float) -> None:
        """A replay's policy time per decision (records keep no per-step latency)."""
        self.stream.set_time("step", sequence=step_index)
        self.stream.log("timing/policy_ms_mean", self.rr.Scalars(mean_s * 1e3))

    def log_summary(self, text: str) -> None:
        """The final scores (markdown), at the current step."""
        self.stream.log("summary", self.rr.TextDocument(text, media_type="text/markdown"))

    def _log_boxes(self, step: StepResult) -> None:
        rr, case = self.rr, self.info.case
        if not step.valid:
            self._set_aside(self._index[step.internal_id])
        for i, box in enumerate(case.objects):
            centre, quat = step.positions_mm[i], step.quaternions[i]
            if np.isnan(centre).any() or not self._moved(i, centre, quat):
                continue
            self._logged[i] = (centre.copy(), quat.copy())
            self.stream.log(
                f"world/boxes/{box_path(box.internal_id)}",
                rr.Boxes3D(
                    centers=[centre * MM],
                    half_sizes=[[v * MM / 2 for v in box.size_mm]],
                    quaternions=[rr.Quaternion(xyzw=xyzw(quat))],
                    colors=[rgb(type_colour(box.type_id))],
                    labels=[str(box.internal_id)],
                    fill_mode="Solid",
                ),
            )

    def _moved(self, i: int, centre: np.ndarray, quat: np.ndarray) -> bool:
        if i not in self._logged:
            return True
        old_centre, old_quat = self._logged[i]
        # q and -q are the same rotation.
        dq = min(np.abs(quat - old_quat).max(), np.abs(quat + old_quat).max())
        return bool(np.linalg.norm(centre - old_centre) > MOVED_MM or dq > MOVED_QUAT)

    def _set_aside(self, i: int) -> None:
        """Stand an object set aside by an invalid step on the shelf beside the container."""
        rr, case = self.rr, self.info.case
        box = case.objects[i]
        l, w, h = box.size_mm
        centre = (case.container.size_mm[0] + gap_mm(case) + l / 2, self._shelf_y + w / 2, h / 2)
        self._shelf_y += w + gap_mm(case) / 2
        self.stream.log(
            f"world/boxes/{box_path(box.internal_id)}",
            rr.Boxes3D(
                centers=[[v * MM for v in centre]],
                half_sizes=[[v * MM / 2 for v in box.size_mm]],
                colors=[SET_ASIDE_RGB],
                labels=[f"{box.internal_id} (set aside)"],
                fill_mode="Solid",
            ),
        )

    def _log_buffer(self, step: StepResult) -> None:
        rr = self.rr
        centres, halves = buffer_row(self.info.case, step.shown)
        chosen = step.action.object_id if isinstance(step.action, Action) else None
        colours = [
            CHOSEN_RGB if s.shown_index == chosen else rgb(type_colour(s.type_id))
            for s in step.shown
        ]
        labels = [f"#{s.shown_index} {s.internal_id}" for s in step.shown]
        self.stream.log(
            "world/buffer",
            rr.Boxes3D(
                centers=centres * MM,
                half_sizes=halves * MM,
                colors=colours,
                labels=labels,
                fill_mode="Solid",
            ),
        )
        text = rr.TextDocument(buffer_markdown(step), media_type="text/markdown")
        self.stream.log("buffer", text)

    def _log_target(self, step: StepResult) -> None:
        rr, case = self.rr, self.info.case
        if step.drop_mm is None or not isinstance(step.action, Action):
            self.stream.log("world/target", rr.Clear(recursive=False))
            return
        box = case.objects[self._index[step.internal_id]]
        fx, fy = box.footprint_mm(int(step.action.rotation))
        x, y, z = step.drop_mm
        h = box.size_mm[2]
        self.stream.log(
            "world/target",
            rr.Boxes3D(
                centers=[[(x + fx / 2) * MM, (y + fy / 2) * MM, (z + h / 2) * MM]],
                half_sizes=[[fx * MM / 2, fy * MM / 2, h * MM / 2]],
                colors=[CHOSEN_RGB],
                fill_mode="MajorWireframe",
            ),
        )


# -- text --------------------------------------------------------------------------------------


def box_path(internal_id: object) -> str:
    """An internal id as one entity path part (reference ids are strings like ``obj_00000``)."""
    return rerun_module().escape_entity_path_part(str(internal_id))


def case_markdown(info: EpisodeInfo) -> str:
    case = info.case
    x, y, z = (v / 10 for v in case.container.size_mm)
    return "\n".join(
        [
            f"# {case.episode_id}",
            "",
            f"- policy: **{info.policy}**, run seed {info.seed}, backend {info.backend}",
            f"- source: {info.source}",
            (
                f"- difficulty: {case.difficulty or '-'}, buffer {case.buffer_size}, "
                f"{len(case.objects)} objects"
            ),
            f"- container: {x:g} x {y:g} x {z:g} cm, cell {case.container.cell_xy_mm} mm",
        ]
    )


def buffer_markdown(step: StepResult) -> str:
    chosen = step.action.object_id if isinstance(step.action, Action) else None
    rows = [
        f"Step {step.step_index}: the buffer shown to the policy",
        "",
        "| # | id | size (cm) | cells | chosen |",
        "|---|----|-----------|-------|--------|",
    ]
    for s in step.shown:
        size = " x ".join(f"{v:g}" for v in s.size_cm)
        cells = " x ".join(map(str, s.size_cells))
        rows.append(
            f"| {s.shown_index} | {s.internal_id} | {size} | {cells} | "
            f"{'yes' if s.shown_index == chosen else ''} |"
        )
    return "\n".join(rows)


def step_line(case: Case, frame: Frame) -> str:
    """One line: what the policy chose and what came of it."""
    step = frame.step
    latency = "" if frame.policy_s is None else f"; policy {frame.policy_s * 1e3:.1f} ms"
    a = step.action
    if not step.valid:
        what = f"{a.to_dict()}" if isinstance(a, Action) else f"unparsable {a.text[:80]!r}"
        return (
            f"step {step.step_index}: invalid ({step.reason}): {what}; "
            f"object {step.internal_id} set aside{latency}"
        )
    assert isinstance(a, Action) and step.drop_mm is not None
    box = case.box_by_id(step.internal_id)
    size = "x".join(str(v) for v in box.size_mm)
    settled = "" if step.settled else "; still moving (settle cap)"
    return (
        f"step {step.step_index}: #{a.object_id} = object {step.internal_id} ({size} mm), "
        f"rotation {a.rotation}, cell ({a.x}, {a.y}), drop z {step.drop_mm[2]} mm{settled}{latency}"
    )


def metrics_markdown(metrics: EpisodeMetrics, recorded: Any = None, note: str = "") -> str:
    """Final scores; with ``recorded`` (a record's MetricsRecord), the recorded ones beside."""
    names = ("overall", "success_ratio", "compactness")
    head = "| metric | this episode |" + (" recorded |" if recorded is not None else "")
    rows = ["# Final scores", "", head, "|---|---|" + ("---|" if recorded is not None else "")]
    for k in names:
        row = f"| {k} | {getattr(metrics, k):.4f} |"
        if recorded is not None:
            row += f" {float(getattr(recorded, k)):.4f} |"
        rows.append(row)
    rows += [
        "",
        (
            f"- inside: {metrics.n_inside} of {metrics.n_objects} objects, "
            f"set aside: {metrics.n_set_aside}, max height {metrics.max_height_mm} mm"
        ),
        (
            f"- invalid steps: {dict(metrics.invalid_by_reason) or 'none'}, "
            f"unsettled steps: {metrics.unsettled_steps}, at rest: {metrics.at_rest}"
        ),
    ]
    if note:
        rows += ["", note]
    return "\n".join(rows)


def replay_note(replay: Replay) -> str:
    """What a replay shows, in a sentence or two for the summary."""
    if replay.method == RECORDED_POSES:
        return (
            "Boxes at the poses the record logged after each step (to 0.5 mm); heightmaps "
            "rasterised from them. No engine was run."
        )
    error = replay.max_pose_error_mm
    distance = "n/a" if math.isnan(error) else f"{error:.3g} mm"
    if replay.exact:
        return (
            "The record has no per-step poses: its actions were stepped again on its backend, "
            "which reproduced the recorded steps, scores and final poses."
        )
    return (
        "The record has no per-step poses: its actions were stepped again on its backend, and "
        f"the result differs from the record (largest final-pose difference {distance}): the "
        "engine or its settings differ from the run's. The boxes show the re-simulation; the "
        "recorded scores are beside."
    )


__all__ = [
    "INSTALL_HINT",
    "EpisodeInfo",
    "EpisodeLogger",
    "blueprint",
    "box_path",
    "metrics_markdown",
    "replay_note",
    "rerun_module",
    "step_line",
]
