"""Level-fit features on hand-made heightmaps whose answers are known."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core.types import ShownItem
from packlab.policies.candidates import Candidate
from packlab.policies.level_fit import (
    FEATURE_NAMES,
    N_FEATURES,
    RUN_SCALE,
    level_fit,
    level_fit_rows,
)


def _shown(*sizes):
    """Shown boxes of (l, w, h) cells; 1 cell = 25 mm, heights in mm."""
    return tuple(
        ShownItem(i, i, (l * 25, w * 25, h), (l, w, -(-h // 20)), 0)
        for i, (l, w, h) in enumerate(sizes)
    )


def _at(shown, obj, x, y, z=0, rotation=0):
    l, w = shown[obj].size_cells[:2]
    fx, fy = (l, w) if rotation == 0 else (w, l)
    return Candidate(0, obj, rotation, x, y, fx, fy, z, z + shown[obj].size_mm[2], 100, 0, 0)


def _feature(row, name):
    return float(row[FEATURE_NAMES.index(name)])


def test_runs_and_exact_strips_on_an_empty_floor():
    hm = np.zeros((10, 6), dtype=np.int32)
    shown = _shown((4, 6, 100), (6, 3, 100), (3, 3, 200))
    row = level_fit(hm, shown, _at(shown, 0, 0, 0))  # 4 x 6 in the corner: a 6 x 6 strip left
    assert row.shape == (N_FEATURES,)
    assert _feature(row, "run_x_near") * RUN_SCALE == 6 == _feature(row, "run_x_far") * RUN_SCALE
    assert _feature(row, "run_y_near") == 0 and _feature(row, "run_x_back") == 0
    assert _feature(row, "fits_x_near") == 1  # 6 = box 1's length (same height)
    assert _feature(row, "region") == pytest.approx(36 / 60)
    assert _feature(row, "same_area") == pytest.approx(18 / 36)
    assert _feature(row, "closes") == 0  # 18 cells of same-height boxes cannot make 36
    assert _feature(row, "same_count") == pytest.approx(0.1)
    assert _feature(row, "lowest") == 1


def test_a_strip_no_same_height_box_closes():
    hm = np.zeros((10, 6), dtype=np.int32)
    shown = _shown((5, 6, 100), (4, 3, 100), (5, 3, 200))
    row = level_fit(hm, shown, _at(shown, 0, 0, 0))  # leaves 5 cells: box 2 has 5 but is taller
    assert _feature(row, "fits_x_near") == 0


def test_closing_a_pocket_and_ending_level_with_the_neighbours():
    hm = np.full((8, 8), 100, dtype=np.int32)
    hm[2:6, 2:5] = 0  # a 4 x 3 pocket, 100 mm deep
    shown = _shown((4, 3, 100), (2, 2, 100))
    row = level_fit(hm, shown, _at(shown, 0, 2, 2))
    assert _feature(row, "region") == 0 and _feature(row, "closes") == 1
    assert _feature(row, "level_with") == 1  # its top meets the pocket's rim everywhere
    assert _feature(row, "run_x_near") == 0 and _feature(row, "run_y_far") == 0
    partial = level_fit(hm, shown, _at(shown, 1, 2, 2))  # 2 x 2 in the pocket: 8 cells left
    assert _feature(partial, "closes") == 0 and _feature(partial, "region") * 64 == 8


def test_rows_stack_per_listed_placement():
    hm = np.zeros((6, 6), dtype=np.int32)
    shown = _shown((3, 3, 100), (3, 6, 100))
    listed = [_at(shown, 0, 0, 0), _at(shown, 1, 3, 0)]
    rows = level_fit_rows(hm, shown, listed)
    assert rows.shape == (2, N_FEATURES) and rows.dtype == np.float32
    assert np.array_equal(rows[1], level_fit(hm, shown, listed[1]))
    assert level_fit_rows(hm, shown, []).shape == (0, N_FEATURES)


def test_line_vectors_join_geometry_and_level_fit():
    from packlab.core.types import Container, Observation
    from packlab.policies.line_vector import LINE_VECTOR_SIZE, geometry, line_vectors

    hm = np.zeros((6, 6), dtype=np.int32)
    shown = _shown((3, 3, 100), (3, 6, 100))
    obs = Observation(0, Container((150, 150, 500), 25, 2), hm, shown, remaining=2)
    listed = [_at(shown, 0, 0, 0), _at(shown, 1, 3, 0)]
    rows = line_vectors(obs, listed)
    assert rows.shape == (2, LINE_VECTOR_SIZE)
    assert np.array_equal(rows[1, : len(geometry(obs, listed[1]))], geometry(obs, listed[1]))
    assert np.array_equal(rows[1, -N_FEATURES:], level_fit(hm, shown, listed[1]))
    assert rows[1, 2] == pytest.approx(1.0)  # the second box reaches the far x wall


def _region_by_search(hm, c, tol=4):
    """Free cells at or below z's level connected (4-neighbours) to the box's ring, the box's
    own cells excluded: a plain breadth-first search, independent of the labelling."""
    nx, ny = hm.shape
    inside = {(i, j) for i in range(c.x, c.x + c.fx) for j in range(c.y, c.y + c.fy)}

    def free(i, j):
        return 0 <= i < nx and 0 <= j < ny and (i, j) not in inside and hm[i, j] <= c.z_mm + tol

    steps = ((1, 0), (-1, 0), (0, 1), (0, -1))
    todo = [(i + di, j + dj) for i, j in inside for di, dj in steps if free(i + di, j + dj)]
    seen = set(todo)
    while todo:
        i, j = todo.pop()
        for di, dj in steps:
            n = (i + di, j + dj)
            if n not in seen and free(*n):
                seen.add(n)
                todo.append(n)
    return len(seen)


@pytest.mark.parametrize("seed", range(20))
def test_region_matches_a_search_and_shared_levels_change_nothing(seed):
    """``region`` from the state's shared labelling equals a breadth-first search, at Eq. 2's
    height and at a z below the footprint's top (read without the shortcut), and a row made with
    the state's :class:`Levels` equals one made alone."""
    from packlab.core.feasibility import footprint_max
    from packlab.policies.level_fit import Levels

    rng = np.random.default_rng(seed)
    nx, ny = (int(v) for v in rng.integers(4, 14, size=2))
    hm = rng.choice([0, 0, 0, 100, 102, 200], size=(nx, ny)).astype(np.int32)
    shown = _shown(*[(int(rng.integers(1, 4)), int(rng.integers(1, 4)), 100) for _ in range(4)])
    levels = Levels(hm)
    for obj in range(4):
        c = _at(shown, obj, int(rng.integers(0, nx - 3)), int(rng.integers(0, ny - 3)))
        z = int(footprint_max(hm, c.fx, c.fy)[c.x, c.y])
        for at in (z, z - 100):
            placed = _at(shown, obj, c.x, c.y, z=at)
            row = level_fit(hm, shown, placed, levels)
            assert _feature(row, "region") * nx * ny == pytest.approx(_region_by_search(hm, placed))
            assert np.array_equal(row, level_fit(hm, shown, placed))
