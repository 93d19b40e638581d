"""The perception figure of one step: container depth image, recovered vs true heightmap, and
the segmented buffer image with its estimated boxes (``packlab.sim.sensing``).

Built on ``matplotlib.figure.Figure`` directly (no pyplot state); save with
``packlab.viz.plots.save_figure``.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Polygon

from packlab.sim.sensing import EstimatedBox, PerceivedState


def _box_outline(estimate: EstimatedBox, sized_mm: tuple[float, float]) -> np.ndarray:
    """(4, 2) world xy corners of an estimated box's footprint of the given (l, w)."""
    yaw = np.radians(estimate.yaw_deg)
    axes = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])
    half = np.array(sized_mm) / 2.0
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
    return corners @ axes + np.asarray(estimate.top_centre_mm[:2])


def _image(ax, data: np.ndarray, extent, title: str, cmap: str, label: str, fig: Figure):
    """One panel: an (x, y) array drawn with x to the right and y up, with a colour bar."""
    x0, y0, x1, y1 = extent
    shown = ax.imshow(data.T, origin="lower", extent=(x0, x1, y0, y1), cmap=cmap)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x (mm)", fontsize=8)
    ax.set_ylabel("y (mm)", fontsize=8)
    ax.tick_params(labelsize=7)
    fig.colorbar(shown, ax=ax, shrink=0.8).set_label(label, fontsize=8)


def _buffer_panel(ax, state: PerceivedState) -> None:
    """The buffer: its depth image, the segments (tint) and each estimated box outlined."""
    image, labels = state.buffer.image, state.buffer.labels
    nx, ny = image.shape
    x0, y0 = image.origin_mm
    x1, y1 = x0 + nx * image.pixel_mm, y0 + ny * image.pixel_mm
    ax.set_facecolor("#EEEEEE")
    heights = np.ma.masked_invalid(image.heights_mm())
    top = float(heights.max()) if heights.count() else 1.0
    window = (x0, x1, y0, y1)
    ax.imshow(heights.T, origin="lower", extent=window, cmap="Greys", vmin=0, vmax=top)
    tint = np.ma.masked_where(labels < 0, labels % 10)
    ax.imshow(tint.T, origin="lower", extent=window, cmap="tab10", alpha=0.35, vmin=0, vmax=9)
    for estimate in state.buffer.found:
        outline = _box_outline(estimate, estimate.size_mm[:2])
        ax.add_patch(Polygon(outline, closed=True, fill=False, edgecolor="#D62728", lw=1.2))
        l, w, h = estimate.size_mm
        ax.text(
            *estimate.top_centre_mm[:2],
            f"{l}x{w}x{h}\n{estimate.yaw_deg:.1f}°",
            fontsize=6,
            ha="center",
            va="center",
            color="#FFD700",
        )
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    missed = state.stats.missed
    ax.set_title(
        f"buffer: segments (tint), estimated boxes (red); {state.stats.scans} scan(s)"
        + (f", {missed} missed" if missed else ""),
        fontsize=9,
    )
    ax.tick_params(labelsize=7)


def perception_figure(state: PerceivedState, true_heightmap: np.ndarray, title: str = "") -> Figure:
    """Four panels: depth image, recovered heightmap, true heightmap, segmented buffer."""
    fig = Figure(figsize=(15, 4.2), layout="constrained")
    axes = fig.subplots(1, 4, gridspec_kw={"width_ratios": [1, 1, 1, 1.3]})
    image = state.container_image
    nx, ny = image.shape
    extent = (
        *image.origin_mm,
        image.origin_mm[0] + nx * image.pixel_mm,
        image.origin_mm[1] + ny * image.pixel_mm,
    )
    depth = np.ma.masked_invalid(image.depth_mm)
    _image(axes[0], depth, extent, "container depth (missing: white)", "viridis_r", "depth mm", fig)
    cells_extent = (0, 0, extent[2], extent[3])
    vmax = float(max(true_heightmap.max(initial=0), state.heightmap.max(initial=0), 1))
    for ax, data, name in (
        (axes[1], state.heightmap, "perceived"),
        (axes[2], true_heightmap, "true"),
    ):
        _image(ax, data, cells_extent, f"{name} heightmap", "magma", "height mm", fig)
        ax.images[0].set_clim(0, vmax)
    _buffer_panel(axes[3], state)
    stats = state.stats
    fig.suptitle(
        f"{title}  heightmap MAE {stats.heightmap_mae_mm:.2f} mm, dims error max "
        f"{np.nanmax(stats.dims_error_mm, initial=0):.0f} mm, yaw error max "
        f"{np.nanmax(stats.yaw_error_deg, initial=0):.2f}°",
        fontsize=10,
    )
    return fig
