"""The size prior of perception: ``grid`` snaps the estimates to the container's grids (the
default, every case's sizes before off-grid cartons), ``none`` reports them in whole mm."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core.choices import DEFAULT_SIZE_PRIOR
from packlab.core.errors import ConfigError
from packlab.core.types import Container
from packlab.sim.modes import episode_modes
from packlab.sim.sensing import perceive_state
from packlab.sim.sensing.perception import size_quanta

CONTAINER = Container((500, 500, 400))
#: Cartons off the grid: no side a multiple of 25 mm, heights odd.
OFF_GRID = np.array([[262, 143, 97], [188, 111, 53], [340, 215, 141]])
EMPTY = np.zeros((0, 3))


def _sizes(prior: str | None, preset: str = "structured-light", seed: int = 0) -> np.ndarray:
    kwargs = {} if prior is None else {"size_prior": prior}
    state = perceive_state(
        CONTAINER,
        EMPTY,
        EMPTY,
        np.zeros((0, 4)),
        OFF_GRID,
        preset,
        np.random.default_rng(seed),
        **kwargs,
    )
    assert not state.missed
    # Listed in the segments' order: row j is the buffered box a pick at it takes.
    order = np.argsort(state.picks)
    return np.asarray(state.shown_sizes_mm)[order]


def test_the_quanta_of_each_prior():
    assert DEFAULT_SIZE_PRIOR == "grid"
    assert size_quanta("grid", 25, 2) == (25, 2)
    assert size_quanta("none", 25, 2) == (1, 1)
    with pytest.raises(ValueError, match="size_prior = 'cm'"):
        size_quanta("cm", 25, 2)  # type: ignore[arg-type]


@pytest.mark.parametrize("preset", ["none", "structured-light", "stereo"])
def test_the_grid_prior_snaps_and_no_prior_keeps_the_cartons_sizes(preset):
    truth = np.column_stack(
        [OFF_GRID[:, :2].max(axis=1), OFF_GRID[:, :2].min(axis=1), OFF_GRID[:, 2]]
    )
    for seed in range(3):
        grid = _sizes("grid", preset, seed)
        assert (grid[:, :2] % 25 == 0).all() and (grid[:, 2] % 2 == 0).all()
        raw = _sizes("none", preset, seed)
        # Each estimate within 2 mm of the truth: the 2 mm pixels, not the 25 mm grid.
        assert np.abs(raw - truth).max() <= 2, (raw, truth)
        assert np.abs(grid - truth).max() >= 7  # snapping moved a side at least 7 mm
        assert (raw[:, :2] % 25 != 0).any()


def test_the_default_is_the_grid_prior():
    """Leaving the prior out gives the grid prior's sizes, draw for draw."""
    for seed in range(3):
        np.testing.assert_array_equal(_sizes(None, seed=seed), _sizes("grid", seed=seed))


def test_episode_modes_carry_the_prior_and_refuse_an_unknown_one():
    assert episode_modes("perceived").perceiver.size_prior == "grid"
    assert episode_modes("perceived", size_prior="none").perceiver.size_prior == "none"
    with pytest.raises(ConfigError, match="size_prior = 'mm': unknown"):
        episode_modes("perceived", size_prior="mm")  # type: ignore[arg-type]
