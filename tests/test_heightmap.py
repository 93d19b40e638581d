"""Pure heightmap functions against hand-computed expectations."""

import numpy as np
import pytest

from packlab.core.feasibility import footprint_fits, footprint_max, placement_height
from packlab.core.types import Box
from packlab.sim.heightmap import (
    place_box,
    quat_to_matrix,
    rasterise_poses,
    yaw_quaternion,
)


def test_eq2_drop_height_is_max_under_footprint():
    hm = np.array([[0, 10, 0], [0, 0, 30], [5, 0, 0]], dtype=np.int32)
    assert placement_height(hm, 0, 0, 2, 2) == 10
    assert placement_height(hm, 1, 1, 2, 2) == 30
    assert placement_height(hm, 2, 0, 1, 2) == 5
    assert placement_height(hm, 0, 0, 3, 3) == 30


def test_footprint_max_matches_every_window():
    rng = np.random.default_rng(3)
    hm = rng.integers(0, 500, size=(9, 7)).astype(np.int32)
    for fx, fy in [(1, 1), (2, 3), (4, 1), (9, 7), (3, 7)]:
        out = footprint_max(hm, fx, fy)
        assert out.shape == (9 - fx + 1, 7 - fy + 1)
        for x in range(out.shape[0]):
            for y in range(out.shape[1]):
                assert out[x, y] == hm[x : x + fx, y : y + fy].max()


@pytest.mark.parametrize("dtype", [np.int32, np.int64, np.uint16, np.float64])
def test_footprint_max_matches_every_window_at_every_size(dtype):
    """Every footprint, odd and even sides alike (the running max is shifted by half a window),
    on maps of several dtypes: the max of each whole window, in the map's dtype."""
    rng = np.random.default_rng(4)
    hm = rng.integers(0, 500, size=(8, 11)).astype(dtype)
    for fx in range(1, 9):
        for fy in range(1, 12):
            out = footprint_max(hm, fx, fy)
            assert out.dtype == hm.dtype
            expected = [
                [hm[x : x + fx, y : y + fy].max() for y in range(11 - fy + 1)]
                for x in range(8 - fx + 1)
            ]
            assert np.array_equal(out, np.array(expected, dtype=dtype).reshape(out.shape))


def test_footprint_larger_than_map_has_no_candidates():
    assert footprint_max(np.zeros((3, 3), np.int32), 4, 1).size == 0


def test_footprint_fits_bounds():
    assert footprint_fits((4, 4), 0, 0, 4, 4)
    assert not footprint_fits((4, 4), 1, 0, 4, 1)
    assert not footprint_fits((4, 4), -1, 0, 1, 1)
    assert not footprint_fits((4, 4), 0, 3, 1, 2)


def test_rotation_swaps_footprint():
    box = Box(0, (100, 50, 30))
    assert box.footprint_mm(0) == (100, 50)
    assert box.footprint_mm(1) == (50, 100)


def test_place_box_raises_only_the_footprint_and_copies():
    hm = np.zeros((3, 3), np.int32)
    out = place_box(hm, 1, 0, 2, 1, 40)
    assert hm.sum() == 0
    assert out.tolist() == [[0, 0, 0], [40, 0, 0], [40, 0, 0]]


def test_yaw_quaternion_rotates_x_onto_y():
    r = quat_to_matrix(yaw_quaternion(1))
    assert np.allclose(r @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(quat_to_matrix(yaw_quaternion(0)), np.eye(3))


def test_rasterise_axis_aligned_box():
    # A 50 x 75 x 40 mm box resting on the floor with its min corner at cell (1, 0), 25 mm cells.
    hm = rasterise_poses(
        (4, 4),
        25,
        np.array([[50, 75, 40]]),
        np.array([[25 + 25, 37.5, 20]]),
        np.array([yaw_quaternion(0)]),
    )
    expected = np.zeros((4, 4), np.int32)
    expected[1:3, 0:3] = 40
    assert hm.tolist() == expected.tolist()


def test_rasterise_rotated_box_uses_swapped_footprint():
    # Same box at rotation 1: footprint 75 along x, 50 along y.
    hm = rasterise_poses(
        (4, 4),
        25,
        np.array([[50, 75, 40]]),
        np.array([[37.5, 25, 20]]),
        np.array([yaw_quaternion(1)]),
    )
    expected = np.zeros((4, 4), np.int32)
    expected[0:3, 0:2] = 40
    assert hm.tolist() == expected.tolist()


def test_rasterise_tilted_box_top_is_the_exit_of_a_vertical_ray():
    # A 100 x 100 x 20 mm slab tilted 45 degrees about y, centred at (100, 50, 100).
    angle = np.pi / 4
    q = (np.cos(angle / 2), 0.0, np.sin(angle / 2), 0.0)
    hm = rasterise_poses(
        (8, 4), 25, np.array([[100, 100, 20]]), np.array([[100.0, 50.0, 100.0]]), np.array([q])
    )
    # Along y the slab is untilted: every covered row of a column has the same height.
    assert (hm[:, 0] == hm[:, 1]).all()
    # Over the cell centre x = 112.5 (12.5 mm right of the centre) the top face is at
    # z = 100 + 10 / cos(45) + 12.5 * tan(45) (sign follows the rotation) or its mirror.
    top_face = 100 + 10 / np.cos(angle)
    assert hm[4, 0] in (round(top_face + 12.5), round(top_face - 12.5))
    assert hm[4, 0] + hm[3, 0] == pytest.approx(2 * top_face, abs=1)
    # Outside the tilted slab's planar extent nothing is drawn.
    assert hm[0, 0] == 0 and hm[7, 0] == 0
