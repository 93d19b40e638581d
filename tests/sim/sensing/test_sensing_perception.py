"""Perception: heightmaps and box estimates from depth images (zero noise exact, noise bounded)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from sensing_scenes import packed_layered_case

from packlab.core.types import Container
from packlab.sim.heightmap import rasterise_poses
from packlab.sim.sensing import (
    SENSOR_PRESETS,
    add_sensor_noise,
    buffer_camera,
    container_camera,
    estimate_objects,
    heightmap_from_depth,
    layout_buffer,
    render_depth,
    segment_depth,
    segment_truth,
)
from packlab.sim.sensing.camera import CARTON_BEVEL_MM
from packlab.sim.sensing.perception import flatten_tops, min_area_rect_angle

NONE = SENSOR_PRESETS["none"]
SIZES = np.array([[400, 300, 100], [75, 100, 80], [200, 200, 90], [1000, 450, 200], [125, 75, 88]])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_zero_noise_heightmap_equals_the_geometric_backends(seed):
    case, backend = packed_layered_case(seed)
    sizes = np.array([b.size_mm for b in case.objects])
    image = container_camera(case.container, sizes, *backend.poses(), NONE)
    np.testing.assert_array_equal(
        heightmap_from_depth(image, case.container), backend.finish().heightmap
    )


def test_zero_noise_heightmap_equals_the_rasteriser_for_settled_offsets():
    """Boxes a few mm off the grid and slightly yawed, as physics leaves them."""
    rng = np.random.default_rng(5)
    container = Container((500, 400, 400))
    sizes = np.array([[200, 150, 100], [100, 100, 60], [150, 100, 80]], dtype=float)
    positions = np.array([[100, 75, 50], [300, 250, 30], [100, 75, 140]], dtype=float)
    positions[:, :2] += rng.uniform(-2, 2, size=(3, 2))
    yaw = np.radians(rng.uniform(-0.5, 0.5, size=3))
    quats = np.column_stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)])
    image = container_camera(container, sizes, positions, quats, NONE)
    expected = rasterise_poses(container.cells, 25, sizes, positions, quats)
    np.testing.assert_array_equal(heightmap_from_depth(image, container), expected)


def test_flat_tops_remove_cell_noise_and_keep_steps():
    """Two flat tops 30 mm apart with 0.3 mm cell noise: each top gets one value (its median)
    and the step between them stays; zero noise is left as it is."""
    rng = np.random.default_rng(3)
    truth = np.full((12, 10), 330.0)
    truth[6:, :] = 300.0
    noisy = truth + rng.normal(0.0, 0.3, truth.shape)
    assert np.any(np.abs(np.rint(noisy) - truth) >= 1)  # the stray 1 mm steps it removes
    flat = flatten_tops(noisy, 1.5)
    assert np.rint(flat).tolist() == truth.tolist()
    assert len(np.unique(flat[:6])) == 1 and len(np.unique(flat[6:])) == 1
    np.testing.assert_array_equal(flatten_tops(truth, 1.5), truth)
    ramp = np.add.outer(np.arange(12) * 10.0, np.zeros(10))  # 10 mm per cell: no top to join
    np.testing.assert_array_equal(flatten_tops(ramp, 1.5), ramp)


@pytest.mark.parametrize(("name", "seed"), [("structured-light", 2), ("stereo", 5)])
def test_noisy_heightmap_of_a_flat_packing_is_exact_with_flat_tops(name, seed):
    case, backend = packed_layered_case(1)
    sizes = np.array([b.size_mm for b in case.objects])
    preset = SENSOR_PRESETS[name]
    clean = container_camera(case.container, sizes, *backend.poses(), preset)
    image = add_sensor_noise(clean, preset, np.random.default_rng(seed))
    exact = backend.finish().heightmap
    raw = heightmap_from_depth(image, case.container)
    flat = heightmap_from_depth(image, case.container, flat_tolerance_mm=preset.flat_tolerance_mm)
    assert np.count_nonzero(raw != exact) > 0
    np.testing.assert_array_equal(flat, exact)


def test_binned_path_agrees_with_the_aligned_path_and_fills_missing_cells():
    case, backend = packed_layered_case(3)
    sizes = np.array([b.size_mm for b in case.objects])
    x, y, _ = case.container.size_mm
    aligned = container_camera(case.container, sizes, *backend.poses(), NONE)
    # A wider image is not cell-aligned: heightmap_from_depth takes the general binning path.
    wider = render_depth(
        sizes, *backend.poses(), (-10.0, 0.0, x + 10.0, y), 5.0, aligned.camera_z_mm
    )
    expected = backend.finish().heightmap
    np.testing.assert_array_equal(heightmap_from_depth(wider, case.container), expected)
    holed = aligned.depth_mm.copy()
    holed[0:5, 0:5] = np.nan  # cell (0, 0) has no valid pixel: it takes its neighbour's value
    filled = heightmap_from_depth(
        type(aligned)(holed, aligned.ids, aligned.origin_mm, 5.0, aligned.camera_z_mm),
        case.container,
    )
    assert filled[0, 0] in (expected[1, 0], expected[0, 1])
    np.testing.assert_array_equal(filled[1:, :], expected[1:, :])


def _table(yaws_deg, sizes=SIZES, arrangement="apart", seed=0):
    """The buffer image with the boxes at the given yaws: (image, scene)."""
    scene = layout_buffer(sizes, np.random.default_rng(seed), arrangement)
    if yaws_deg is not None:
        yaw = np.radians(np.asarray(yaws_deg, dtype=float))
        quats = np.column_stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)])
        scene = replace(scene, quaternions=quats, yaws_rad=yaw)
    return buffer_camera(sizes, scene, NONE), scene


def _estimates(image):
    """Each box's estimate by the ground-truth segmentation, in box order."""
    found = estimate_objects(image, segment_truth(image))
    assert [e.label for e in found] == list(range(len(found)))
    return found


