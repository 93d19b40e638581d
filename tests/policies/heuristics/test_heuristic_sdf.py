"""SDF-Pack on hand-made states, and its distance field against scipy's EDT."""

from __future__ import annotations

import heuristics_reference as ref
import numpy as np
from heuristics_strategies import packing_states
from hypothesis import given, settings
from scipy.ndimage import distance_transform_edt

from packlab.core.feasibility import search_candidates
from packlab.core.types import Action
from packlab.policies.heuristics import dblf, sdf
from packlab.policies.heuristics.select import choose, to_action


def cands(heights, shown, rim=100):
    return search_candidates(np.asarray(heights, dtype=np.int32), shown, rim)


def gap_at(c, x, y, obj=0, rotation=0) -> float:
    i = np.flatnonzero((c.x == x) & (c.y == y) & (c.obj == obj) & (c.rotation == rotation))[0]
    return float(sdf.mean_surface_gap_mm(c)[i])


def test_mean_gap_of_a_box_in_the_middle_and_in_a_corner() -> None:
    # 3 x 3 empty floor, rim 100 (walls 4 voxels high); a 1 x 1 box 50 mm tall = 2 voxels.
    # At (1, 1): the bottom voxel sits on the floor (gap 0); the upper one is 2 voxels from the
    # floor and from each wall (gap 25 mm): mean 12.5. At (0, 0) both touch walls: 0.
    c = cands(np.zeros((3, 3)), [ref.shown_item(0, 1, 1, 50)])
    assert gap_at(c, 1, 1) == 12.5
    assert gap_at(c, 0, 0) == 0.0


def test_a_snug_spot_beats_a_slightly_lower_open_pit() -> None:
    # 5 x 5 cells at 10 mm with a floor pit at the centre; rim 200; box 1 x 1, 100 mm (4 layers).
    # Pit (2, 2), z = 0: 10 mm columns fill no voxel, so its layers are 0, 1, 2 and 2 voxels
    # from the floor/walls above the bottom: gaps 0, 25, 50, 50 -> mean 31.25, score 31.25.
    # Corner (0, 0), z = 10: walls beside every layer, floor under it: gap 0, score 10.
    heights = np.full((5, 5), 10)
    heights[2, 2] = 0
    c = cands(heights, [ref.shown_item(0, 1, 1, 100)], rim=200)
    assert gap_at(c, 2, 2) == 31.25
    assert gap_at(c, 0, 0) == 0.0
    assert to_action(c, choose(c, dblf.score(c))) == Action(0, 0, 2, 2)
    assert to_action(c, choose(c, sdf.score(c))) == Action(0, 0, 0, 0)


def test_size_penalty_prefers_the_larger_object_when_placements_tie() -> None:
    # Both boxes fit the corner with zero gap; the 25 mm box is half the 50 mm box's volume and
    # pays SIZE_PENALTY_MM * 0.5.
    shown = [ref.shown_item(0, 1, 1, 26), ref.shown_item(1, 1, 1, 50)]
    c = cands(np.zeros((3, 3)), shown)
    scores = sdf.sdf_score(c)
    corner = (c.x == 0) & (c.y == 0) & (c.rotation == 0)
    assert scores[corner & (c.obj == 1)][0] == 0.0
    assert scores[corner & (c.obj == 0)][0] == sdf.SIZE_PENALTY_MM * (1 - 26 / 50)
    assert to_action(c, choose(c, sdf.score(c))) == Action(1, 0, 0, 0)


def test_voxel_layers_follow_voxel_centres() -> None:
    z = np.array([0, 12, 13, 25, 40])
    k0, k1 = sdf.voxel_layers(z, z + np.array([50, 50, 50, 10, 2]), 25)
    # [0, 50) -> centres 12.5, 37.5; [12, 62) -> 12.5, 37.5; [13, 63) -> 37.5, 62.5 (13 > 12.5);
    # [25, 35) -> 37.5; [40, 42) holds no centre -> the one layer at or above z (centre 62.5).
    assert list(zip(k0.tolist(), k1.tolist())) == [(0, 2), (0, 2), (1, 3), (1, 2), (2, 3)]


def _occupancy(hm: np.ndarray, wall: int, v: int, layers: int) -> np.ndarray:
    """The occupancy of sdf.gap_field, built voxel by voxel for scipy's EDT."""
    nx, ny = hm.shape
    solid = np.zeros((nx + 2, ny + 2, layers + 1), dtype=bool)
    solid[:, :, 0] = True
    for i in range(nx + 2):
        for j in range(ny + 2):
            wall_cell = i in (0, nx + 1) or j in (0, ny + 1)
            height = wall if wall_cell else hm[i - 1, j - 1]
            for k in range(layers):
                solid[i, j, k + 1] = (k + 0.5) * v < height
    return solid


@settings(max_examples=60, deadline=None)
@given(packing_states(max_cells=9))
def test_gap_field_equals_truncated_scipy_edt(state) -> None:
    hm, _, rim = state
    v, layers = 25, 16
    dist = distance_transform_edt(~_occupancy(hm, rim, v, layers))
    expected = np.clip((dist - 1.0) * v, 0.0, sdf.TRUNCATION_MM)
    np.testing.assert_allclose(sdf.gap_field(hm, rim, v, layers), expected, atol=1e-9)
