"""The numeric vector of one listed placement: its own geometry and its level fit (pure).

A learned policy that picks among listed placements (the candidate-mode VLM's pointer head, the
probes in ``benchmarks/``) reads each line's numbers directly as well as through text: a model
trained from random weights learns a comparison of run lengths and box sides far faster from a
float than from digits. One function builds the vector for every such reader, so they cannot
drift apart.

Columns (:data:`LINE_VECTOR_NAMES`): the placement's geometry as the listed line shows it
(position and far corner as shares of the container, footprint area share, box height, resting
height and top in container heights, support, flushness, mean void, rotation), then
:func:`packlab.policies.level_fit.level_fit`'s columns.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from packlab.core.types import Observation
from packlab.policies.candidates import Candidate
from packlab.policies.level_fit import FEATURE_NAMES, level_fit_rows

GEOMETRY_NAMES = (
    "x0", "y0", "x1", "y1", "area", "height", "z", "top", "support", "flush", "void", "rotation",
)  # fmt: skip
LINE_VECTOR_NAMES = GEOMETRY_NAMES + FEATURE_NAMES
LINE_VECTOR_SIZE = len(LINE_VECTOR_NAMES)


def geometry(observation: Observation, c: Candidate) -> np.ndarray:
    """(len(GEOMETRY_NAMES),) float32: a listed placement's own geometry, scaled."""
    nx, ny = observation.container.cells
    rim = float(observation.container.height_mm)
    h = observation.shown[c.object_index].size_mm[2]
    row = [
        c.x / nx, c.y / ny, (c.x + c.fx) / nx, (c.y + c.fy) / ny, c.fx * c.fy / (nx * ny),
        h / rim, c.z_mm / rim, c.top_mm / rim,
        c.support_pct / 100, c.flush_pct / 100, c.void_mm / rim, float(c.rotation),
    ]  # fmt: skip
    return np.asarray(row, dtype=np.float32)


def line_vectors(observation: Observation, listed: Sequence[Candidate]) -> np.ndarray:
    """(len(listed), LINE_VECTOR_SIZE) float32, one row per listed placement."""
    if not listed:
        return np.zeros((0, LINE_VECTOR_SIZE), dtype=np.float32)
    geometries = np.stack([geometry(observation, c) for c in listed])
    fits = level_fit_rows(observation.heightmap, observation.shown, listed)
    return np.concatenate([geometries, fits], axis=1).astype(np.float32, copy=False)
