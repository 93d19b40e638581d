"""The buffer's boxes from its depth image: what packlab's simulated robot finds, and boxes seen
by a tilted pinhole camera."""

from __future__ import annotations

import numpy as np
import pytest
from cell_scenes import generated_case, look_at, pinhole_depth

from packlab.cell.buffer import measure_boxes
from packlab.cell.convert import calibration
from packlab.cell.geometry import Calibration, Pinhole, buffer_image
from packlab.cell.simulated import simulated_camera
from packlab.sim.sensing import layout_buffer, perceive_buffer, sensor_preset


@pytest.mark.parametrize("preset", ["none", "structured-light", "stereo"])
@pytest.mark.parametrize(("difficulty", "seed"), [("medium", 5), ("hard", 3)])
def test_the_boxes_are_the_ones_packlab_s_simulated_robot_finds(preset, difficulty, seed):
    case = generated_case(difficulty, seed)
    sensor = sensor_preset(preset)
    shown = np.array([b.size_mm for b in case.objects[: case.buffer_size]])
    grid = (case.container.cell_xy_mm, case.container.cell_z_mm)
    for scan_seed in range(3):
        scan = perceive_buffer(shown, sensor, np.random.default_rng(scan_seed), "depth", grid)
        cal = calibration(simulated_camera(scan.image), "buffer_camera")
        image = buffer_image(scan.image.depth_mm, cal, sensor.buffer_pixel_mm)
        found = measure_boxes(image, sensor, grid)
        assert found.boxes == scan.found
        np.testing.assert_array_equal(found.labels, scan.labels)


def test_boxes_seen_by_a_tilted_pinhole_are_measured_to_the_grid():
    sizes = np.array([[300, 200, 150], [250, 250, 100], [400, 150, 120], [175, 125, 80]])
    scene = layout_buffer(sizes, np.random.default_rng(3), "apart")
    boxes = [
        ((p[0], p[1]), s, np.degrees(yaw))
        for p, s, yaw in zip(scene.positions_mm, sizes, scene.yaws_rad)
    ]
    x0, y0, x1, y1 = scene.extent_mm
    camera = ((x0 + x1) / 2 - 150, (y0 + y1) / 2 - 100, 1500.0)
    rotation = look_at(camera, ((x0 + x1) / 2, (y0 + y1) / 2, 0.0), roll_deg=20.0)
    width, height, f = 1280, 1024, 1100.0
    cx, cy = width / 2 - 0.5, height / 2 - 0.5
    depth = pinhole_depth(boxes, camera, rotation, f, f, cx, cy, width, height)
    cal = Calibration(Pinhole(f, f, cx, cy, width, height), rotation, np.array(camera))
    found = measure_boxes(buffer_image(depth, cal, 2.0), sensor_preset("none"), (25, 2))
    measured = sorted(e.size_mm for e in found.boxes)
    truth = sorted(tuple(int(v) for v in (max(s[:2]), min(s[:2]), s[2])) for s in sizes)
    assert measured == truth
    for estimate in found.boxes:  # each top-face centre lies over its box's centre
        distance = np.hypot(*(scene.positions_mm[:, :2] - estimate.top_centre_mm[:2]).T)
        assert distance.min() < 15.0


@pytest.mark.parametrize("prior", ["grid", "none"])
def test_a_session_measures_boxes_under_its_size_prior(prior):
    """``sensing.size_prior``: with ``grid`` cartons off the grid are shown their cell multiples,
    with ``none`` their measured sides in whole mm (a noise-free camera: within two 2 mm
    pixels)."""
    from packlab.cell import schema
    from packlab.cell.convert import cell_config
    from packlab.cell.simulated import planned_steps, session_request
    from packlab.cell.step import StepInput, _boxes

    case = generated_case("medium", 5)
    steps = planned_steps(case, "none", 1)
    request = session_request(case, "none", steps[0])
    request.sensing = schema.Sensing(preset="none", size_prior=prior)
    config = cell_config(request, "dblf")
    # the scan's image of the case's first boxes, re-measured with sizes made off the grid
    off = np.array([b.size_mm for b in case.objects[: case.buffer_size]]) - (7, 11, 3)
    scan = perceive_buffer(off, sensor_preset("none"), np.random.default_rng(1), "depth", (1, 1))
    step = StepInput(
        steps[0].container_image.depth_mm,
        buffer_depth_mm=scan.image.depth_mm,
        buffer_camera=calibration(simulated_camera(scan.image), "buffer_camera"),
    )
    boxes, _dropped = _boxes(config, step)
    measured = sorted(b.size_mm for b in boxes)
    truth = sorted(tuple(int(v) for v in (max(s[:2]), min(s[:2]), s[2])) for s in off)
    assert len(measured) == len(truth)
    for got, want in zip(measured, truth, strict=True):
        if prior == "grid":
            assert got[0] % 25 == got[1] % 25 == got[2] % 2 == 0
        else:
            assert max(abs(g - w) for g, w in zip(got, want, strict=True)) <= 4  # two pixels


def test_segments_packlab_measured_are_listed_where_the_same_detections_are_refused():
    """More box-like segments than the buffer holds (a box cut in two) and one larger than the
    container (touching boxes merged) are perception's outcome, listed as the simulated robot
    lists them; sent by the cell as detections they are a bad request."""
    from packlab.cell import schema
    from packlab.cell.convert import cell_config
    from packlab.cell.errors import CellInputError
    from packlab.cell.simulated import planned_steps, session_request
    from packlab.cell.step import MeasuredBox, StepInput, _check_boxes

    case = generated_case("medium", 5)
    steps = planned_steps(case, "none", 1)
    config = cell_config(session_request(case, "none", steps[0]), "dblf")
    x, y, _ = config.container.size_mm
    merged = MeasuredBox(0, (2 * max(x, y), 100, 100), None)
    extra = tuple(MeasuredBox(i, (100, 100, 100), None) for i in range(config.buffer_size + 1))
    image = np.zeros((4, 4))
    from_image = StepInput(steps[0].container_image.depth_mm, buffer_depth_mm=image)
    _check_boxes(config, from_image, (merged,))
    _check_boxes(config, from_image, extra)
    detected = StepInput(
        steps[0].container_image.depth_mm, detections=(schema.Detection(size_mm=[1, 1, 1]),)
    )
    with pytest.raises(CellInputError, match="larger than the container"):
        _check_boxes(config, detected, (merged,))
    with pytest.raises(CellInputError, match="more boxes than the session's buffer_size"):
        _check_boxes(config, detected, extra)


def test_measured_sides_a_few_mm_over_a_cell_multiple_take_that_multiple():
    """The service's shown items take the measured-side slack perceived mode takes
    (``MEASURED_SIDE_SLACK_MM``), so both show a policy the same cells."""
    from packlab.cell.step import MeasuredBox, shown_items
    from packlab.core.types import Container
    from packlab.sim.buffer import MEASURED_SIDE_SLACK_MM, size_cells

    container = Container((500, 500, 400))
    boxes = (MeasuredBox(0, (252, 126, 100), None), MeasuredBox(1, (260, 140, 97), None))
    items = shown_items(boxes, container, 0)
    assert [i.size_cells for i in items] == [(10, 5, 50), (11, 6, 49)]
    assert items[0].size_cells == size_cells((252, 126, 100), container, MEASURED_SIDE_SLACK_MM)
