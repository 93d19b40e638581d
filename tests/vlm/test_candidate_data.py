"""Candidate mode without torch: labelled states on disk, teachers over the listed set, the lazy
composer and its export, collection (resume) and the recipe's case split."""

from __future__ import annotations

import json

import msgspec
import numpy as np
import pytest

from packlab.cases.fingerprint import case_fingerprint
from packlab.core.errors import ConfigError
from packlab.core.feasibility import action_mask, observation_candidates
from packlab.datagen.generator import generate_cases
from packlab.policies.candidates import propose
from packlab.policies.listed import TEACHERS, ListedTeacher
from packlab.policies.registry import make_policy
from packlab.sim.episode import Episode
from packlab.vlm.candidate.collect import RobotPath, collect, done_cases
from packlab.vlm.candidate.compose import export_chat_jsonl, state_messages
from packlab.vlm.candidate.dagger_split import split_cases
from packlab.vlm.candidate.recipe import DaggerConfig
from packlab.vlm.candidate.states import (
    decode_heightmap,
    encode_heightmap,
    listed_of,
    make_state,
    observation_of,
    read_states,
    shuffled,
)


@pytest.fixture(scope="module")
def cases():
    return generate_cases("easy", 3, 11, validate=False, domain="train") + generate_cases(
        "medium", 1, 11, validate=False, domain="train"
    )


def _mid_episode(case, steps: int = 2):
    """An observation after ``steps`` SDF-Pack placements (geometric)."""
    episode = Episode("geometric")
    obs = episode.reset(case, 0)
    sdf = make_policy("sdf")
    sdf.reset(case, 0)
    for _ in range(steps):
        episode.step(sdf.act(obs))
        obs = episode.observe()
    return obs


def test_state_round_trip_keeps_what_the_model_sees(cases):
    obs = _mid_episode(cases[3])
    listed = propose(obs)
    state = make_state("c", "medium", obs, listed, "sdf", 2, "teacher")
    back = observation_of(state)
    assert np.array_equal(back.heightmap, obs.heightmap)
    assert back.shown == obs.shown and back.remaining == obs.remaining
    assert back.container == obs.container and back.step_index == obs.step_index
    assert listed_of(state) == listed


def test_heightmap_codec_is_exact():
    hm = np.random.default_rng(0).integers(0, 900, size=(31, 17)).astype(np.int32)
    assert np.array_equal(decode_heightmap(encode_heightmap(hm), (31, 17)), hm)


def test_read_states_names_file_and_line_and_skips_a_torn_last_line(cases, tmp_path):
    obs = _mid_episode(cases[0], 1)
    state = make_state("c", "easy", obs, propose(obs), "sdf", 0, "teacher")
    good = msgspec.json.encode(state).decode()
    path = tmp_path / "states.jsonl"
    path.write_text(good + "\n" + good[:40])  # a crash mid-line
    assert len(list(read_states(path))) == 1
    bad = json.loads(good)
    bad["step"] = "three"
    path.write_text(good + "\n" + json.dumps(bad) + "\n")
    with pytest.raises(ConfigError, match=r"states.jsonl:2: .*step"):
        list(read_states(path))


@pytest.mark.parametrize("teacher", TEACHERS)
def test_every_teacher_picks_a_listed_placement_or_says_none(cases, teacher):
    case = cases[3]
    obs = _mid_episode(case)
    cands = observation_candidates(obs)
    listed = propose(obs)
    t = ListedTeacher(teacher)
    t.reset(case, 0)
    i = t.choose(obs, cands, listed)
    assert -1 <= i < len(listed)
    if teacher not in ("oracle", "oracle-canonical"):
        assert i >= 0


def test_sdf_teacher_takes_sdf_own_action_when_it_is_listed(cases):
    hits = 0
    for case in cases:
        obs = _mid_episode(case, 1)
        own = make_policy("sdf")
        own.reset(case, 0)
        action = own.act(obs)
        listed = propose(obs)
        i = ListedTeacher("sdf").choose(obs, observation_candidates(obs), listed)
        if action in [c.action for c in listed]:
            hits += 1
            assert listed[i].action == action
    assert hits >= 2


def test_unknown_teacher_is_refused():
    with pytest.raises(ConfigError, match="teacher = 'nobody'"):
        ListedTeacher("nobody")
    with pytest.raises(ConfigError, match="teacher = 'nobody'"):
        DaggerConfig(out="x", teacher="nobody")


def test_listed_answers_are_valid_actions(cases):
    for case in cases:
        obs = _mid_episode(case, 1)
        mask = action_mask(observation_candidates(obs))
        for c in propose(obs):
            assert mask[c.object_index, c.rotation, c.x, c.y]