def _yaw_error_deg(estimate, size, yaw_rad) -> float:
    true = np.degrees(yaw_rad) + (90.0 if size[0] < size[1] else 0.0)
    period = 90.0 if size[0] == size[1] else 180.0
    diff = (estimate.yaw_deg - true) % period
    return min(diff, period - diff)


@pytest.mark.parametrize("quarter", [0, 90, 180, 270])
def test_zero_noise_quarter_turns_give_exact_dims_and_yaw(quarter):
    image, scene = _table([quarter] * len(SIZES))
    for est, size, yaw in zip(_estimates(image), SIZES, scene.yaws_rad):
        assert sorted(est.size_mm[:2]) == sorted(size[:2]) and est.size_mm[2] == size[2]
        assert _yaw_error_deg(est, size, yaw) < 1.0
        # the top is flat inside the rounded edges
        assert est.top_centre_mm[2] == pytest.approx(size[2])


@pytest.mark.parametrize("seed", range(6))
def test_zero_noise_random_yaws_give_exact_dims_yaw_within_three_degrees(seed):
    rng = np.random.default_rng(seed)
    image, scene = _table(rng.uniform(-180, 180, size=len(SIZES)))
    for est, size, yaw in zip(_estimates(image), SIZES, scene.yaws_rad):
        assert sorted(est.size_mm[:2]) == sorted(size[:2]) and est.size_mm[2] == size[2]
        assert _yaw_error_deg(est, size, yaw) < 3.0  # a 75 mm side spans ~15 pixels
        assert est.size_mm[0] >= est.size_mm[1]  # l is the long side, along the yaw axis


def _same_partition(found, truth, share=0.97):
    """True when each true box has its own segment holding ``share`` of its pixels (a pixel
    or two of the groove between two boxes may go to the neighbour)."""
    owner = []
    for box in range(truth.max() + 1):
        labels, counts = np.unique(found[truth == box], return_counts=True)
        best = int(np.argmax(counts))
        if labels[best] < 0 or counts[best] < share * counts.sum():
            return False
        owner.append(int(labels[best]))
    return len(set(owner)) == len(owner)


