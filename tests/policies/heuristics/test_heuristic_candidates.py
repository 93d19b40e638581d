"""The shared candidate search: hand-made states and agreement with a slow loop."""

from __future__ import annotations

import heuristics_reference as ref
import numpy as np
from heuristics_strategies import packing_states
from hypothesis import given, settings

from packlab.core.feasibility import action_mask, scatter, search_candidates


def test_hand_made_state_in_scan_order() -> None:
    # 3 x 2 cells; x is the first axis. Rim 100 mm.
    hm = np.array([[0, 40], [10, 0], [0, 0]], dtype=np.int32)
    # Object 0: 2 x 1 cells, 50 mm tall. Object 1: 1 x 1 cell, 70 mm.
    shown = [ref.shown_item(0, 2, 1, 50), ref.shown_item(1, 1, 1, 70)]
    c = search_candidates(hm, shown, container_height_mm=100)
    got = list(zip(c.obj, c.rotation, c.x, c.y, c.z, c.top, c.fits_in_rim))
    expected = [
        # object 0, rotation 0 (fx=2, fy=1): x in 0..1, y in 0..1
        (0, 0, 0, 0, 10, 60, True),
        (0, 0, 0, 1, 40, 90, True),
        (0, 0, 1, 0, 10, 60, True),
        (0, 0, 1, 1, 0, 50, True),
        # object 0, rotation 1 (fx=1, fy=2): x in 0..2, y = 0
        (0, 1, 0, 0, 40, 90, True),
        (0, 1, 1, 0, 10, 60, True),
        (0, 1, 2, 0, 0, 50, True),
        # object 1, both rotations (square): every cell
        *[
            (1, r, x, y, int(hm[x, y]), int(hm[x, y]) + 70, int(hm[x, y]) + 70 <= 100)
            for r in (0, 1)
            for x in range(3)
            for y in range(2)
        ],
    ]
    as_ints = [tuple(int(v) for v in row) for row in got]
    assert as_ints == [tuple(int(v) for v in e) for e in expected]
    # Object 1 on the 40 mm cell tops out at 110 > 100: outside the rim.
    assert not c.fits_in_rim[(c.obj == 1) & (c.x == 0) & (c.y == 1)].any()


def test_dense_masks_match_the_flat_arrays() -> None:
    hm = np.array([[0, 40], [10, 0], [0, 0]], dtype=np.int32)
    shown = [ref.shown_item(0, 2, 1, 50), ref.shown_item(1, 1, 1, 70), ref.shown_item(2, 4, 1, 10)]
    c = search_candidates(hm, shown, container_height_mm=100)
    mask = action_mask(c)
    assert mask.shape == (3, 2, 3, 2)
    assert mask.sum() == len(c)
    assert mask[0, 0, :2, :].all() and not mask[0, 0, 2, :].any()
    assert mask[0, 1, :, 0].all() and not mask[0, 1, :, 1].any()
    assert not mask[2].any()  # 4 cells long fits neither way
    rim = action_mask(c, in_rim_only=True)
    assert rim.sum() == c.fits_in_rim.sum()
    assert not rim[1, 0, 0, 1]
    z = scatter(c, c.z, fill=-1)
    assert z[0, 0, 1, 1] == 0 and z[0, 1, 0, 0] == 40 and z[2, 0, 0, 0] == -1


def test_empty_buffer_and_oversized_objects_give_no_candidates() -> None:
    hm = np.zeros((2, 2), dtype=np.int32)
    assert len(search_candidates(hm, [], 100)) == 0
    assert len(search_candidates(hm, [ref.shown_item(0, 3, 3, 10)], 100)) == 0


def test_equal_footprints_share_one_window_max_but_keep_their_own_heights() -> None:
    hm = np.array([[0, 30], [0, 0]], dtype=np.int32)
    shown = [ref.shown_item(0, 1, 1, 20), ref.shown_item(1, 1, 1, 90)]
    c = search_candidates(hm, shown, container_height_mm=100)
    assert c.groups[0].z is c.groups[2].z  # one Eq. 2 grid for the 1 x 1 footprint
    assert c.top[(c.obj == 1) & (c.x == 0) & (c.y == 1)].tolist() == [120, 120]


@settings(max_examples=150, deadline=None)
@given(packing_states())
def test_search_agrees_with_a_slow_loop(state) -> None:
    hm, shown, rim = state
    c = search_candidates(hm, shown, rim)
    expected = ref.candidates(hm, shown, rim)
    got = [
        (int(o), int(r), int(x), int(y), int(fx), int(fy), int(z), int(t), bool(f))
        for o, r, x, y, fx, fy, z, t, f in zip(
            c.obj, c.rotation, c.x, c.y, c.fx, c.fy, c.z, c.top, c.fits_in_rim
        )
    ]
    assert got == [
        (e.obj, e.rotation, e.x, e.y, e.fx, e.fy, e.z, e.top, e.fits_in_rim) for e in expected
    ]
    mask = action_mask(c)
    assert mask.shape == (len(shown), 2, *hm.shape)
    assert sorted(zip(*np.nonzero(mask))) == [(e.obj, e.rotation, e.x, e.y) for e in expected]
