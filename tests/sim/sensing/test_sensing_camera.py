"""The depth cameras: ray casting against posed boxes, the noise model and the buffer layout."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core.errors import ConfigError
from packlab.sim.heightmap import rasterise_poses, yaw_quaternion
from packlab.sim.sensing import (
    SENSOR_PRESETS,
    SensorPreset,
    add_sensor_noise,
    buffer_camera,
    layout_buffer,
    render_depth,
    sensor_preset,
)
from packlab.sim.sensing.camera import depth_edges

IDENTITY = (1.0, 0.0, 0.0, 0.0)


def test_render_depth_sees_the_highest_top_and_its_id():
    sizes = np.array([[100.0, 100.0, 50.0], [50.0, 50.0, 30.0]])
    # Box 1 sits on box 0, over its first quarter.
    positions = np.array([[50.0, 50.0, 25.0], [25.0, 25.0, 65.0]])
    image = render_depth(
        sizes, positions, np.array([IDENTITY, IDENTITY]), (0, 0, 200, 100), 5, 1000
    )
    assert image.shape == (40, 20)
    heights = image.heights_mm()
    assert heights[0, 0] == pytest.approx(80.0) and image.ids[0, 0] == 1
    assert heights[15, 15] == pytest.approx(50.0) and image.ids[15, 15] == 0
    assert heights[30, 10] == pytest.approx(0.0) and image.ids[30, 10] == -1
    assert image.depth_mm[30, 10] == pytest.approx(1000.0)


def test_render_depth_skips_unplaced_boxes_and_handles_yaw():
    sizes = np.array([[200.0, 50.0, 40.0], [50.0, 50.0, 50.0]])
    positions = np.array([[100.0, 100.0, 20.0], [np.nan, np.nan, np.nan]])
    quats = np.array([yaw_quaternion(1), IDENTITY])
    image = render_depth(sizes, positions, quats, (0, 0, 200, 200), 5, 500)
    covered = image.ids == 0
    # A quarter-turn puts the long side along y: 10 pixels wide in x, 40 long in y.
    assert covered.sum() == 10 * 40
    assert covered.any(axis=1).sum() == 10 and covered.any(axis=0).sum() == 40
    assert not (image.ids == 1).any()


def test_noise_free_preset_leaves_the_image_unchanged():
    sizes = np.array([[100.0, 100.0, 50.0]])
    image = render_depth(
        sizes, np.array([[60.0, 60.0, 25.0]]), np.array([IDENTITY]), (0, 0, 150, 150), 5, 800
    )
    same = add_sensor_noise(image, SENSOR_PRESETS["none"], np.random.default_rng(0))
    np.testing.assert_array_equal(same.depth_mm, image.depth_mm)


def test_noise_model_drops_only_edge_pixels_and_quantises():
    sizes = np.array([[100.0, 100.0, 50.0]])
    image = render_depth(
        sizes, np.array([[60.0, 60.0, 25.0]]), np.array([IDENTITY]), (0, 0, 150, 150), 5, 800
    )
    preset = SensorPreset("test", depth_noise_mm=3.0, edge_dropout=1.0, quantisation_mm=2.0)
    noisy = add_sensor_noise(image, preset, np.random.default_rng(1))
    missing = np.isnan(noisy.depth_mm)
    np.testing.assert_array_equal(missing, depth_edges(image))
    valid = noisy.depth_mm[~missing]
    np.testing.assert_allclose(valid / 2.0, np.round(valid / 2.0))
    residual = valid - image.depth_mm[~missing]
    assert 2.0 < residual.std() < 4.5


def test_buffer_layout_is_seeded_and_keeps_boxes_apart():
    sizes = np.array([[400, 300, 100], [75, 100, 80], [200, 200, 90], [1000, 500, 200]])
    a = layout_buffer(sizes, np.random.default_rng(3), "apart")
    b = layout_buffer(sizes, np.random.default_rng(3), "apart")
    np.testing.assert_array_equal(a.positions_mm, b.positions_mm)
    np.testing.assert_allclose(a.positions_mm[:, 2], sizes[:, 2] / 2)
    radius = np.hypot(sizes[:, 0], sizes[:, 1]) / 2
    for i in range(len(sizes)):
        for j in range(i):
            gap = np.hypot(*(a.positions_mm[i, :2] - a.positions_mm[j, :2])) - radius[i] - radius[j]
            assert gap >= 40 - 1e-6
    image = buffer_camera(sizes, a, SENSOR_PRESETS["none"])
    x0, y0, x1, y1 = a.extent_mm
    assert (x0, y0) == (0.0, 0.0) and x1 > 0 and y1 > 0
    # Every box is fully inside the table: its whole top area is seen.
    for i, (l, w, _) in enumerate(sizes):
        assert (image.ids == i).sum() * image.pixel_mm**2 == pytest.approx(l * w, rel=0.05)


def _corners(scene, sizes):
    """(k, 4, 2) world xy corners of each box's footprint."""
    out = []
    for (x, y, _), yaw, (l, w, _) in zip(scene.positions_mm, scene.yaws_rad, sizes):
        axes = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])
        local = np.array([[-l, -w], [l, -w], [l, w], [-l, w]]) / 2.0
        out.append(local @ axes + (x, y))
    return np.array(out)


