"""``perceive_state``: the entry the episode loop calls in perceived mode."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from sensing_scenes import packed_layered_case

import packlab.sim.sensing.buffer as buffer_module
from packlab.core.errors import ConfigError
from packlab.sim.sensing import SENSOR_PRESETS, DepthImage, perceive_state
from packlab.sim.sensing.perception import EstimatedBox

SHOWN = np.array([[400, 300, 100], [75, 100, 80], [200, 200, 90], [1000, 450, 200], [125, 75, 88]])


def _packed(seed: int = 4):
    """(case, sizes (n, 3), positions, quaternions, exact heightmap) after the perfect plan."""
    case, backend = packed_layered_case(seed)
    sizes = np.array([b.size_mm for b in case.objects])
    return case, sizes, *backend.poses(), backend.finish().heightmap


@pytest.mark.parametrize("segmentation", ["truth", "depth"])
def test_zero_noise_perception_is_exact(segmentation):
    case, sizes, positions, quats, exact = _packed()
    state = perceive_state(
        case.container,
        sizes,
        positions,
        quats,
        SHOWN,
        "none",
        np.random.default_rng(0),
        segmentation,
    )
    np.testing.assert_array_equal(state.heightmap, exact)
    assert state.heightmap.dtype == np.int32 and state.heightmap.shape == case.container.cells
    # Longer side first: which side the catalogue calls l is not something a camera sees.
    long_first = np.column_stack([SHOWN[:, :2].max(axis=1), SHOWN[:, :2].min(axis=1), SHOWN[:, 2]])
    # Listed in the segments' order, each box once; row j is the box a pick at it takes.
    picks = list(state.picks)
    assert sorted(picks) == list(range(len(SHOWN))) and state.buffer.clean
    np.testing.assert_array_equal(state.shown_sizes_mm, long_first[picks])
    np.testing.assert_array_equal(state.axis_swapped, (SHOWN[:, 0] < SHOWN[:, 1])[picks])
    assert state.stats.heightmap_mae_mm == 0.0 and state.stats.missed == 0
    assert np.all(state.stats.dims_error_mm == 0) and np.all(state.stats.yaw_error_deg < 2.0)
    # centres within a few pixels (a groove pixel or two may go to the neighbour)
    assert np.abs(state.grasp_errors[:, :2]).max() < 3 * state.buffer.image.pixel_mm


def test_unplaced_boxes_are_ignored():
    case, sizes, _, _, _ = _packed()
    nan = np.full((len(sizes), 3), np.nan)
    state = perceive_state(
        case.container,
        sizes,
        nan,
        np.full((len(sizes), 4), np.nan),
        SHOWN,
        "none",
        np.random.default_rng(0),
    )
    assert not state.heightmap.any()


def test_errors_grow_monotonically_with_the_noise_level():
    """Stereo noise scaled 0, 1, 2, 4 times on one seeded scene (the same draws, scaled).

    Yaw is left out: depth noise does not move pixels sideways, and which edge pixels drop
    changes the yaw error by hundredths of a degree either way. Flat tops are not flattened
    here: on this flat scene flattening removes the heightmap noise at every level (tested in
    test_flat_tops_remove_cell_noise_and_keep_steps).
    """
    case, sizes, positions, quats, _ = _packed()
    stats = [
        perceive_state(
            case.container,
            sizes,
            positions,
            quats,
            SHOWN,
            replace(SENSOR_PRESETS["stereo"], flat_tolerance_mm=0.0).scaled(f),
            np.random.default_rng(7),
            "truth",  # the estimator's errors alone: at 4 x stereo depth cuts lose boxes
        ).stats
        for f in (0.0, 1.0, 2.0, 4.0)
    ]
    heightmap = [s.heightmap_mae_mm for s in stats]
    raw_dims = [float(np.mean(s.raw_dims_error_mm)) for s in stats]
    dims = [float(np.mean(s.dims_error_mm)) for s in stats]
    assert heightmap[0] == 0.0 and np.all(np.diff(heightmap) > 0), heightmap
    # sides are measured in whole pixels, so small noise may leave them unchanged
    assert np.all(np.diff(raw_dims) >= 0) and raw_dims[-1] > raw_dims[0], raw_dims
    assert dims[0] == 0.0 and np.all(np.diff(dims) >= 0), dims


def test_named_presets_order_their_errors_and_structured_light_keeps_sizes():
    case, sizes, positions, quats, _ = _packed()
    raw_light, raw_stereo, light, stereo = (
        perceive_state(
            case.container, sizes, positions, quats, SHOWN, preset, np.random.default_rng(1)
        ).stats
        for preset in (
            replace(SENSOR_PRESETS["structured-light"], flat_tolerance_mm=0.0),
            replace(SENSOR_PRESETS["stereo"], flat_tolerance_mm=0.0),
            "structured-light",
            "stereo",
        )
    )
    assert raw_light.heightmap_mae_mm < 1.0 < raw_stereo.heightmap_mae_mm
    # Flat tops: this packing is flat, so both presets see it exactly.
    assert light.heightmap_mae_mm == stereo.heightmap_mae_mm == 0.0
    assert np.all(light.dims_error_mm == 0) and np.all(light.yaw_error_deg < 1.0)


def test_same_seed_same_perception():
    case, sizes, positions, quats, _ = _packed()
    a, b = (
        perceive_state(
            case.container,
            sizes,
            positions,
            quats,
            SHOWN,
            "stereo",
            np.random.default_rng(11),
            "depth",
        )
        for _ in range(2)
    )
    np.testing.assert_array_equal(a.heightmap, b.heightmap)
    np.testing.assert_array_equal(a.shown_sizes_mm, b.shown_sizes_mm)
    np.testing.assert_array_equal(a.stats.yaw_error_deg, b.stats.yaw_error_deg)


def _fake_estimates(monkeypatch, make):
    """Replace the estimator: ``make(labels)`` gives the boxes the robot 'measures'."""
    monkeypatch.setattr(
        buffer_module, "estimate_objects", lambda image, labels, *grid: make(labels)
    )


def test_the_sizes_shown_are_the_estimates_never_the_true_sizes(monkeypatch):
    """Whatever the estimator measures is what the policy is shown (a leak of the true sizes
    would show SHOWN instead), and the errors are scored against the truth."""
    case, sizes, positions, quats, _ = _packed()

    def make(labels):
        out = []
        for label in range(int(labels.max()) + 1):
            xs, ys = np.nonzero(labels == label)
            # the right place, a wrong size: 50 x 25 x 40 mm (long side first)
            centre = (float(xs.mean()), float(ys.mean()), 40.0)
            out.append(EstimatedBox(label, (50, 25, 40), (50.0, 25.0, 40.0), centre, 0.0))
        return out

    _fake_estimates(monkeypatch, make)
    state = perceive_state(
        case.container, sizes, positions, quats, SHOWN, "none", np.random.default_rng(0), "truth"
    )
    np.testing.assert_array_equal(state.shown_sizes_mm, np.tile([50, 25, 40], (len(SHOWN), 1)))
    assert np.all(state.stats.dims_error_mm > 0)


def test_missed_objects_are_rescanned_then_left_unlisted(monkeypatch):
    """A box the estimator never returns is looked for again, then reported missed: it is not
    listed (nothing of it leaks), and the look fails the robot's own check."""
    case, sizes, positions, quats, _ = _packed()
    real = buffer_module.estimate_objects

    def without_box_1(image, labels, *grid):
        return [e for e in real(image, labels, *grid) if e.label != 1]

    monkeypatch.setattr(buffer_module, "estimate_objects", without_box_1)
    state = perceive_state(
        case.container, sizes, positions, quats, SHOWN, "none", np.random.default_rng(0), "truth"
    )
    assert state.missed == (1,) and state.stats.missed == 1
    assert state.stats.scans == buffer_module.MAX_SCANS  # looked again before giving up
    # Not listed at all (nothing leaks), and the robot's own check of the look failed.
    assert 1 not in state.picks and len(state.picks) == len(SHOWN) - 1
    assert state.shown_sizes_mm.shape == (len(SHOWN) - 1, 3) and state.shown_sizes_mm.all()
    assert np.isfinite(state.stats.dims_error_mm).all() and not state.buffer.clean


