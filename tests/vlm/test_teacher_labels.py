"""The ``plan`` teacher's labels: its own pick always listed, soft targets over its tiling, and
the states file that stores them (format 2, format 1 still read)."""

from __future__ import annotations

import json

import msgspec
import numpy as np
import pytest

from packlab.core.errors import ConfigError
from packlab.core.feasibility import observation_candidates
from packlab.datagen.generator import generate_cases
from packlab.policies.candidates import candidate_for, propose
from packlab.policies.listed import PICK_SHARE, ListedTeacher
from packlab.policies.registry import make_policy
from packlab.sim.episode import Episode
from packlab.vlm.candidate.states import listed_of, make_state, read_states, shuffled


@pytest.fixture(scope="module")
def states():
    """(observation, listed, label, plan-fast's own action) along plan-fast's own trajectories on
    generated cases. The planner keeps state within an episode (an endgame filling it follows),
    so its own action comes from a plan-fast policy run along the same trajectory, not from a
    fresh one per state."""
    out = []
    cases = generate_cases("hard", 2, 23, validate=False, domain="train")
    cases += generate_cases("medium", 2, 23, validate=False, domain="train")
    teacher = ListedTeacher("plan")  # one teacher for every case: reset must forget the last
    for case in cases:
        teacher.reset(case, 0)
        planner = make_policy("plan-fast", overflow="place")  # the teacher's rule
        planner.reset(case, 0)
        episode = Episode("geometric")
        obs = episode.reset(case, 0)
        while not episode.done:
            cands = observation_candidates(obs)
            listed = propose(obs)
            if not listed:
                break
            told = teacher.label(obs, cands, listed)
            out.append((obs, listed, told, planner.act(obs)))
            episode.step(told.action)
            if not episode.done:
                obs = episode.observe()
    return out


def _shape(c, obs):
    return (c.fx, c.fy, obs.shown[c.object_index].size_mm[2], c.x, c.y)


def test_plan_teacher_lists_the_planners_own_pick(states):
    added = 0
    for obs, listed, told, action in states:
        assert told.action == action
        assert told.label >= 0
        picked = told.listed[told.label]
        size = obs.shown[action.object_id].size_cells
        fx, fy = (size[0], size[1]) if action.rotation == 0 else (size[1], size[0])
        assert _shape(picked, obs) == (fx, fy, obs.shown[action.object_id].size_mm[2],
                                       action.x, action.y)  # fmt: skip
        assert told.listed[: len(listed)] == listed  # the proposer's lines come first, unchanged
        if told.added:
            added += 1
            assert told.label == len(listed) and len(told.listed) == len(listed) + 1
        else:
            assert len(told.listed) == len(listed)
    assert 0 < added < len(states)  # the proposer misses some picks, not all


def test_soft_targets_share_the_mass_over_boxes_of_one_tiling(states):
    soft_states = [(obs, told) for obs, _, told, _ in states if told.soft]
    assert len(soft_states) >= 5
    for obs, told in soft_states:
        soft = np.asarray(told.soft)
        assert soft.shape == (len(told.listed),) and soft.sum() == pytest.approx(1.0)
        assert soft[told.label] == PICK_SHARE == soft.max()  # no box is preferred to the pick
        pick = told.listed[told.label]
        for i in np.flatnonzero(soft):  # every box of the tiling rests on the pick's level
            other = told.listed[i]
            assert other.z_mm == pick.z_mm
            height = obs.shown[other.object_index].size_mm[2]
            assert height == obs.shown[pick.object_index].size_mm[2]


def test_candidate_for_rebuilds_a_listed_line(states):
    obs, listed, _, _ = states[3]
    cands = observation_candidates(obs)
    for c in listed:
        assert candidate_for(cands, c.action, c.index) == c


def test_soft_targets_move_with_shuffling_and_are_stored(states, tmp_path):
    obs, _, told = next((o, li, t) for o, li, t, _ in states if t.soft)
    state = make_state("c", "hard", obs, told.listed, "plan", told.label, "teacher", told.soft,
                       told.added)  # fmt: skip
    path = tmp_path / "states.jsonl"
    path.write_bytes(msgspec.json.encode(state) + b"\n")
    (back,) = read_states(path)
    assert back == state
    mixed = shuffled(back, 3)
    for n, c in enumerate(listed_of(mixed)):
        orig = next(i for i, o in enumerate(told.listed) if o.action == c.action)
        assert mixed.soft[n] == back.soft[orig]
    assert listed_of(mixed)[mixed.label].action == told.listed[told.label].action


def test_format_1_files_read_and_bad_soft_is_named(states, tmp_path):
    obs, listed, _, _ = states[0]
    row = json.loads(msgspec.json.encode(make_state("c", "hard", obs, listed, "sdf", 0, "t")))
    row["format"] = "packlab-states-1"
    del row["soft"], row["teacher_added"]
    path = tmp_path / "old.jsonl"
    path.write_text(json.dumps(row) + "\n")
    (old,) = read_states(path)
    assert old.soft == () and not old.teacher_added
    row.update(format="packlab-states-2", soft=[1.0])
    path.write_text(json.dumps(row) + "\n")
    with pytest.raises(ConfigError, match=r"old.jsonl:1: soft has 1 values"):
        list(read_states(path))
