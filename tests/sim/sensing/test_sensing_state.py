"""``perceive_state``: the entry the episode loop calls in perceived mode."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from sensing_scenes import packed_layered_case

from packlab.core.errors import ConfigError
from packlab.sim.sensing import SENSOR_PRESETS, buffer_views, layout_buffer, perceive_state

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
    np.testing.assert_array_equal(state.shown_sizes_mm, SHOWN)  # the catalogue's l/w order too
    assert state.stats.heightmap_mae_mm == 0.0 and state.stats.missed == 0
    assert np.all(state.stats.dims_error_mm == 0) and np.all(state.stats.yaw_error_deg < 1.0)


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
        ).stats
        for f in (0.0, 1.0, 2.0, 4.0)
    ]
    heightmap = [s.heightmap_mae_mm for s in stats]
    raw_dims = [float(np.mean(s.raw_dims_error_mm)) for s in stats]
    dims = [float(np.mean(s.dims_error_mm)) for s in stats]
    assert heightmap[0] == 0.0 and np.all(np.diff(heightmap) > 0), heightmap
    assert np.all(np.diff(raw_dims) > 0), raw_dims
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


def test_buffer_views_show_only_their_own_box():
    scene = layout_buffer(SHOWN, np.random.default_rng(2))
    for index, view in enumerate(buffer_views(SHOWN, scene, SENSOR_PRESETS["none"])):
        assert view.shape == (128, 128)
        assert set(np.unique(view.ids).tolist()) == {-1, index}
        assert not (view.ids[0, :] >= 0).any() and not (view.ids[-1, :] >= 0).any()


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