def _overlap(a, b) -> float:
    """Separating-axis overlap depth (mm) of two convex quads; <= 0: apart or touching."""
    depth = np.inf
    for quad in (a, b):
        for i in range(4):
            edge = quad[(i + 1) % 4] - quad[i]
            axis = np.array([-edge[1], edge[0]]) / np.hypot(*edge)
            pa, pb = a @ axis, b @ axis
            depth = min(depth, min(pa.max(), pb.max()) - max(pa.min(), pb.min()))
    return depth


@pytest.mark.parametrize("seed", range(4))
def test_touching_layout_packs_boxes_against_each_other_without_overlap(seed):
    sizes = np.array(
        [
            [400, 300, 100],
            [75, 100, 80],
            [200, 200, 90],
            [1000, 500, 200],
            [300, 250, 120],
            [150, 150, 60],
        ]
    )
    scene = layout_buffer(sizes, np.random.default_rng(seed), "touching")
    np.testing.assert_array_equal(
        scene.positions_mm, layout_buffer(sizes, np.random.default_rng(seed)).positions_mm
    )
    corners = _corners(scene, sizes)
    depths = np.array(
        [[_overlap(corners[i], corners[j]) for j in range(len(sizes))] for i in range(len(sizes))]
    )
    off = ~np.eye(len(sizes), dtype=bool)
    assert depths[off].max() <= 1e-6  # never inside each other
    # most boxes touch another (within a few mm: a box turned a few degrees meets its
    # neighbour at a corner; one resting on the corner of a turned long box can sit further)
    nearest = np.max(np.where(off, depths, -np.inf), axis=1)
    assert np.mean(nearest > -15.0) >= 0.6
    # each box is square to the tote within 6 degrees
    quarter = np.degrees(scene.yaws_rad) % 90.0
    assert np.all(np.minimum(quarter, 90.0 - quarter) <= 6.0 + 1e-9)


def test_presets_are_ordered_and_validated():
    none, light, stereo = (sensor_preset(n) for n in ("none", "structured-light", "stereo"))
    assert none.depth_noise_mm == 0 and none.edge_dropout == 0
    assert 0.5 <= light.depth_noise_mm <= 1.5 and 5 <= stereo.depth_noise_mm <= 10
    assert sensor_preset("perfect").depth_noise_mm == 0
    with pytest.raises(ConfigError, match="noise preset"):
        sensor_preset("lidar")
    with pytest.raises(ConfigError, match="edge_dropout"):
        SensorPreset("bad", depth_noise_mm=1.0, edge_dropout=1.5, quantisation_mm=0.0)


def test_render_depth_agrees_with_the_rasteriser_for_yawed_and_tilted_boxes():
    """With 25 mm pixels the rays are the rasteriser's cell-centre lines (both code paths)."""
    sizes = np.array([[200.0, 100.0, 80.0], [150.0, 150.0, 60.0]])
    positions = np.array([[130.0, 120.0, 40.0], [330.0, 240.0, 90.0]])
    tilt = np.radians(8.0)  # box 1 tilted about x: the general slab test
    quats = np.array([[np.cos(0.3), 0, 0, np.sin(0.3)], [np.cos(tilt / 2), np.sin(tilt / 2), 0, 0]])
    image = render_depth(sizes, positions, quats, (0, 0, 500, 400), 25.0, 1000.0)
    expected = rasterise_poses((20, 16), 25, sizes, positions, quats)
    np.testing.assert_array_equal(np.rint(image.heights_mm()).astype(np.int32), expected)
    assert (image.ids == 1).any() and (image.ids == 0).any()
