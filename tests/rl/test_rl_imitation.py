"""Imitation warm-start: targets, behaviour cloning, the saved agent, ``--init`` and the CLI."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("sb3_contrib")

import torch

from packlab.cases.fingerprint import case_fingerprint
from packlab.cli.main import main
from packlab.core.errors import ConfigError
from packlab.core.feasibility import observation_candidates
from packlab.core.types import Action
from packlab.datagen.generator import generate_cases
from packlab.policies import make_policy
from packlab.policies.candidates import propose
from packlab.policies.provenance import dir_sha256, file_sha256
from packlab.rl.agent import load_agent
from packlab.rl.config import ImitationConfig, RLTrainConfig
from packlab.rl.envs import ListedActionEnv
from packlab.rl.evaluate import play
from packlab.rl.features import FeatureSpec, encode
from packlab.rl.imitation import Demo, imitation_sample, imitation_samples
from packlab.rl.imitation_fit import collate, imitate, row_logits
from packlab.rl.train import load_init, make_model
from packlab.sim.episode import Episode
from packlab.vlm.candidate.states import append_states, make_state


@pytest.fixture(scope="module")
def hard_case():
    return generate_cases("hard", 1, 5, False, domain="train")[0]


def _observations(case, policy="proposer", steps=30):
    """Observations along ``policy``'s own episode (geometric) and its actions."""
    episode, pol = Episode("geometric"), make_policy(policy)
    observation = episode.reset(case, 0)
    pol.reset(case, 0)
    out = []
    while not episode.done and len(out) < steps:
        action = pol.act(observation)
        out.append((observation, action))
        episode.step(action)
        if not episode.done:
            observation = episode.observe()
    return out


def _as_action(c) -> Action:
    return Action(c.object_index, c.rotation, c.x, c.y)


def test_irbpp_target_is_the_row_with_the_teachers_placement(hard_case):
    observation, _ = _observations(hard_case)[0]
    spec = FeatureSpec.default("irbpp")
    encoded = encode(observation, spec)
    sample = imitation_sample(Demo(observation, encoded.actions[3]), spec)
    assert sample.items.shape[0] == len(encoded.actions)
    assert int(np.argmax(sample.target)) == 3 and sample.target.sum() == pytest.approx(1.0)
    assert np.array_equal(sample.items, encoded.arrays["items"][: len(encoded.actions)])


def test_irbpp_teacher_placement_not_listed_is_added_as_an_extra_row(hard_case):
    observation, _ = _observations(hard_case)[0]
    spec = FeatureSpec.default("irbpp")
    encoded = encode(observation, spec)
    cands = observation_candidates(observation)
    listed = set(encoded.actions)
    i = next(
        i
        for i in range(len(cands))
        if Action(int(cands.obj[i]), int(cands.rotation[i]), int(cands.x[i]), int(cands.y[i]))
        not in listed
    )
    teacher = Action(int(cands.obj[i]), int(cands.rotation[i]), int(cands.x[i]), int(cands.y[i]))
    sample = imitation_sample(Demo(observation, teacher), spec)
    assert sample.added and sample.items.shape[0] == len(encoded.actions) + 1
    assert int(np.argmax(sample.target)) == len(encoded.actions)
    row = sample.items[-1]
    assert row[0] == 1.0 and row[7] == pytest.approx(
        int(cands.z[i]) / observation.container.height_mm
    )


def test_irbpp_soft_target_follows_the_preference(hard_case):
    observation, _ = _observations(hard_case)[0]
    spec = FeatureSpec.default("irbpp")
    acts = encode(observation, spec).actions
    soft = ((acts[1], 3.0), (acts[4], 1.0))
    sample = imitation_sample(Demo(observation, acts[1], soft), spec)
    assert sample.target[1] == pytest.approx(0.75) and sample.target[4] == pytest.approx(0.25)


def test_tapnet_target_spreads_over_shown_boxes_of_identical_size(hard_case):
    observation, _ = _observations(hard_case)[0]
    shown = list(observation.shown)
    l, w, h = shown[0].size_mm
    # box 1 becomes box 0 turned (same sides, another order): interchangeable with it
    shown[1] = dataclasses.replace(
        shown[1],
        size_mm=(w, l, h),
        size_cells=(shown[0].size_cells[1], shown[0].size_cells[0], shown[0].size_cells[2]),
    )
    observation = dataclasses.replace(observation, shown=tuple(shown))
    spec = FeatureSpec.default("tapnet")
    encoded = encode(observation, spec)
    objects = [a.object_id for a in encoded.actions]
    assert 0 in objects and 1 in objects
    sample = imitation_sample(Demo(observation, encoded.actions[objects.index(0)]), spec)
    assert sample.target[objects.index(0)] == pytest.approx(0.5)
    assert sample.target[objects.index(1)] == pytest.approx(0.5)
    assert sample.target.sum() == pytest.approx(1.0)


def _demos(case, agent="irbpp"):
    return [Demo(o, a) for o, a in _observations(case, "dblf")]


