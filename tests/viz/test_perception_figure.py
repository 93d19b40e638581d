"""The perception figure draws every panel and writes a PNG."""

from __future__ import annotations

import numpy as np

from packlab.core.types import Container
from packlab.sim.heightmap import rasterise_poses
from packlab.sim.sensing import perceive_state
from packlab.viz.perception import perception_figure
from packlab.viz.plots import save_figure


def test_perception_figure_has_its_panels_and_saves(tmp_path):
    container = Container((300, 200, 300))
    sizes = np.array([[100, 100, 60], [150, 50, 40]], dtype=float)
    positions = np.array([[50.0, 50.0, 30.0], [225.0, 100.0, 20.0]])
    quats = np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0]])
    shown = np.array([[100, 75, 50], [200, 100, 80]])
    state = perceive_state(
        container, sizes, positions, quats, shown, "stereo", np.random.default_rng(0)
    )
    exact = rasterise_poses(container.cells, 25, sizes, positions, quats)
    fig = perception_figure(state, exact, "test")
    titles = [ax.get_title() for ax in fig.axes]
    assert "perceived heightmap" in titles and "true heightmap" in titles
    buffer_ax = next(ax for ax in fig.axes if ax.get_title().startswith("buffer:"))
    assert len(buffer_ax.patches) == len(shown)  # one estimated box outline per shown object
    path = save_figure(fig, tmp_path / "perception.png")
    assert path.stat().st_size > 10_000