def test_touching_boxes_are_found_and_measured_from_depth_alone():
    """Structured light, boxes pushed together: every box found, sizes mostly exact."""
    case, sizes, positions, quats, _ = _packed()
    found = exact = total = 0
    for seed in range(6):
        state = perceive_state(
            case.container,
            sizes,
            positions,
            quats,
            SHOWN,
            "structured-light",
            np.random.default_rng(seed),
            "depth",
        )
        assert state.buffer.scene is not None
        found += len(SHOWN) - state.stats.missed
        exact += int(np.sum(state.stats.dims_error_mm == 0))
        total += len(SHOWN)
    assert found == total and exact >= 0.9 * total


def test_bad_inputs_are_config_errors():
    case, sizes, positions, quats, _ = _packed()
    rng = np.random.default_rng(0)
    with pytest.raises(ConfigError, match="segmentation"):
        perceive_state(case.container, sizes, positions, quats, SHOWN, "none", rng, "sam")
    with pytest.raises(ConfigError, match="noise preset"):
        perceive_state(case.container, sizes, positions, quats, SHOWN, "kinect", rng)


def test_empty_container_and_empty_buffer():
    case = _packed()[0]
    none3, none4 = np.zeros((0, 3)), np.zeros((0, 4))
    state = perceive_state(
        case.container, none3, none3, none4, none3, "stereo", np.random.default_rng(0), "depth"
    )
    assert state.shown_sizes_mm.shape == (0, 3) and state.stats.missed == 0
    assert (
        state.heightmap.shape == case.container.cells and state.heightmap.max() < 10
    )  # floor noise only


def test_a_pick_takes_the_box_under_the_segments_estimated_centre():
    """The simulator's side of a pick: the true box at the segment's pixel nearest the centre
    the robot estimated; a segment over no box picks nothing (-1)."""
    ids = np.full((8, 4), -1, dtype=np.int32)
    ids[0:4, :] = 0  # box 0 under x = 0-4 mm
    ids[4:6, :] = 1  # box 1 under x = 4-6 mm
    labels = np.full((8, 4), -1, dtype=np.int32)
    labels[0:6, :] = 0  # one segment over both boxes (merged)
    labels[6:8, :] = 1  # one over the table only (noise)
    image = DepthImage(np.zeros((8, 4)), ids, (0.0, 0.0), 1.0, 100.0)

    def segment(label, x_mm):
        return EstimatedBox(label, (25, 25, 2), (6.0, 4.0, 2.0), (x_mm, 2.0, 2.0), 0.0)

    assert buffer_module._picks(image, labels, (segment(0, 5.2), segment(1, 7.0))) == (1, -1)
    assert buffer_module._picks(image, labels, (segment(0, 1.0),)) == (0,)
    # A centre off the segment: its nearest pixel on a box decides.
    assert buffer_module._picks(image, labels, (segment(0, 30.0),)) == (1,)
