"""Metric definitions (DESIGN.md section 5) with their edge cases."""

import numpy as np
import pytest

from packlab.core.types import Container
from packlab.metrics import (
    EpisodeMetrics,
    box_inside,
    compactness,
    score_final_state,
    success_ratio,
)

C = Container((100, 100, 100), 25, 2)


def test_inside_is_a_closed_box_with_tolerance():
    assert box_inside((50, 50, 50), C)
    assert box_inside((0, 100, 100), C)  # on the boundary
    assert box_inside((-0.9, 50, 50), C)  # within 1 mm
    assert not box_inside((-1.1, 50, 50), C)
    assert not box_inside((50, 50, 101.5), C)  # centre above the rim
    assert not box_inside(None, C)  # set aside


def test_success_and_compactness_hand_computed():
    assert success_ratio(300, 400) == 0.75
    # 100 x 100 base, H = 50 mm -> 500000 mm^3 of used space.
    assert compactness(250000, C, 50) == 0.5
    with pytest.raises(ValueError):
        success_ratio(1, 0)


def test_nothing_inside_scores_zero():
    hm = np.zeros((4, 4), np.int32)
    sr, comp, overall, vol, n, h = score_final_state(C, [1000], [None], hm)
    assert (sr, comp, overall, vol, n, h) == (0.0, 0.0, 0.0, 0, 0, 0)


def test_box_above_rim_is_unpacked_but_raises_height():
    # Box A (50x100x100) fills half the floor to the rim; box B (50x100x40) sits above the rim
    # with its centre at z = 120: outside, yet the heightmap over it reads 140.
    hm = np.zeros((4, 4), np.int32)
    hm[:2] = 100
    hm[2:] = 140
    sr, comp, overall, vol, n, h = score_final_state(
        C, [500000, 200000], [(25, 50, 50), (75, 50, 120)], hm
    )
    assert vol == 500000 and n == 1 and h == 140
    assert sr == pytest.approx(500000 / 700000)
    assert comp == pytest.approx(500000 / (100 * 100 * 140))
    assert overall == pytest.approx(sr * comp)


def test_final_pose_decides_even_if_the_box_was_inside_before():
    hm = np.full((4, 4), 50, np.int32)
    inside_then = score_final_state(C, [100, 100], [(50, 50, 25), (50, 50, 75)], hm)
    knocked_out = score_final_state(C, [100, 100], [(50, 50, 25), (150, 50, 20)], hm)
    assert inside_then[0] == 1.0 and knocked_out[0] == 0.5


def test_plan_drift_measures_the_largest_axis_deviation():
    from layered_cases import make_layered_case

    from packlab.core.types import Pose
    from packlab.metrics import plan_drift_mm, planned_centres_mm

    case = make_layered_case(0)
    centres = planned_centres_mm(case)
    poses = {i: Pose(c, (1.0, 0.0, 0.0, 0.0)) for i, c in centres.items()}
    assert plan_drift_mm(case, poses) == 0.0
    first = next(iter(centres))
    x, y, z = centres[first]
    poses[first] = Pose((x, y + 3.5, z - 1.0), (1.0, 0.0, 0.0, 0.0))
    assert plan_drift_mm(case, poses) == 3.5
    poses[first] = None
    assert plan_drift_mm(case, poses) == float("inf")


def test_episode_metrics_carry_the_settling_counters_into_records():
    m = EpisodeMetrics(
        0.5,
        0.5,
        0.25,
        1,
        2,
        10,
        2,
        1,
        0,
        unsettled_steps=3,
        final_settle_steps=5000,
        at_rest=False,
        residual_linear_mps=0.02,
        residual_angular_radps=0.1,
    )
    d = m.to_dict()
    assert d["unsettled_steps"] == 3 and d["final_settle_steps"] == 5000
    assert (
        d["at_rest"] is False
        and d["residual_linear_mps"] == 0.02
        and d["residual_angular_radps"] == 0.1
    )
    # A backend without physics (geometric) leaves the defaults: at rest, nothing moving.
    calm = EpisodeMetrics(1.0, 1.0, 1.0, 1, 1, 10, 1, 1, 0).to_dict()
    assert (
        calm["at_rest"] is True
        and calm["unsettled_steps"] == 0
        and calm["residual_linear_mps"] == 0.0
    )
