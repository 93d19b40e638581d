"""The Monte-Carlo rollout teacher (:mod:`packlab.vlm.candidate.rollout_teacher`): its values are
what playing the line and the base policy to the end gives, its copies leave the episode as it
was, its rows are well-formed and the collection resumes."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.cases.fingerprint import case_fingerprint
from packlab.core.errors import ConfigError
from packlab.core.feasibility import observation_candidates
from packlab.datagen.config import CaseConfig
from packlab.datagen.generator import generate_cases
from packlab.policies.candidates import propose_from
from packlab.policies.registry import make_policy
from packlab.sim.episode import Episode
from packlab.vlm.candidate.collect import DEFAULT_PROPOSER, done_cases
from packlab.vlm.candidate.rollout_teacher import (
    collect_rollout_labels,
    line_values,
    play_out,
    soft_target,
    teacher_name,
)
from packlab.vlm.candidate.states import read_states


@pytest.fixture(scope="module")
def cases():
    return generate_cases("easy", 3, 21, validate=False, config=CaseConfig(layout="random"),
                          domain="train")  # fmt: skip


def _second_step(case):
    env = Episode("geometric")
    obs = env.reset(case, 0)
    base = make_policy("proposer")
    base.reset(case, 0)
    env.step(base.act(obs))
    return env, env.observe(), base


def test_soft_target_is_a_distribution_that_shares_ties():
    soft = soft_target([0.5, 0.7, 0.7, 0.2], 0.01)
    assert sum(soft) == pytest.approx(1.0)
    assert soft[1] == pytest.approx(soft[2]) and soft[1] > 0.49
    assert soft[0] < 1e-6 and soft[3] < 1e-6
    flat = soft_target([0.3, 0.3], 0.01)
    assert flat == pytest.approx((0.5, 0.5))


def test_line_values_are_the_played_out_overall_and_leave_the_episode_alone(cases):
    env, obs, base = _second_step(cases[0])
    listed = propose_from(observation_candidates(obs), DEFAULT_PROPOSER)
    assert len(listed) > 1
    heightmap, steps = env.heightmap.copy(), len(env.steps)
    values = line_values(env, listed, lambda: base.act)
    # The copies played to the end; the episode itself did not move.
    assert np.array_equal(env.heightmap, heightmap) and len(env.steps) == steps and not env.done
    assert all(0.0 <= v <= 1.0 for v in values)
    # Replaying one line by hand gives its value (the geometric backend and the base are exact).
    k = int(np.argmax(values))
    env.step(listed[k].action)
    assert play_out(env, base.act) == pytest.approx(values[k])


def test_rows_name_the_teacher_and_case_and_the_collection_resumes(cases, tmp_path):
    out = tmp_path / "mc.jsonl"
    n = collect_rollout_labels(cases[:2], out, "r-mc", workers=1, progress=False)
    rows = list(read_states(out))
    assert n == len(rows) > 0
    prints = {c.episode_id: case_fingerprint(c) for c in cases}
    for r in rows:
        assert r.teacher == teacher_name("proposer") == "mc-proposer"
        assert r.case_sha256 == prints[r.case_id] and r.source == "r-mc"
        assert 0 <= r.label < len(r.listed) and len(r.soft) == len(r.listed)
        assert r.soft[r.label] == max(r.soft) and sum(r.soft) == pytest.approx(1.0)
        assert not r.teacher_added  # the teacher labels the list as given
    assert done_cases(out) == {c.episode_id for c in cases[:2]}
    again = collect_rollout_labels(cases, out, "r-mc", workers=1, progress=False)
    after = list(read_states(out))
    assert len(after) == len(rows) + again > len(rows)
    assert {r.case_id for r in after[len(rows) :]} == {cases[2].episode_id}


def test_bad_settings_are_refused_before_any_work(cases, tmp_path):
    out = tmp_path / "mc.jsonl"
    with pytest.raises(ConfigError, match="temperature = 0"):
        collect_rollout_labels(cases, out, "r", temperature=0, progress=False)
    with pytest.raises(ConfigError):
        collect_rollout_labels(cases, out, "r", base="no-such-policy", progress=False)
    assert not out.exists()


def test_collect_states_script_labels_with_the_rollout_teacher(cases, tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    from packlab.cases.write import save_cases

    src = tmp_path / "cases.jsonl"
    save_cases(cases[:1], src)
    script = Path(__file__).resolve().parents[2] / "scripts" / "collect_states.py"
    out = tmp_path / "mc.jsonl"
    run = subprocess.run(
        [sys.executable, str(script), str(src), str(out), "r-mc", "--teacher", "mc",
         "--workers", "1"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    rows = list(read_states(out))
    assert rows and {r.teacher for r in rows} == {"mc-proposer"}
    refused = subprocess.run(
        [sys.executable, str(script), str(src), str(tmp_path / "x.jsonl"), "r", "--teacher", "mc",
         "--robot", "stereo"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert refused.returncode == 2 and "--teacher mc" in refused.stderr
    assert not (tmp_path / "x.jsonl").exists()
