"""Perception's shortcuts give what the long way gives, bit for bit.

The depth segmentation opens its cores and finds steep pixels with whole-array numpy
(``_open_cross``, ``_steeper_than``), the box fit finds a segment's boundary the same way
(``_boundary``) and reads sums, extremes and medians through numpy's reductions directly
(``_edge_refinement``, ``_robust_span``, ``_median_finite``). Each is compared with the scipy or
numpy call it stands for.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from packlab.sim.sensing import (
    SENSOR_PRESETS,
    add_sensor_noise,
    buffer_camera,
    layout_buffer,
    perception,
)
from packlab.sim.sensing.perception import (
    _boundary,
    _open_cross,
    _steeper_than,
    estimate_objects,
    segment_depth,
)


@pytest.mark.parametrize("shape", [(1, 1), (1, 6), (2, 3), (5, 1), (4, 4), (37, 53)])
def test_open_cross_is_scipy_binary_opening(shape):
    rng = np.random.default_rng(sum(shape))
    for fill in (0.3, 0.7, 0.95, 1.0):
        for iterations in (1, 2, 3):
            mask = rng.random(shape) < fill
            expected = ndimage.binary_opening(mask, iterations=iterations)
            np.testing.assert_array_equal(_open_cross(mask, iterations), expected)


@pytest.mark.parametrize("shape", [(1, 1), (1, 5), (3, 3), (12, 17)])
def test_boundary_is_the_mask_less_its_erosion(shape):
    rng = np.random.default_rng(len(shape) + shape[0])
    for fill in (0.5, 0.9, 1.0):
        mask = rng.random(shape) < fill
        padded = np.pad(mask, 1)
        expected = (padded & ~ndimage.binary_erosion(padded))[1:-1, 1:-1]
        np.testing.assert_array_equal(_boundary(mask), expected)


def test_steeper_than_is_hypot_over_the_limit_even_at_the_limit():
    rng = np.random.default_rng(0)
    limit = 2.0
    dx, dy = rng.normal(0.0, 2.0, (2, 200, 300))
    # Pairs whose length is the limit to the last bits, either side of it.
    angle = rng.uniform(0.0, 2 * np.pi, 2000)
    length = limit * (1.0 + rng.integers(-4, 5, 2000) * np.finfo(float).eps)
    dx.ravel()[:2000], dy.ravel()[:2000] = length * np.cos(angle), length * np.sin(angle)
    dx.ravel()[2000:2010], dy.ravel()[2000:2010] = limit, 0.0
    expected = np.hypot(dx, dy) > limit
    near = expected.ravel()[:2000]
    assert near.any() and not near.all()  # both answers at the limit
    np.testing.assert_array_equal(_steeper_than(dx, dy, limit), expected)


@pytest.mark.parametrize("preset", ["structured-light", "stereo"])
def test_segmentation_and_fits_are_the_long_ways(preset):
    """Segmentation with scipy's opening and hypot, the fits with scipy's erosion, against the
    shortcuts on noisy buffer images."""
    sensor = SENSOR_PRESETS[preset]
    rng = np.random.default_rng(4)
    long_way = {
        "_open_cross": lambda mask, n: ndimage.binary_opening(mask, iterations=n),
        "_steeper_than": lambda dx, dy, limit: np.hypot(dx, dy) > limit,
        "_boundary": lambda mask: (np.pad(mask, 1) & ~ndimage.binary_erosion(np.pad(mask, 1)))[
            1:-1, 1:-1
        ],
    }
    for _ in range(6):
        shown = rng.integers(2, 20, size=(8, 3)) * np.array([25, 25, 2])
        scene = layout_buffer(shown, rng)
        image = add_sensor_noise(buffer_camera(shown, scene, sensor), sensor, rng)
        args = {"min_height_mm": 10.0, "groove_mm": 1.5, "step_mm": 2.0, "window_px": 7}
        labels = segment_depth(image, **args)
        fits = estimate_objects(image, labels)
        with pytest.MonkeyPatch.context() as patch:
            for name, function in long_way.items():
                patch.setattr(perception, name, function)
            expected_labels = segment_depth(image, **args)
            expected_fits = estimate_objects(image, expected_labels)
        np.testing.assert_array_equal(labels, expected_labels)
        assert fits == expected_fits
        assert len(fits) >= 4


def _edge_refinement_long_way(edge_points: np.ndarray, angle: float, pixel_mm: float) -> float:
    """``perception._edge_refinement`` with numpy's methods (``min``, ``ptp``, ``mean``)."""
    c, s = np.cos(angle), np.sin(angle)
    u = c * edge_points[:, 0] + s * edge_points[:, 1]
    v = -s * edge_points[:, 0] + c * edge_points[:, 1]
    corrections, weights = [], []
    for along, across, sign in ((u, v, 1.0), (v, u, -1.0)):
        inner = (along > along.min() + 2 * pixel_mm) & (along < along.max() - 2 * pixel_mm)
        band = 1.5 * pixel_mm
        for side in (across <= across.min() + band, across >= across.max() - band):
            sel = side & inner
            a, b = along[sel], across[sel]
            if len(a) < 3 or np.ptp(a) <= 0:
                continue
            a = a - a.mean()
            slope = float(a @ (b - b.mean()) / (a @ a))
            corrections.append(sign * np.arctan(slope))
            weights.append(float(len(a)))
    if not weights:
        return 0.0
    return float(np.average(corrections, weights=weights))


