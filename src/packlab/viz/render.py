"""3D pictures of packings from final poses: boxes coloured by type, the container as an outline.

Poses come from bench records (``EpisodeOk.final_poses``: centre in mm and quaternion wxyz by
str(internal id); ``None`` for objects set aside). Every box is drawn where it settled, rotation
included, so a toppled box looks toppled; a box whose centre left the container is outlined in red.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

from packlab.core.records import EpisodeOk, FinalPose, MetricsRecord, StepRecord
from packlab.core.types import Case, Container
from packlab.metrics import box_inside
from packlab.sim.heightmap import quat_to_matrix
from packlab.sim.raster import height_colour, heightmap_to_rgb
from packlab.viz.labels import display_name
from packlab.viz.options import EPISODE_MAX_STEPS

#: Type colours (type_id modulo the list): soft, distinguishable, legible with black edges.
TYPE_COLOURS = [
    "#8DB3E2",
    "#F4A582",
    "#A6D96A",
    "#C2A5CF",
    "#FFD966",
    "#80CDC1",
    "#F1B6DA",
    "#BABABA",
    "#E6AB02",
    "#66C2A5",
    "#FC8D62",
    "#B3B3E6",
]
_UNIT = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
#: Corner indices of the six faces of a box (corners ordered as in _UNIT).
_FACES = ((0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5))


def type_colour(type_id: int) -> str:
    return TYPE_COLOURS[int(type_id) % len(TYPE_COLOURS)]


def box_corners(
    size_mm: Sequence[float], position_mm: Sequence[float], quaternion: Sequence[float]
) -> np.ndarray:
    """(8, 3) corners in mm of a box of ``size_mm`` (its own l, w, h) at a pose."""
    local = _UNIT * np.asarray(size_mm, dtype=float)
    return local @ quat_to_matrix(quaternion).T + np.asarray(position_mm, dtype=float)


#: Camera of every packing picture (degrees); the painter's order below depends on it.
ELEVATION, AZIMUTH = 26.0, -58.0


def _view_direction() -> np.ndarray:
    """Unit vector from the scene towards the camera (matplotlib's elev/azim convention)."""
    e, a = np.radians(ELEVATION), np.radians(AZIMUTH)
    return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def _container_edges(c: Container) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(back edges, front edges): back ones are drawn under the boxes, front ones over them."""
    x, y, z = c.size_mm
    pts = np.array(
        [[a, b, h] for h in (0, z) for a, b in ((0, 0), (x, 0), (x, y), (0, y))], dtype=float
    )
    edges = [(i, (i + 1) % 4) for i in range(4)] + [(4 + i, 4 + (i + 1) % 4) for i in range(4)]
    edges += [(i, i + 4) for i in range(4)]
    view, centre = _view_direction(), pts.mean(axis=0)
    segs = [pts[[a, b]] for a, b in edges]
    # An edge is at the back when it is farther from the camera than the container's centre.
    back = [s for s in segs if (s.mean(axis=0) - centre) @ view < -1e-9]
    front = [s for s in segs if (s.mean(axis=0) - centre) @ view >= -1e-9]
    return back, front


def painter_order(corners: list[np.ndarray]) -> list[int]:
    """Indices of boxes from back to front, for drawing each box over those behind it.

    mplot3d sorts polygons by their mean depth, which paints faces of neighbouring boxes in the
    wrong order; packings are boxes side by side, where a *separating axis* decides the order:
    if A lies entirely on the far side of B along x, y or z (as seen from the camera), A goes
    first. That partial order is completed by a topological sort, ties and any cycle (possible
    between tilted boxes) broken by the depth of the box centres.
    """
    n = len(corners)
    view = _view_direction()
    lo = [c.min(axis=0) for c in corners]
    hi = [c.max(axis=0) for c in corners]
    depth = [float(c.mean(axis=0) @ view) for c in corners]
    tol = 0.5  # mm: touching boxes are separated
    behind = [[False] * n for _ in range(n)]
    for a in range(n):
        for b in range(n):
            if a == b:
                continue
            for k in range(3):
                # Camera on the + side of axis k: the box at smaller k is farther, and vice versa.
                if (view[k] > 0 and hi[a][k] <= lo[b][k] + tol) or (
                    view[k] < 0 and lo[a][k] >= hi[b][k] - tol
                ):
                    behind[a][b] = True
    remaining, order = set(range(n)), []
    while remaining:
        free = [i for i in remaining if not any(behind[j][i] for j in remaining if j != i)]
        pick = min(free or remaining, key=lambda i: depth[i])
        order.append(pick)
        remaining.remove(pick)
    return order


def draw_packing(
    ax: Any, case: Case, poses: Mapping[str, FinalPose | None], title: str = "", zoom: float = 0.92
) -> int:
    """Draw a case's boxes at ``poses`` (record form, keyed by str(internal_id)) on a 3D axis.

    Returns the number of boxes drawn (set-aside boxes have no pose and are not drawn).
    """
    c = case.container
    view = _view_direction()
    boxes = []
    for box in case.objects:
        pose = poses.get(str(box.internal_id))
        if pose is not None:
            corners = box_corners(box.size_mm, pose.position_mm, pose.quaternion)
            boxes.append((box, corners, box_inside(pose.position_mm, c)))
    # Our own drawing order (see painter_order) instead of mplot3d's per-polygon depth sort.
    ax.computed_zorder = False
    floor = np.array(
        [[0, 0, 0], [c.size_mm[0], 0, 0], [c.size_mm[0], c.size_mm[1], 0], [0, c.size_mm[1], 0]],
        float,
    )
    ax.add_collection3d(
        Poly3DCollection([floor], facecolors="#EEEEEE", edgecolors="none", alpha=0.7)
    )
    back, front = _container_edges(c)
    ax.add_collection3d(Line3DCollection(back, colors="#999999", linewidths=0.8))
    for i in painter_order([b[1] for b in boxes]):
        box, corners, inside = boxes[i]
        faces = sorted(
            (corners[list(f)] for f in _FACES), key=lambda q: float(q.mean(axis=0) @ view)
        )
        ax.add_collection3d(
            Poly3DCollection(
                faces,
                facecolors=type_colour(box.type_id),
                edgecolors="#222222" if inside else "#D62728",
                linewidths=0.5 if inside else 1.1,
                alpha=1.0,
            )
        )
    ax.add_collection3d(Line3DCollection(front, colors="#333333", linewidths=1.1))
    # Limits: the container, widened to take in boxes that fell outside it.
    lo, hi = np.zeros(3), np.asarray(c.size_mm, dtype=float)
    if boxes:
        pts = np.concatenate([b[1] for b in boxes])
        lo, hi = np.minimum(lo, pts.min(axis=0)), np.maximum(hi, pts.max(axis=0))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(0, hi[2])
    ax.set_box_aspect(tuple(np.maximum(hi - np.array([lo[0], lo[1], 0]), 1.0)), zoom=zoom)
    ax.view_init(elev=ELEVATION, azim=AZIMUTH)
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=10, pad=0)
    return len(boxes)


def scores_text(metrics: MetricsRecord) -> str:
    return (
        f"SR {metrics.success_ratio:.3f} · C {metrics.compactness:.3f} · "
        f"Overall {metrics.overall:.3f}"
    )


def packing_comparison_figure(
    case: Case, entries: Sequence[tuple[str, EpisodeOk]], seed: int | None = None, columns: int = 4
) -> Figure:
    """Side by side: each method's final packing of one case, titled with its three scores."""
    n = max(1, len(entries))
    cols = min(columns, n)
    rows = -(-n // cols)
    fig = Figure(figsize=(3.6 * cols, 3.5 * rows + 0.5))
    for i, (policy, record) in enumerate(entries):
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        m = record.metrics
        aside = f" · {m.n_set_aside} set aside" if m.n_set_aside else ""
        title = f"{display_name(policy)}\n{scores_text(m)}{aside}"
        draw_packing(ax, case, record.final_poses, title)
    x, y, z = (v / 10 for v in case.container.size_mm)
    seed_txt = f", seed {seed}" if seed is not None else ""
    fig.suptitle(
        f"{case.episode_id} ({case.difficulty}, {len(case.objects)} objects, "
        f"buffer {case.buffer_size}, "
        f"container {x:g}x{y:g}x{z:g} cm{seed_txt})",
        fontsize=12,
    )
    fig.subplots_adjust(left=0.01, right=0.99, bottom=0.01, top=0.9, wspace=0.02, hspace=0.12)
    return fig


def _step_label(step: StepRecord) -> str:
    a = step.action
    if isinstance(a.unparsable, str):
        return f"{step.step}: unparsable"
    head = f"{step.step}: #{step.internal_id} r{a.rotation} ({a.x},{a.y})"
    return head if step.valid else f"{step.step}: {step.reason}"


def _crop_background(rgb: np.ndarray) -> np.ndarray:
    """Cut the raster's uniform margin (its top-left pixel colour) so tiles show only the map."""
    keep = (rgb != rgb[0, 0]).any(axis=2)
    rows, cols = np.flatnonzero(keep.any(axis=1)), np.flatnonzero(keep.any(axis=0))
    if rows.size == 0:
        return rgb
    return rgb[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]


def _height_scale(ax: Any, container: Container) -> None:
    """A horizontal colour bar of the raster's fixed height scale, floor to rim, then above."""
    rim = container.height_mm
    heights = np.linspace(0, rim * 1.08, 256)
    strip = np.array([[height_colour(int(h), container) for h in heights]], dtype=np.uint8)
    ax.imshow(strip, aspect="auto", extent=(0, heights[-1] / 10, 0, 1))
    ax.set_yticks([])
    ticks = [0, rim / 20, rim / 10]
    ax.set_xticks(ticks)
    ax.set_xticklabels(["floor", f"{rim / 20:g}", f"rim {rim / 10:g} cm"], fontsize=8)
    ax.set_title("heightmap colour: height (cm); red = above the rim", fontsize=8, pad=3)


def episode_figure(
    case: Case,
    record: EpisodeOk,
    heightmaps: Sequence[np.ndarray],
    max_steps: int = EPISODE_MAX_STEPS,
) -> Figure:
    """One episode: the final packing (left) and the heightmap after each step (right grid).

    Heightmaps use ``packlab.sim.raster``'s fixed colour scale (the picture the VLM reads), so
    colours compare across steps; each tile is titled with the step's action.
    """
    steps = list(record.steps)[:max_steps]
    n = len(steps)
    cols = int(np.ceil(np.sqrt(n * 1.6))) if n else 1
    rows = max(1, -(-n // cols))
    tile = 1.55
    left_w = 5.6
    fig = Figure(figsize=(left_w + tile * cols, max(4.8, tile * 1.12 * rows + 1.0)))
    outer = fig.add_gridspec(1, 2, width_ratios=[left_w, tile * cols], wspace=0.04)
    left = outer[0, 0].subgridspec(2, 1, height_ratios=[14, 1], hspace=0.25)
    ax3d = fig.add_subplot(left[0, 0], projection="3d")
    draw_packing(ax3d, case, record.final_poses, scores_text(record.metrics), zoom=0.82)
    _height_scale(fig.add_subplot(left[1, 0]), case.container)
    tiles = outer[0, 1].subgridspec(rows, cols, wspace=0.08, hspace=0.35)
    for i, (step, hm) in enumerate(zip(steps, heightmaps)):
        ax = fig.add_subplot(tiles[i // cols, i % cols])
        ax.imshow(
            _crop_background(heightmap_to_rgb(hm, case.container, size=160, major_every=5)),
            interpolation="nearest",
        )
        ax.set_title(
            _step_label(step), fontsize=7, color="black" if step.valid else "#D62728", pad=2
        )
        ax.set_xticks([])
        ax.set_yticks([])
        for spine in ax.spines.values():
            spine.set_visible(False)
    more = (
        f" (first {max_steps} of {len(record.steps)} steps)"
        if len(record.steps) > max_steps
        else ""
    )
    fig.suptitle(
        f"{display_name(record.policy)} on {case.episode_id} "
        f"({case.difficulty}, {len(case.objects)} "
        f"objects), seed {record.seed}, {record.backend}{more}\n"
        f"tiles: heightmap after each step (x right, y down), titled step: #object rotation (x, y)",
        fontsize=10,
    )
    return fig


__all__ = [
    "TYPE_COLOURS",
    "box_corners",
    "draw_packing",
    "episode_figure",
    "packing_comparison_figure",
    "scores_text",
    "type_colour",
]
