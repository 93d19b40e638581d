"""Episode frames for viewers: live, from a record's poses, re-simulated; rerun imported lazily."""

from __future__ import annotations

import subprocess
import sys

import msgspec
import numpy as np
import pytest
from layered_cases import make_layered_case
from viz_policies import OutOfBoundsAtStep1

from packlab.bench.task import run_task
from packlab.core.errors import ConfigError
from packlab.core.records import ActionRecord, EpisodeOk
from packlab.core.types import Case
from packlab.sim.episode import run_episode
from packlab.viz.episode_frames import (
    RECORDED_POSES,
    RESIMULATED,
    has_step_poses,
    live_frames,
    replay_frames,
)
from packlab.viz.rerun_log import INSTALL_HINT, rerun_module


@pytest.fixture(scope="module")
def case() -> Case:
    return make_layered_case(3, episode_id="frames-3")


def _record(case: Case, policy: str = "dblf") -> EpisodeOk:
    record = run_task(case, policy, 0, "geometric")
    assert isinstance(record, EpisodeOk)
    return record


def _without_poses(record: EpisodeOk) -> EpisodeOk:
    """The record as written before steps carried poses."""
    if not has_step_poses(record):
        return record
    steps = tuple(msgspec.structs.replace(s, poses=msgspec.UNSET) for s in record.steps)
    return msgspec.structs.replace(record, steps=steps)


def test_live_frames_one_per_step_with_latency_and_final_metrics(case):
    frames = list(live_frames(case, OutOfBoundsAtStep1(), 0, "geometric"))
    reference = run_episode(case, OutOfBoundsAtStep1(), 0, "geometric")
    assert [f.step.step_index for f in frames] == list(range(len(case.objects)))
    assert [f.step.valid for f in frames] == [s.valid for s in reference.steps]
    assert frames[1].step.reason == "out_of_bounds"
    assert all(f.policy_s is not None and f.policy_s >= 0 for f in frames)
    assert all(f.metrics is None for f in frames[:-1])
    final, expected = frames[-1].metrics, reference.metrics
    for name in ("overall", "success_ratio", "compactness", "n_inside", "n_set_aside"):
        assert getattr(final, name) == getattr(expected, name), name
    assert final.n_set_aside == 1
    # Heightmaps are the state after each step, so they only grow on a geometric backend.
    tops = [int(f.heightmap.sum()) for f in frames]
    assert tops == sorted(tops) and tops[0] > 0 and tops[1] == tops[0]


def test_record_poses_and_resimulation_give_the_same_frames(case):
    record = _record(case)
    assert has_step_poses(record), "bench records carry per-step poses"
    recorded = replay_frames(case, record)
    resimulated = replay_frames(case, _without_poses(record))
    assert (recorded.method, resimulated.method) == (RECORDED_POSES, RESIMULATED)
    assert recorded.exact and resimulated.exact
    assert len(recorded.frames) == len(resimulated.frames) == len(record.steps)
    for a, b in zip(recorded.frames, resimulated.frames):
        assert a.step.action == b.step.action and a.step.internal_id == b.step.internal_id
        assert a.step.shown == b.step.shown
        np.testing.assert_allclose(a.step.positions_mm, b.step.positions_mm, atol=0.05)
        np.testing.assert_array_equal(a.heightmap, b.heightmap)
    assert recorded.frames[-1].metrics.overall == pytest.approx(record.metrics.overall)
    assert resimulated.frames[-1].metrics.overall == pytest.approx(record.metrics.overall)
    assert recorded.mean_policy_s == pytest.approx(record.policy_time_s / len(record.steps))


def test_resimulate_forces_the_engine_and_invalid_steps_replay(case):
    record = run_task(case, "random", 2, "geometric")
    replay = replay_frames(case, record, resimulate=True)
    assert replay.method == RESIMULATED and replay.exact
    assert [f.step.valid for f in replay.frames] == [s.valid for s in record.steps]


def test_a_tampered_record_is_not_an_exact_replay(case):
    record = _without_poses(_record(case))
    first = record.steps[0]
    moved = msgspec.structs.replace(
        first, action=ActionRecord(object_id=first.action.object_id, x=1, y=1, rotation=0)
    )
    tampered = msgspec.structs.replace(record, steps=(moved, *record.steps[1:]))
    replay = replay_frames(case, tampered)
    assert not replay.exact and replay.max_pose_error_mm > 1


def test_a_pose_of_an_unknown_object_is_a_clear_error(case):
    record = _record(case)
    bad = msgspec.structs.replace(record.steps[0], poses=((99, 0, 0, 0, 1, 0, 0, 0),))
    with pytest.raises(ConfigError, match="poses.*99"):
        replay_frames(case, msgspec.structs.replace(record, steps=(bad, *record.steps[1:])))


def test_a_record_of_another_case_is_refused(case):
    with pytest.raises(ConfigError, match="does not match"):
        replay_frames(make_layered_case(4), _record(case))


def test_packlab_imports_without_loading_rerun():
    code = (
        "import sys; import packlab.cli.main as m; m.build_parser(); "
        "import packlab.viz.rerun_export, packlab.viz.rerun_log; "
        "assert 'rerun' not in sys.modules, 'rerun imported eagerly'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_without_rerun_the_error_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # makes `import rerun` raise ImportError
    with pytest.raises(ConfigError) as err:
        rerun_module()
    assert INSTALL_HINT in str(err.value)


@pytest.mark.physics
def test_mujoco_record_replays_from_its_poses_and_by_resimulation(case):
    record = run_task(case, "dblf", 0, "mujoco")
    recorded = replay_frames(case, record)
    resimulated = replay_frames(case, record, resimulate=True)
    # Same engine version and settings: stepping the actions again is the recorded episode.
    assert recorded.exact and resimulated.exact
    for a, b in zip(recorded.frames, resimulated.frames):
        placed = ~np.isnan(b.step.positions_mm).any(axis=1)
        assert (placed == ~np.isnan(a.step.positions_mm).any(axis=1)).all()
        # Record poses are written again only past 0.5 mm per axis (sim.pose_log).
        err = np.abs(a.step.positions_mm[placed] - b.step.positions_mm[placed])
        assert err.max(initial=0) <= 0.55