def _robust_span_long_way(values: np.ndarray, pixel_mm: float) -> tuple[float, float]:
    """``perception._robust_span`` with ``np.median`` and ``ndarray.min``."""
    start = float(values.min())
    counts = np.bincount(np.floor((values - start) / pixel_mm).astype(np.int64))
    full = np.flatnonzero(counts >= 0.5 * np.median(counts[counts > 0]))
    return start + (full[0] - 0.5) * pixel_mm, start + (full[-1] + 0.5) * pixel_mm


def test_side_fits_and_spans_are_numpy_s_methods():
    rng = np.random.default_rng(11)
    for _ in range(300):
        pixel = float(rng.choice([2.0, 2.5, 5.0]))
        n = int(rng.integers(3, 400))
        # Boundary-like clouds: a turned rectangle's outline on the pixel grid, and noise.
        w, h, yaw = rng.uniform(10, 300), rng.uniform(10, 300), rng.uniform(-1, 1)
        t = rng.uniform(0, 1, n)
        side = rng.integers(4, size=n)
        local = np.where(
            (side % 2 == 0)[:, None],
            np.column_stack([(t - 0.5) * w, (side - 1) * h / 2]),
            np.column_stack([(side - 2) * w / 2, (t - 0.5) * h]),
        )
        rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
        points = np.round(local @ rot.T / pixel) * pixel + rng.normal(0, 0.01, (n, 2))
        angle = float(rng.uniform(0, np.pi / 2))
        assert perception._edge_refinement(points, angle, pixel) == _edge_refinement_long_way(
            points, angle, pixel
        )
        values = points[:, int(rng.integers(2))]
        assert perception._robust_span(values, pixel) == _robust_span_long_way(values, pixel)
    for counts in ([3], [1, 2], [5, 1, 4, 4], [7, 7, 2, 9, 1], np.arange(1, 60)):
        counts = np.asarray(counts, dtype=np.int64)
        assert perception._median_count(counts) == float(np.median(counts))


def test_median_of_finite_heights_is_np_median():
    rng = np.random.default_rng(12)
    for n in (1, 2, 3, 4, 7, 8, 100, 101):
        for _ in range(50):
            values = np.round(rng.normal(300, 5, n), int(rng.integers(0, 3)))
            assert perception._median_finite(values) == float(np.median(values))
