"""Figures of a data set's distributions (``packlab inspect-data --plots``).

The data engine collects the numbers (``packlab.datagen.stats``) and hands them here as plain
series by group (difficulty), since viz sits below datagen and knows none of its types. Figures
are built on ``matplotlib.figure.Figure`` directly (no pyplot state, no GUI backend).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure


def histogram_figure(title: str, series: Mapping[str, Sequence[float]], bins: int = 30) -> Figure:
    """Overlaid histograms, one per group (``""``: unlabelled); empty groups are left out."""
    fig = Figure(figsize=(6, 3.5))
    ax = fig.subplots()
    for name, values in series.items():
        if len(values):
            ax.hist(values, bins=bins, alpha=0.55, label=name or "unlabelled")
    ax.set_title(title)
    if ax.get_legend_handles_labels()[0]:  # nothing drawn: no empty legend box
        ax.legend()
    fig.tight_layout()
    return fig


def cell_scatter_figure(title: str, points: Mapping[str, np.ndarray]) -> Figure:
    """Scatter of fractional grid positions (n, 2) in [0, 1] per group, y down like heightmaps."""
    fig = Figure(figsize=(4, 4))
    ax = fig.subplots()
    for name, xy in points.items():
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if xy.size:
            ax.scatter(xy[:, 0], xy[:, 1], s=6, alpha=0.5, label=name or "unlabelled")
    ax.set_xlim(0, 1)
    ax.set_ylim(1, 0)  # y down, like the heightmap images
    ax.set_title(title)
    if ax.get_legend_handles_labels()[0]:  # nothing drawn: no empty legend box
        ax.legend()
    fig.tight_layout()
    return fig


__all__ = ["cell_scatter_figure", "histogram_figure"]
