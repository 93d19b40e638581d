"""The teacher-free candidate proposer: valid placements, its documented geometry, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core.feasibility import footprint_cells, search_candidates
from packlab.core.types import ShownItem
from packlab.policies.candidates import ProposerConfig, propose_from

CELL = 25


def _item(i: int, fx: int, fy: int, h_mm: int, internal_id: int | None = None) -> ShownItem:
    iid = i if internal_id is None else internal_id
    return ShownItem(i, iid, (fx * CELL, fy * CELL, h_mm), (fx, fy, h_mm // 2))


def _state(seed: int) -> tuple[np.ndarray, list[ShownItem], int]:
    """A random small state: a stepped heightmap, 1-6 boxes (some identical), a rim."""
    rng = np.random.default_rng(seed)
    nx, ny = (int(v) for v in rng.integers(3, 13, size=2))
    hm = rng.choice([0, 0, 20, 40, 60, 100], size=(nx, ny)).astype(np.int32)
    rim = int(rng.integers(60, 260))
    shown = []
    for i in range(int(rng.integers(1, 7))):
        if shown and rng.random() < 0.3:  # an identical box with another id
            prev = shown[-1]
            shown.append(ShownItem(i, 100 + i, prev.size_mm, prev.size_cells))
        else:
            fx, fy = (int(v) for v in rng.integers(1, 6, size=2))
            shown.append(_item(i, fx, fy, 2 * int(rng.integers(5, 60))))
    return hm, shown, rim


def _flush_cells(hm: np.ndarray, x: int, y: int, fx: int, fy: int, z: int, rim: int) -> int:
    """Side cells of the footprint whose neighbour (a wall has the rim's height) is above z."""
    nx, ny = hm.shape

    def above(i: int, j: int) -> bool:
        inside = 0 <= i < nx and 0 <= j < ny
        return (hm[i, j] if inside else rim) > z

    sides = [(x - 1, j) for j in range(y, y + fy)] + [(x + fx, j) for j in range(y, y + fy)]
    sides += [(i, y - 1) for i in range(x, x + fx)] + [(i, y + fy) for i in range(x, x + fx)]
    return sum(above(i, j) for i, j in sides)


CONFIGS = [ProposerConfig(), ProposerConfig(3), ProposerConfig(16, "lowest+largest")]


@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: f"{c.rule}-{c.k}")
@pytest.mark.parametrize("seed", range(40))
def test_candidates_are_valid_placements_with_their_geometry(seed, config):
    hm, shown, rim = _state(seed)
    cands = search_candidates(hm, shown, rim, CELL)
    listed = propose_from(cands, config)
    assert listed == propose_from(cands, config)  # deterministic
    assert [c.index for c in listed] == list(range(len(listed))) and len(listed) <= config.k
    assert len({c.action for c in listed}) == len(listed)
    lowest_top = int(cands.top.min()) if len(cands) else 0
    for c in listed:
        item = shown[c.object_index]
        assert (c.fx, c.fy) == footprint_cells(item, c.rotation)
        assert 0 <= c.x and c.x + c.fx <= hm.shape[0] and 0 <= c.y and c.y + c.fy <= hm.shape[1]
        window = hm[c.x : c.x + c.fx, c.y : c.y + c.fy]
        assert c.z_mm == window.max()  # Eq. 2
        assert c.top_mm == c.z_mm + item.size_mm[2]
        # The shared rim pool: within the rim, or the lowest tops when nothing fits under it.
        assert c.top_mm <= rim or (not cands.fits_in_rim.any() and c.top_mm == lowest_top)
        area = c.fx * c.fy
        assert c.support_pct == round(100 * int((window == c.z_mm).sum()) / area)
        flush = _flush_cells(hm, c.x, c.y, c.fx, c.fy, c.z_mm, rim)
        assert c.flush_pct == round(100 * flush / (2 * (c.fx + c.fy)))
        assert c.void_mm == round(int((c.z_mm - window).sum()) / area)


@pytest.mark.parametrize("seed", range(40))
def test_every_distinct_shape_gets_its_lowest_position_first(seed):
    hm, shown, rim = _state(seed)
    cands = search_candidates(hm, shown, rim, CELL)
    listed = propose_from(cands, ProposerConfig(k=64))
    shapes = {}
    for c in listed:
        item = shown[c.object_index]
        shapes.setdefault((c.fx, c.fy, item.size_mm[2]), c)  # the first listed of each shape
    if cands.fits_in_rim.any():
        pool = np.flatnonzero(cands.fits_in_rim)
        pool_shapes = {(int(cands.fx[i]), int(cands.fy[i]), int(cands.h[i])) for i in pool}
        assert set(shapes) == pool_shapes  # every shape that fits is listed
        for (fx, fy, h), first in shapes.items():
            same = (cands.fx == fx) & (cands.fy == fy) & (cands.h == h) & cands.fits_in_rim
            assert first.z_mm == cands.z[same].min()  # its lowest resting height
    # The first round lists each shape once, before any shape's second position.
    n_shapes = len(shapes)
    firsts = [(c.fx, c.fy, shown[c.object_index].size_mm[2]) for c in listed[:n_shapes]]
    assert len(set(firsts)) == n_shapes


def test_identical_boxes_and_square_rotations_are_proposed_once():
    hm = np.zeros((6, 6), dtype=np.int32)
    shown = [
        _item(0, 2, 3, 40, internal_id=9),
        _item(1, 2, 3, 40, internal_id=4),
        _item(2, 2, 2, 20),
    ]
    listed = propose_from(search_candidates(hm, shown, 200, CELL), ProposerConfig(k=64))
    # Boxes 0 and 1 are identical: only box 1 (the smaller id) is proposed; the square box 2
    # only at rotation 0.
    assert {(c.object_index, c.rotation) for c in listed} == {(1, 0), (1, 1), (2, 0)}
    # On an empty floor the lowest, most flush places are the corners: the first round
    # takes the origin corner for each shape (ties after flushness go by x, then y).
    assert [(c.x, c.y) for c in listed[:3]] == [(0, 0)] * 3
    assert all(c.flush_pct == 50 for c in listed[:3])


def test_nothing_fits_gives_an_empty_list():
    hm = np.zeros((3, 3), dtype=np.int32)
    assert propose_from(search_candidates(hm, [_item(0, 4, 1, 20)], 100, CELL)) == ()
    assert propose_from(search_candidates(hm, [], 100, CELL)) == ()


def test_config_is_validated():
    for bad in (0, -1, True, 2.0):
        with pytest.raises(ValueError, match="k"):
            ProposerConfig(k=bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="rule"):
        ProposerConfig(rule="best")  # type: ignore[arg-type]