def test_collect_writes_labelled_states_and_resumes(cases, tmp_path):
    out = tmp_path / "r0" / "states.jsonl"
    seen = []
    n = collect(cases[:2], out, "sdf", "teacher", workers=1, progress=False,
                on_case=lambda c, o: seen.append(c))  # fmt: skip
    states = list(read_states(out))
    assert n == len(states) > 0 and len(seen) == 2
    assert {s.case_id for s in states} == {c.episode_id for c in cases[:2]}
    assert all(0 <= s.label < len(s.listed) and s.teacher == "sdf" for s in states)
    prints = {c.episode_id: case_fingerprint(c) for c in cases}
    assert all(s.case_sha256 == prints[s.case_id] for s in states)  # the content hash
    assert done_cases(out) == {c.episode_id for c in cases[:2]}
    again = collect(cases[:3], out, "sdf", "teacher", workers=1, progress=False)
    after = list(read_states(out))
    assert len(after) == len(states) + again  # only the third case was played
    assert {s.case_id for s in after[len(states) :]} == {cases[2].episode_id}


def test_export_holds_the_composed_messages_and_the_answer(cases, tmp_path):
    out = tmp_path / "states.jsonl"
    collect(cases[:1], out, "sdf", "teacher", workers=1, progress=False)
    states = list(read_states(out))
    n = export_chat_jsonl(states, tmp_path / "sft.jsonl")
    rows = [json.loads(line) for line in (tmp_path / "sft.jsonl").read_text().splitlines()]
    assert n == len(rows) == len(states)
    for s, row in zip(states, rows, strict=True):
        assert row["messages"][:2] == state_messages(s)
        assert row["messages"][2]["content"][0]["text"] == str(s.label)


def test_blank_map_hides_the_surface_only(cases):
    obs = _mid_episode(cases[3])
    s = make_state("c", "medium", obs, propose(obs), "sdf", 0, "teacher")
    plain = state_messages(s)[1]["content"][0]["text"]
    blank = state_messages(s, blank_map=True)[1]["content"][0]["text"]
    map_rows = lambda t: t.split("Boxes:")[0]
    assert map_rows(plain) != map_rows(blank) and set(map_rows(blank).split("\n", 2)[2]) <= {
        "0",
        "\n",
    }
    assert plain.split("Boxes:")[1] == blank.split("Boxes:")[1]


def test_split_cases_gives_disjoint_rounds_and_evaluation(cases):
    many = [c for d in ("easy", "medium") for c in generate_cases(d, 7, 2, False, domain="train")]
    rounds, evals = split_cases(many, per_round=4, rounds=1, eval_per_level=2)
    ids = [c.episode_id for r in rounds for c in r] + [c.episode_id for c in evals]
    assert len(ids) == len(set(ids)) == 4 + 4 + 4
    assert [c.difficulty for c in rounds[0]] == ["easy", "medium"] * 2
    with pytest.raises(ValueError, match="6 rounds of 4 cases need 15 cases per level; easy has 7"):
        split_cases(many, per_round=4, rounds=5, eval_per_level=3)


def test_shuffled_moves_the_label_with_its_placement_and_is_reproducible(cases):
    obs = _mid_episode(cases[3])
    listed = propose(obs)
    state = make_state("c", "medium", obs, listed, "sdf", 1, "teacher")
    a, b = shuffled(state, 0), shuffled(state, 0)
    assert a == b
    assert [p.index for p in a.listed] == list(range(len(listed)))
    assert listed_of(a)[a.label].action == listed[1].action
    assert {c.action for c in listed_of(a)} == {c.action for c in listed}
    orders = {tuple(c.action for c in listed_of(shuffled(state, s))) for s in range(6)}
    assert len(orders) > 1  # the seed changes the order


def test_collect_on_the_robot_path_labels_what_the_robot_is_shown(cases, tmp_path):
    # States from perceived + noisy MuJoCo episodes carry what perception showed (fresh
    # ids per observation, sizes measured off the depth image), not the case's boxes.
    out = tmp_path / "robot.jsonl"
    n = collect(cases[:1], out, "sdf", "robot", workers=1, progress=False,
                robot=RobotPath("stereo"))  # fmt: skip
    states = list(read_states(out))
    assert n == len(states) > 0
    true_ids = {str(o.internal_id) for o in cases[0].objects}
    shown = [box for s in states for box in s.shown]
    assert shown and not {str(b.internal_id) for b in shown} & true_ids
    exact = tmp_path / "exact.jsonl"
    collect(cases[:1], exact, "sdf", "exact", workers=1, progress=False)
    exact_shown = [box for s in read_states(exact) for box in s.shown]
    assert {str(b.internal_id) for b in exact_shown} <= true_ids