@pytest.mark.parametrize("seed", range(4))
def test_depth_segmentation_splits_touching_boxes_at_zero_noise(seed):
    """Boxes pushed together in a tote: every box is its own segment, however they touch."""
    image, _ = _table(None, arrangement="touching", seed=seed)
    found = segment_depth(image, window_px=2 * int(np.ceil(CARTON_BEVEL_MM / image.pixel_mm)) + 3)
    truth = segment_truth(image)
    assert found.max() + 1 == len(SIZES)
    assert _same_partition(found, truth)
    # and nearly every pixel of each box is in its segment
    assert np.mean((found >= 0) == (truth >= 0)) > 0.99


def test_without_rounded_edges_equal_boxes_side_by_side_merge():
    """The groove is what splits two touching boxes of one height: flat-topped, they merge
    (so the test above depends on it, not on luck)."""
    sizes = np.array([[300, 200, 150], [300, 200, 150]], dtype=float)
    positions = np.array([[150.0, 100.0, 75.0], [450.0, 100.0, 75.0]])
    quats = np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0]])
    flat = render_depth(sizes, positions, quats, (-10, -10, 610, 210), 2.0, 1500.0)
    rounded = render_depth(sizes, positions, quats, (-10, -10, 610, 210), 2.0, 1500.0, 6.0)
    assert segment_depth(flat, window_px=9).max() == 0
    assert segment_depth(rounded, window_px=9).max() == 1


def test_min_area_rect_angle_of_a_rotated_rectangle():
    angle = np.radians(30.0)
    corners = np.array([[0, 0], [100, 0], [100, 40], [0, 40]], dtype=float)
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    assert min_area_rect_angle(corners @ rot.T) == pytest.approx(np.radians(30.0))


def test_flat_tops_move_no_cell_by_more_than_the_tolerance():
    """A long gentle slope chains into one component; its ends keep their own heights."""
    slope = np.add.outer(np.arange(40) * 1.0, np.zeros(5))  # 1 mm per cell, 40 mm in all
    flat = flatten_tops(slope, 1.5)
    assert np.abs(flat - slope).max() <= 1.5
    np.testing.assert_array_equal(flat[[0, -1]], slope[[0, -1]])


def _grow_by_filter(cores, heights, foreground, steps, tolerance_mm):
    """The growth as first written: a 3 x 3 maximum filter of the labels at every ring."""
    from scipy import ndimage

    count = int(cores.max()) + 1
    inside = cores >= 0
    total = np.bincount(cores[inside], weights=heights[inside], minlength=count)
    level = total / np.maximum(np.bincount(cores[inside], minlength=count), 1)
    out = cores.copy()
    for _ in range(steps):
        grown = ndimage.maximum_filter(out, size=3)
        take = (out < 0) & foreground & (grown >= 0)
        take &= np.abs(heights - level[np.maximum(grown, 0)]) <= tolerance_mm
        if not take.any():
            break
        out[take] = grown[take]
    return out


@pytest.mark.parametrize("seed", range(8))
def test_growth_reads_only_unlabelled_pixels_and_matches_the_filter(seed):
    """Growing cores back over the foreground by reading only the unlabelled pixels'
    neighbourhoods gives the labels a 3 x 3 maximum filter over the whole image gives, at the
    image's edges too (cores and foreground touching every border)."""
    from packlab.sim.sensing.perception import _grow

    rng = np.random.default_rng(seed)
    nx, ny = (int(v) for v in rng.integers(5, 40, size=2))
    heights = rng.choice([0.0, 100.0, 104.0, 180.0], size=(nx, ny)) + rng.normal(0, 2, (nx, ny))
    foreground = heights > 10
    cores = np.where(foreground & (rng.random((nx, ny)) < 0.3), rng.integers(0, 4, (nx, ny)), -1)
    cores = cores.astype(np.int32)
    for tolerance in (5.0, 100.0):
        got = _grow(cores, heights, foreground, 7, tolerance)
        expected = _grow_by_filter(cores, heights, foreground, 7, tolerance)
        assert got.dtype == cores.dtype and np.array_equal(got, expected)
