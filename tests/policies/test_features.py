"""The shared placement features on hand-computed heightmaps, and their three forms agreeing."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core.feasibility import CandidateSet, search_candidates
from packlab.core.types import ShownItem
from packlab.policies import features as F
from packlab.policies.heuristics import mta

CELL = 25


def _item(i: int, fx: int, fy: int, h_mm: int, internal_id: int | None = None) -> ShownItem:
    iid = 100 + i if internal_id is None else internal_id
    return ShownItem(i, iid, (fx * CELL, fy * CELL, h_mm), (fx, fy, -(-h_mm // 2)))


def _cands(heights, shown, rim: int = 100) -> CandidateSet:
    return search_candidates(np.asarray(heights, dtype=np.int32), shown, rim, CELL)


def _at(c: CandidateSet, x: int, y: int, obj: int = 0, rotation: int = 0) -> int:
    hit = np.flatnonzero((c.obj == obj) & (c.rotation == rotation) & (c.x == x) & (c.y == y))
    assert hit.size == 1
    return int(hit[0])


# -- space under ------------------------------------------------------------------------------

PIT = [
    [50, 50, 50, 50],
    [50, 10, 30, 50],
    [50, 50, 50, 50],
    [50, 50, 50, 50],
]


@pytest.mark.parametrize(
    "fx, fy, x, y, expected",
    [
        (3, 3, 0, 0, 40 + 20),  # over the whole pit: (50 - 10) + (50 - 30)
        (3, 3, 1, 1, 40 + 20),
        (2, 2, 0, 0, 40),  # covers the 10 mm cell only
        (2, 2, 0, 2, 20),  # covers the 30 mm cell only
        (1, 2, 1, 1, 20),  # rests at 30 over the 10 mm cell
        (1, 1, 1, 1, 0),  # sits in the pit's bottom
        (2, 2, 2, 2, 0),  # on the flat part
    ],
)
def test_a_box_over_a_pit_has_exactly_the_space_under_it(fx, fy, x, y, expected) -> None:
    c = _cands(PIT, [_item(0, fx, fy, 40)], rim=200)
    i = _at(c, x, y)
    assert int(F.space_under(c)[i]) == expected
    assert F.space_under_at(c.heightmap, x, y, fx, fy, int(c.z[i])) == expected
    grid = F.space_under_grid(c.heightmap, fx, fy, c.groups[0].z)
    assert int(grid[x, y]) == expected


def test_space_under_on_the_empty_floor_is_zero_and_in_cell_mm() -> None:
    c = _cands(np.zeros((3, 4)), [_item(0, 2, 3, 40)])
    assert F.space_under(c).tolist() == [0] * len(c)
    # One 80 mm column under a 2 x 2 box elsewhere at 0: 3 cells x 80 mm trapped.
    hm = np.zeros((3, 3), dtype=np.int32)
    hm[0, 0] = 80
    assert F.space_under_at(hm, 0, 0, 2, 2, 80) == 3 * 80


# -- flushness ---------------------------------------------------------------------------------


def test_a_box_against_two_walls_has_its_hand_counted_flushness() -> None:
    # 4 x 5 cells, rim 100; a 2 x 2 box in the corner (0, 0) on the floor. Its 8 side cells:
    # the -x and -y walls (2 + 2, walls stand at the rim's 100 mm), at +x the 30 mm column
    # (2, 0) (above z = 0) and the empty (2, 1), at +y the empty (0, 2), (1, 2): 5 of 8.
    hm = np.zeros((4, 5), dtype=np.int32)
    hm[2, 0] = 30
    c = _cands(hm, [_item(0, 2, 2, 40)])
    i = _at(c, 0, 0)
    walls = F.walled(c.heightmap, c.container_height_mm)
    assert int(F.flush_cells(c)[i]) == 5
    assert F.flush_cells_at(walls, 0, 0, 2, 2, 0) == 5
    assert F.flush_share(c)[i] == pytest.approx(5 / 8)
    assert F.side_cells(2, 2) == 8
    # The opposite corner (2, 3): the +x and +y walls only (the floor around it is empty).
    assert int(F.flush_cells(c)[_at(c, 2, 3)]) == 4
    # At (1, 1) the 30 mm column (2, 0) is one of the -y side cells; at (1, 2), in the middle
    # of the floor, every side cell is empty floor: nothing is flush.
    assert int(F.flush_cells(c)[_at(c, 1, 1)]) == 1
    assert int(F.flush_cells(c)[_at(c, 1, 2)]) == 0


def test_flushness_counts_only_columns_strictly_above_z_and_walls_below_the_rim() -> None:
    # A 2 x 2 plinth at 40 mm in the corner, neighbours at +x of 30 (below) and 60 (above).
    hm = np.zeros((4, 4), dtype=np.int32)
    hm[0:2, 0:2] = 40
    hm[2, 0], hm[2, 1] = 30, 60
    hm[0, 2] = 40  # level with the box's underside: touches nothing
    c = _cands(hm, [_item(0, 2, 2, 20)], rim=100)
    i = _at(c, 0, 0)
    assert int(c.z[i]) == 40
    assert int(F.flush_cells(c)[i]) == 2 + 2 + 1
    # On a rim-high plinth the walls (at the rim) are no longer above z.
    hm[0:2, 0:2] = 100
    c = _cands(hm, [_item(0, 2, 2, 20)], rim=100)
    assert int(F.flush_cells(c)[_at(c, 0, 0)]) == 0


# -- support -----------------------------------------------------------------------------------

BUMP = [[20, 20, 20], [20, 24, 20], [20, 20, 20]]


@pytest.mark.parametrize(
    "fx, fy, tolerance, expected_cells",
    [
        (2, 2, 0, 1),  # rests on the 24 mm bump alone
        (2, 2, 3, 1),  # 20 mm cells are 4 mm lower: outside a 3 mm tolerance
        (2, 2, 4, 4),
        (3, 3, 0, 1),
        (3, 3, 4, 9),
        (1, 1, 0, 1),
    ],
)
def test_support_share_with_a_bump(fx, fy, tolerance, expected_cells) -> None:
    c = _cands(BUMP, [_item(0, fx, fy, 30)])
    i = _at(c, 0, 0)
    assert int(F.support_cells(c, tolerance)[i]) == expected_cells
    assert F.support_share(c, tolerance)[i] == pytest.approx(expected_cells / (fx * fy))
    z = int(c.z[i])
    assert F.support_cells_at(c.heightmap, 0, 0, fx, fy, z, tolerance) == expected_cells
    assert int(F.support_grid(c.heightmap, fx, fy, tolerance)[0, 0]) == expected_cells


def test_support_on_the_floor_is_every_cell() -> None:
    c = _cands(np.zeros((3, 3)), [_item(0, 2, 3, 30)])
    assert F.support_share(c).tolist() == [1.0] * len(c)


# -- contact area (MTA's measure, its earlier numbers) -----------------------------------------

POCKET = [[50, 50, 50], [0, 0, 50], [0, 0, 50]]


def test_contact_area_keeps_mtas_numbers_in_the_pocket() -> None:
    # MTA's hand-computed areas before the move (cm^2: 52.5, 58.75, 105.0, 52.5).
    c = _cands(POCKET, [_item(0, 2, 2, 40)])
    got = {(int(c.x[i]), int(c.y[i])): int(a) for i, a in enumerate(F.contact_area_mm2(c))}
    expected = {(0, 0): 5250, (0, 1): 5875, (1, 0): 10500, (1, 1): 5250}
    assert {k: got[k] for k in expected} == expected
    assert np.array_equal(mta.contact_area_mm2(c), F.contact_area_mm2(c))


def test_contact_area_clips_side_overlap_to_the_box_and_the_wall() -> None:
    # MTA's example: z = 30, top = 110; walls 70 mm each, the 200 column 80, the 50 column 20.
    c = _cands([[30, 50], [200, 0]], [_item(0, 1, 1, 80)], rim=100)
    assert int(F.contact_area_mm2(c)[_at(c, 0, 0)]) == 625 + (70 + 70 + 80 + 20) * 25


def test_contact_area_of_a_pit_and_of_the_floor_corner() -> None:
    c = _cands([[0], [0], [0], [150], [30], [150]], [_item(0, 1, 1, 50)], rim=200)
    area = F.contact_area_mm2(c)
    assert int(area[_at(c, 4, 0)]) == 625 + 4 * 50 * 25
    assert int(area[_at(c, 0, 0)]) == 625 + 3 * 50 * 25


# -- the forms agree, and agree with loops over cells -------------------------------------------


def _state(seed: int) -> tuple[np.ndarray, list[ShownItem], int]:
    rng = np.random.default_rng(seed)
    nx, ny = (int(v) for v in rng.integers(2, 10, size=2))
    hm = rng.choice([0, 0, 20, 22, 40, 60, 100], size=(nx, ny)).astype(np.int32)
    shown = [
        _item(i, int(rng.integers(1, 5)), int(rng.integers(1, 5)), 2 * int(rng.integers(5, 60)))
        for i in range(int(rng.integers(1, 5)))
    ]
    return hm, shown, int(rng.integers(40, 200))


def _column(hm: np.ndarray, rim: int, i: int, j: int) -> int:
    nx, ny = hm.shape
    return int(hm[i, j]) if 0 <= i < nx and 0 <= j < ny else rim


def _loop_features(hm, rim, x, y, fx, fy, h, tol=F.LEVEL_TOLERANCE_MM) -> tuple[int, ...]:
    """(space under, support, flush, contact mm^2), one cell and one edge at a time; support and
    flush with "the same level" spelled out as within ``tol`` mm."""
    z = max(int(hm[i, j]) for i in range(x, x + fx) for j in range(y, y + fy))
    space = support = flush = contact = 0
    for i in range(x, x + fx):
        for j in range(y, y + fy):
            space += z - int(hm[i, j])
            support += z - int(hm[i, j]) <= tol
            for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                ni, nj = i + di, j + dj
                if x <= ni < x + fx and y <= nj < y + fy:
                    continue
                column = _column(hm, rim, ni, nj)
                flush += column > z + tol
                contact += max(0, min(z + h, column) - z) * CELL
    return space, support, flush, contact + support * CELL * CELL


@pytest.mark.parametrize("seed", range(30))
def test_vectorised_scalar_and_loop_forms_agree(seed) -> None:
    hm, shown, rim = _state(seed)
    c = search_candidates(hm, shown, rim, CELL)
    walls = F.walled(hm, rim)
    flat = (F.space_under(c), F.support_cells(c), F.flush_cells(c), F.contact_area_mm2(c))
    for i in range(len(c)):
        x, y, fx, fy, z, h = (int(a[i]) for a in (c.x, c.y, c.fx, c.fy, c.z, c.h))
        expected = _loop_features(hm, rim, x, y, fx, fy, h)
        assert tuple(int(a[i]) for a in flat) == expected
        assert (
            F.space_under_at(hm, x, y, fx, fy, z),
            F.support_cells_at(hm, x, y, fx, fy, z),
            F.flush_cells_at(walls, x, y, fx, fy, z),
        ) == expected[:3]
    for g in c.groups:
        sl = slice(g.offset, g.offset + g.size)
        assert np.array_equal(F.flush_grid(walls, g.fx, g.fy, g.z).ravel(), flat[2][sl])
        assert np.array_equal(F.support_grid(hm, g.fx, g.fy).ravel(), flat[1][sl])
        assert np.array_equal(F.space_under_grid(hm, g.fx, g.fy, g.z).ravel(), flat[0][sl])


@pytest.mark.parametrize("seed", range(10))
def test_support_with_a_tolerance_matches_a_loop(seed) -> None:
    hm, shown, rim = _state(seed)
    c = search_candidates(hm, shown, rim, CELL)
    got = F.support_cells(c, tolerance_mm=2)
    for i in range(len(c)):
        x, y, fx, fy, z = (int(a[i]) for a in (c.x, c.y, c.fx, c.fy, c.z))
        window = hm[x : x + fx, y : y + fy]
        assert int(got[i]) == int((window >= z - 2).sum())


@pytest.mark.parametrize("seed", range(10))
def test_mta_keeps_exact_support(seed) -> None:
    # MTA's published rule counts support by exact equality; the maps hold levels 2 mm apart.
    hm, shown, rim = _state(seed)
    c = search_candidates(hm, shown, rim, CELL)
    got = mta.contact_area_mm2(c)
    for i in range(len(c)):
        x, y, fx, fy, h = (int(a[i]) for a in (c.x, c.y, c.fx, c.fy, c.h))
        assert int(got[i]) == _loop_features(hm, rim, x, y, fx, fy, h, tol=0)[3]


@pytest.mark.parametrize("seed", range(12))
def test_flush_grid_on_a_rectangle_matches_the_loop_by_either_method(seed) -> None:
    """Both exact ways of counting flush side cells (one pass per side cell, one per distinct
    height) agree with the cell-by-cell loop, on the whole grid and on any rectangle of it read
    from its ``origin`` (the proposer reads only the positions it can rank)."""
    rng = np.random.default_rng(1000 + seed)
    hm, shown, rim = _state(seed)
    walls = F.walled(hm, rim)
    c = search_candidates(hm, shown, rim, CELL)
    for g in c.groups:
        px, py = g.z.shape
        x0, y0 = int(rng.integers(0, px)), int(rng.integers(0, py))
        x1, y1 = int(rng.integers(x0 + 1, px + 1)), int(rng.integers(y0 + 1, py + 1))
        z = g.z[x0:x1, y0:y1]
        expected = np.array(
            [
                [_loop_features(hm, rim, x, y, g.fx, g.fy, g.height_mm)[2] for y in range(y0, y1)]
                for x in range(x0, x1)
            ]
        )
        heights = np.unique(z)
        by_cell = F._flush_by_side_cell(walls, g.fx, g.fy, z, x0, y0)
        by_height = F._flush_by_height(walls, g.fx, g.fy, z, x0, y0, heights)
        assert np.array_equal(by_cell, expected) and np.array_equal(by_height, expected)
        assert np.array_equal(F.flush_grid(walls, g.fx, g.fy, z, origin=(x0, y0)), expected)
