"""Calibrated depth images to packlab's top-down view: back-projection, poses, heightmaps."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from cell_scenes import generated_case, look_at, pinhole_depth

from packlab.cell.convert import calibration
from packlab.cell.errors import CellInputError
from packlab.cell.geometry import (
    TOP_DOWN,
    Calibration,
    Orthographic,
    Pinhole,
    camera_points,
    container_heightmap,
    container_image,
    direct_image,
    frame_points,
    pose_from_matrix,
    pose_from_quaternion,
    top_down_image,
)
from packlab.cell.simulated import simulated_camera
from packlab.core.types import Container
from packlab.sim.sensing import add_sensor_noise, container_camera, sensor_preset
from packlab.sim.sensing.perception import heightmap_from_depth
from packlab.sim.sensing.scene import planned_scene


def test_pinhole_back_projection_follows_the_camera_matrix():
    intrinsics = Pinhole(fx=500.0, fy=400.0, cx=2.0, cy=1.0, width=5, height=3)
    depth = np.full((3, 5), 1000.0)
    depth[2, 4] = 2000.0
    depth[0, 0] = np.nan
    x, y, z = camera_points(depth, intrinsics)
    assert (x[1, 2], y[1, 2], z[1, 2]) == (0.0, 0.0, 1000.0)  # the principal point
    assert (x[2, 4], y[2, 4], z[2, 4]) == pytest.approx(((4 - 2) * 4.0, (2 - 1) * 5.0, 2000.0))
    assert np.isnan(x[0, 0]) and np.isnan(z[0, 0])


def test_orthographic_back_projection_is_centred_by_default():
    x, y, z = camera_points(np.full((3, 5), 7.0), Orthographic(pixel_mm=2.0, width=5, height=3))
    assert x[0].tolist() == [-4.0, -2.0, 0.0, 2.0, 4.0]
    assert y[:, 0].tolist() == [-2.0, 0.0, 2.0]
    assert np.all(z == 7.0)


def test_a_flat_box_seen_by_a_tilted_pinhole_gives_its_heightmap_cells():
    # A 200 x 200 x 40 mm box on cells x 8..15, y 4..11 of a 600 x 400 mm container, seen from
    # 2 m up and 0.5 m to the side, the image turned 30 degrees about the optical axis.
    container = Container((600, 400, 400))
    camera = (300.0, -300.0, 2000.0)
    rotation = look_at(camera, (300.0, 200.0, 0.0), roll_deg=30.0)
    width, height, f = 640, 480, 600.0
    cx, cy = width / 2 - 0.5, height / 2 - 0.5
    box = ((300.0, 200.0), (200.0, 200.0, 40.0), 0.0)
    depth = pinhole_depth([box], camera, rotation, f, f, cx, cy, width, height)
    assert abs(np.degrees(np.arccos(-rotation[2, 2]))) > 10  # the optical axis is tilted
    cal = Calibration(Pinhole(f, f, cx, cy, width, height), rotation, np.array(camera))
    heightmap, unseen = container_heightmap(container_image(depth, cal, container), container, 0)
    expected = np.zeros(container.cells, dtype=np.int32)
    expected[8:16, 4:12] = 40
    assert unseen == 0
    np.testing.assert_array_equal(heightmap, expected)


def test_a_packlab_rendered_image_is_used_as_it_is():
    case = generated_case("medium", seed=5)
    preset = sensor_preset("structured-light")
    sizes, positions, quats = planned_scene(case)
    image = add_sensor_noise(
        container_camera(case.container, sizes, positions, quats, preset),
        preset,
        np.random.default_rng(0),
    )
    cal = calibration(simulated_camera(image), "container_camera")
    direct = direct_image(image.depth_mm, cal)
    assert direct is not None and direct.origin_mm == (0.0, 0.0)
    np.testing.assert_array_equal(direct.depth_mm, image.depth_mm)
    ours, unseen = container_heightmap(direct, case.container, preset.flat_tolerance_mm)
    packlab = heightmap_from_depth(
        image, case.container, flat_tolerance_mm=preset.flat_tolerance_mm
    )
    np.testing.assert_array_equal(ours, packlab)
    assert unseen == 0


def test_the_general_path_agrees_with_packlab_s_pixel_centres():
    # The same orthographic image through back-projection and resampling lands every pixel on
    # the world point packlab's DepthImage says it sees.
    case = generated_case("easy", seed=3)
    preset = sensor_preset("none")
    sizes, positions, quats = planned_scene(case)
    image = container_camera(case.container, sizes, positions, quats, preset)
    cal = calibration(simulated_camera(image), "container_camera")
    xs, ys, zs = frame_points(image.depth_mm, cal)
    px, py = image.pixel_centres()
    np.testing.assert_allclose(xs, px, atol=1e-9)
    np.testing.assert_allclose(ys, py, atol=1e-9)
    np.testing.assert_allclose(zs, image.heights_mm(), atol=1e-9)
    x, y, _ = case.container.size_mm
    resampled = top_down_image((xs, ys, zs), (0.0, 0.0, x, y), image.pixel_mm)
    ours, _ = container_heightmap(resampled, case.container, 0.0)
    np.testing.assert_array_equal(ours, heightmap_from_depth(image, case.container))


def test_matrix_and_quaternion_poses_agree():
    angle = np.radians(30.0)
    q = (np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2))  # 30 degrees about z
    rotation, translation = pose_from_quaternion(np.array([1.0, 2.0, 3.0]), np.array(q), "q")
    matrix = np.eye(4)
    matrix[:3, :3] = [
        [np.cos(angle), -np.sin(angle), 0],
        [np.sin(angle), np.cos(angle), 0],
        [0, 0, 1],
    ]
    matrix[:3, 3] = [1.0, 2.0, 3.0]
    r2, t2 = pose_from_matrix(matrix, "m")
    np.testing.assert_allclose(rotation, r2, atol=1e-12)
    np.testing.assert_allclose(translation, t2)


@pytest.mark.parametrize(
    ("matrix", "words"),
    [
        (np.diag([2.0, 1.0, 1.0, 1.0]), "not a rigid rotation"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "not a rigid rotation"),  # a mirror
        (np.eye(4) + np.eye(4, k=1) * 0.1, "not a rigid rotation"),  # sheared
        (np.vstack([np.eye(4)[:3], [0, 0, 1, 1]]), "last row"),
    ],
)
def test_a_pose_that_is_not_rigid_is_refused(matrix, words):
    with pytest.raises(CellInputError, match=words) as caught:
        pose_from_matrix(matrix, "container_camera.pose.matrix")
    assert caught.value.field.startswith("container_camera.pose.matrix")


def test_a_quaternion_that_is_not_unit_is_refused():
    with pytest.raises(CellInputError, match="unit quaternion"):
        pose_from_quaternion(np.zeros(3), np.array([1.0, 1.0, 0.0, 0.0]), "pose")


def test_packlab_s_cameras_look_down_with_a_proper_rotation():
    assert np.linalg.det(TOP_DOWN) == pytest.approx(1.0)
    np.testing.assert_array_equal(TOP_DOWN @ [0, 0, 1], [0, 0, -1])  # optical axis: down


def test_unseen_cells_are_counted_alike_on_both_paths():
    container = Container((100, 50, 100))  # 4 x 2 cells, 20 x 10 pixels of 5 mm
    depth = np.full((20, 10), 900.0)
    depth[5:10, 0:5] = np.nan  # all of cell (1, 0)
    depth[10:12, 5:10] = np.nan  # part of cell (2, 1): still seen
    depth[15:20, 5:10] = np.nan  # all of cell (3, 1)
    cal = Calibration(Orthographic(5.0, 10, 20, -0.5, -0.5), TOP_DOWN, np.array([0, 0, 1000.0]))
    aligned = direct_image(depth, cal)
    assert aligned is not None and aligned.origin_mm == (0.0, 0.0)
    binned = replace(aligned, origin_mm=(1e-6, 0.0))  # off the grid: pixels binned one by one
    for image in (aligned, binned):
        heightmap, unseen = container_heightmap(image, container, 0.0)
        assert unseen == 2
        assert (heightmap == 100).all()  # unseen cells take their nearest seen cell's height