def test_short_imitation_lowers_the_loss_and_saves_a_playable_agent(hard_case, tmp_path):
    spec = FeatureSpec.default("irbpp")
    samples = imitation_samples(_demos(hard_case), spec)
    cfg = ImitationConfig(agent="irbpp", out=str(tmp_path / "m"), epochs=30, batch=16, lr=3e-3)
    result = imitate(samples, cfg, "test")
    assert result.losses[-1] < result.losses[0] - 0.2, result.losses
    loaded = load_agent(tmp_path / "m")
    assert loaded.card.agent == "irbpp" and loaded.card.n_items == spec.n_items
    assert loaded.card.cores >= 1 and loaded.card.wall_time_s > 0  # the time and where
    # exported to ONNX, so the default runtime plays it (the same actions as torch)
    onnx = make_policy("irbpp", model=str(tmp_path / "m"))
    torch_ = make_policy("irbpp", model=str(tmp_path / "m"), runtime="torch")
    observations = [o for o, _ in _observations(hard_case, steps=12)]
    assert [onnx.act(o) for o in observations] == [torch_.act(o) for o in observations]
    assert 0.0 < play(loaded.model, loaded.card.spec, hard_case).overall <= 1.0
    # the saved network scores the rows as the fitted one did (extra rows included)
    with torch.no_grad():
        logits = row_logits(loaded.model.policy, collate(samples[:4]))
    assert logits.shape[0] == 4 and torch.isfinite(logits.max(-1).values).all()


def test_init_loads_the_imitation_weights_and_refuses_another_agent(hard_case, tmp_path):
    samples = imitation_samples(_demos(hard_case), FeatureSpec.default("tapnet"))
    imitate(samples, ImitationConfig(agent="tapnet", out=str(tmp_path / "m"), epochs=2), "t")
    source = load_agent(tmp_path / "m").model.policy.state_dict()
    for agent in ("tapnet", "irbpp"):
        cfg = RLTrainConfig(agent=agent, out=str(tmp_path / agent), envs=1, vec="dummy")
        model = make_model(cfg, ListedActionEnv(agent, [hard_case]), tmp_path)
        spec = FeatureSpec.default(agent)
        if agent == "irbpp":
            with pytest.raises(ConfigError, match="tapnet"):
                load_init(model, tmp_path / "m", spec)
            continue
        load_init(model, tmp_path / "m", spec)
        for name, tensor in model.policy.state_dict().items():
            assert torch.equal(tensor, source[name]), name


def test_imitation_from_init_starts_at_its_weights_and_records_it(hard_case, tmp_path):
    """A DAgger round on a trained agent: the fit starts from ``init``'s weights (its first
    epoch's loss is the trained agent's, lower than fresh weights'), and the card names it."""
    samples = imitation_samples(_demos(hard_case), FeatureSpec.default("irbpp"))
    base: dict = {"agent": "irbpp", "batch": 16, "lr": 3e-3}
    imitate(samples, ImitationConfig(out=str(tmp_path / "a"), epochs=20, **base), "t")
    fresh = imitate(samples, ImitationConfig(out=str(tmp_path / "f"), epochs=1, **base), "t")
    cfg = ImitationConfig(out=str(tmp_path / "b"), epochs=1, init=str(tmp_path / "a"), **base)
    warm = imitate(samples, cfg, "t")
    assert warm.losses[0] < fresh.losses[0] - 0.2, (warm.losses, fresh.losses)
    card = load_agent(tmp_path / "b").card
    assert card.init is not None and card.init["sha256"] == dir_sha256(tmp_path / "a")
    assert load_agent(tmp_path / "f").card.init is None
    with pytest.raises(ConfigError, match="irbpp"):  # a tapnet fit cannot start from irbpp
        tap = ImitationConfig(agent="tapnet", out=str(tmp_path / "t"), init=str(tmp_path / "a"))
        imitate(imitation_samples(_demos(hard_case), FeatureSpec.default("tapnet")), tap, "t")


def test_cli_imitates_from_states_then_trains_from_init(hard_case, tmp_path):
    states = tmp_path / "states.jsonl"
    lines = []
    for observation, _ in _observations(hard_case, steps=8):
        listed = propose(observation)
        lines.append(
            make_state(hard_case.episode_id, "hard", observation, listed, "t", 1, "teacher",
                       case_sha256=case_fingerprint(hard_case))
        )  # fmt: skip
    append_states(states, lines)
    out = tmp_path / "imit"
    args = ["train", "rl-imitate", "--agent", "irbpp", "--states", str(states)]
    assert main([*args, "--out", str(out), "--epochs", "2", "--seed", "3"]) == 0
    card = load_agent(out).card
    assert card.cases == "imitation" and card.seed == 3 and card.selection is None
    assert card.states == [{"path": "states.jsonl", "sha256": file_sha256(states)}]
    cases = tmp_path / "cases.jsonl"
    from packlab.cases import save_cases

    save_cases(generate_cases("easy", 2, 9, False, domain="train"), cases)
    run = ["train", "rl", "--agent", "irbpp", "--cases", str(cases), "--steps", "64"]
    run += ["--n-steps", "32", "--batch", "32", "--envs", "1", "--vec", "dummy"]
    run += ["--eval-cases", "1", "--out", str(tmp_path / "run"), "--init", str(out)]
    assert main(run) == 0
    assert (tmp_path / "run" / "final" / "model.zip").is_file()
    ppo = load_agent(tmp_path / "run" / "final").card
    assert ppo.init == {"path": "imit", "sha256": dir_sha256(out)}  # a name, not a path
    assert ppo.cases == "cases.jsonl" and ppo.seed == 0
    assert (
        ppo.selection is not None and ppo.selection["n"] == 1 and "best/" in ppo.selection["rule"]
    )


def test_states_of_non_training_cases_are_refused(hard_case, tmp_path):
    from packlab.cli.train_rl import demos_from_states

    observation, _ = _observations(hard_case, steps=1)[0]
    state = make_state("bench-hard-00001", "hard", observation, propose(observation), "t", 0, "x",
                       case_sha256=case_fingerprint(hard_case))  # fmt: skip
    append_states(tmp_path / "s.jsonl", [state])
    with pytest.raises(ConfigError, match="training-domain"):
        demos_from_states(tmp_path / "s.jsonl")
