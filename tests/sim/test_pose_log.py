"""Per-step pose changes (packlab.sim.pose_log) and the records that carry them."""

from __future__ import annotations

import numpy as np
import pytest
from layered_cases import make_layered_case

from packlab.core.records import EpisodeOk, convert
from packlab.policies import make_policy
from packlab.sim.episode import run_episode
from packlab.sim.pose_log import POSE_TOLERANCE_MM, pose_updates, poses_after

NAN3, NAN4 = [np.nan] * 3, [np.nan] * 4
IDENTITY = [1.0, 0.0, 0.0, 0.0]


def _step(positions, quats):
    return np.array(positions, dtype=float), np.array(quats, dtype=float)


def test_only_placed_or_moved_boxes_are_written():
    steps = [
        _step([[10, 10, 5], NAN3], [IDENTITY, NAN4]),
        _step([[10.2, 10, 5], [30, 10, 5]], [IDENTITY, IDENTITY]),  # box 0 jitters 0.2 mm
        _step([[12, 10, 5], [30, 10, 5]], [IDENTITY, IDENTITY]),  # box 0 slides 2 mm
    ]
    updates = pose_updates([p for p, _ in steps], [q for _, q in steps])
    assert [[e[0] for e in u] for u in updates] == [[0], [1], [0]]
    assert updates[2][0][1:4] == (12.0, 10.0, 5.0)
    assert poses_after(updates, 1)[0][1] == 10.0  # the jitter stays unwritten


def test_slow_drift_is_written_once_it_adds_up():
    """Compared with the last pose *written*, not the previous step's: 0.3 mm per step escapes
    no more than one step."""
    xs = [10.0 + 0.3 * i for i in range(6)]
    steps = [_step([[x, 0, 0]], [IDENTITY]) for x in xs]
    updates = pose_updates([p for p, _ in steps], [q for _, q in steps])
    for i, x in enumerate(xs):
        shown = poses_after(updates, i)[0][1]
        assert abs(shown - x) <= POSE_TOLERANCE_MM + 0.05
    assert sum(len(u) for u in updates) == 3  # at 10.0, 10.6, 11.2 (not every step)


def test_a_quaternion_and_its_negative_are_the_same_pose():
    steps = [_step([[0, 0, 0]], [IDENTITY]), _step([[0, 0, 0]], [[-1.0, 0.0, 0.0, 0.0]])]
    updates = pose_updates([p for p, _ in steps], [q for _, q in steps])
    assert updates[1] == []


@pytest.mark.parametrize("policy", ["dblf", "random"])
def test_geometric_records_log_exactly_the_placed_box_at_each_step(policy):
    case = make_layered_case(3, cells=(16, 12), layer_heights_mm=(100, 80), pieces=4)
    result = run_episode(case, make_policy(policy), seed=2, backend="geometric")
    record = result.to_record()
    index_of = {b.internal_id: i for i, b in enumerate(case.objects)}
    for step in record["steps"]:
        if step["valid"]:
            assert [e[0] for e in step["poses"]] == [index_of[step["internal_id"]]]
        else:
            assert step["poses"] == []
    # The latest logged pose of each box is its final pose (to the records' rounding).
    updates = [s["poses"] for s in record["steps"]]
    last = poses_after(updates, len(updates) - 1)
    for iid, pose in record["final_poses"].items():
        entry = last[index_of[int(iid)]]
        assert np.allclose(entry[1:4], pose["position_mm"], atol=0.05)
        assert np.allclose(entry[4:], pose["quaternion"], atol=1e-4)
    # and the typed record reads them back as they were written
    typed = convert(
        {
            "format": "packlab-bench-run-2",
            "status": "ok",
            "difficulty": "",
            "n_objects": len(case.objects),
            **record,
            "timing": {},
        },
        EpisodeOk,
        "test",
    )
    assert [list(map(list, s.poses)) for s in typed.steps] == [
        [list(e) for e in s["poses"]] for s in record["steps"]
    ]
