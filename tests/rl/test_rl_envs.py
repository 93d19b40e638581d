"""The RL action-space envs, features and rewards (torch-free)."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from packlab.core.errors import ConfigError
from packlab.core.feasibility import footprint_fits, observation_candidates
from packlab.core.types import Observation
from packlab.datagen.generator import generate_cases
from packlab.policies import make_policy
from packlab.policies.candidates import ProposerConfig, propose
from packlab.policies.heuristics.policy import make_dblf
from packlab.rl import policy as rl_policy
from packlab.rl.config import RLTrainConfig
from packlab.rl.envs import CandidatePlacementEnv, ListedActionEnv, ObjectChoiceEnv
from packlab.rl.features import N_ITEM_FEATURES, FeatureSpec, encode, rule_placement
from packlab.rl.split import hold_out
from packlab.sim.episode import Episode, run_episode

AGENTS = ("irbpp", "tapnet")


@pytest.fixture(scope="module")
def cases():
    """Two generated cases per level: containers and buffers of every size the levels use."""
    return [c for level in ("easy", "medium", "hard") for c in generate_cases(level, 2, 7, False)]


def _random_episode(env: ListedActionEnv, rng: np.random.Generator, index: int):
    """(return, final info) of one episode with uniformly random allowed rows."""
    _, info = env.reset(seed=index, options={"case_index": index})
    total, done = 0.0, False
    while not done:
        mask = env.action_masks()
        assert mask.any(), "an unfinished episode always offers a choice"
        _, reward, done, _, info = env.step(int(rng.choice(np.flatnonzero(mask))))
        total += reward
    return total, info


@pytest.mark.parametrize("agent", AGENTS)
def test_spaces_pass_the_gymnasium_checker(agent, cases):
    check_env(ListedActionEnv(agent, cases), skip_render_check=True)


@pytest.mark.parametrize("agent", AGENTS)
def test_masks_allow_only_in_bounds_executable_actions(agent, cases):
    env = ListedActionEnv(agent, cases)
    rng = np.random.default_rng(0)
    for index in range(len(cases)):
        env.reset(seed=index, options={"case_index": index})
        episode = env._episode
        while not episode.done:
            mask, listed = env.action_masks(), env.listed_actions()
            assert mask.sum() == len(listed) and not mask[len(listed) :].any()
            for action in listed:
                item = episode.observe().shown[action.object_id]
                fx, fy = item.size_cells[:2][:: 1 if action.rotation == 0 else -1]
                assert footprint_fits(episode.heightmap.shape, action.x, action.y, fx, fy)
            _, _, _, _, info = env.step(int(rng.choice(np.flatnonzero(mask))))
            assert info["valid"], info


@pytest.mark.parametrize("agent", AGENTS)
@pytest.mark.parametrize("reward", ["overall", "overall-terminal"])
def test_overall_rewards_return_the_episode_overall(agent, reward, cases):
    env = ListedActionEnv(agent, cases, reward=reward)
    rng = np.random.default_rng(1)
    for index in range(len(cases)):
        total, info = _random_episode(env, rng, index)
        assert total == pytest.approx(info["metrics"]["overall"], abs=1e-12)
        assert 0 < total <= 1


@pytest.mark.parametrize("env_class", [CandidatePlacementEnv, ObjectChoiceEnv])
def test_perceived_noisy_modes_keep_the_return_equal_to_the_overall(env_class, cases):
    """The bench's modes on the RL envs: the agent sees the perceived state, the robot is
    noisy (mujoco), and the return is still the episode's true Overall."""
    easy = cases[:2]
    env = env_class(easy, backend="mujoco", observation="perceived", execution="noisy")
    check_env(env, skip_render_check=True)
    total, info = _random_episode(env, np.random.default_rng(2), 1)
    assert total == pytest.approx(info["metrics"]["overall"], abs=1e-12)
    assert env._episode.steps[-1].replan is not None  # perceived mode: re-plan flags logged
    with pytest.raises(ConfigError, match="noise"):
        env_class(easy, observation="perceived", noise="lidar")


def test_success_reward_returns_the_success_ratio(cases):
    env = CandidatePlacementEnv(cases, reward="success")
    total, info = _random_episode(env, np.random.default_rng(2), 3)
    assert total == pytest.approx(info["metrics"]["success_ratio"], abs=1e-12)


def test_potential_reward_is_dense(cases):
    env = ObjectChoiceEnv(cases)
    env.reset(seed=0, options={"case_index": 4})
    _, reward, done, _, _ = env.step(int(np.flatnonzero(env.action_masks())[0]))
    assert not done and reward > 0  # the first placement already scores


def test_candidate_rows_are_the_proposer_list(cases):
    observation = Episode("geometric").reset(cases[2], 0)
    encoded = encode(observation, FeatureSpec.default("irbpp", 6))
    assert encoded.actions == tuple(c.action for c in propose(observation, ProposerConfig(k=6)))
    assert encoded.arrays["items"].shape == (6, N_ITEM_FEATURES) and N_ITEM_FEATURES == 32


def test_object_rows_place_each_object_by_dblf(cases):
    """Each object-choice row is DBLF's action for a buffer holding that object alone."""
    episode = Episode("geometric")
    observation = episode.reset(cases[4], 0)
    episode.step(make_dblf().act(observation))  # a non-empty floor
    observation = episode.observe()
    rows = encode(observation, FeatureSpec.default("tapnet", placement="dblf")).actions
    assert len(rows) == len(observation.shown)
    for shown, row in zip(observation.shown, rows):
        alone = Observation(0, observation.container, observation.heightmap,
                            (replace(shown, shown_index=0),))  # fmt: skip
        assert replace(row, object_id=0) == make_dblf().act(alone)
        assert rule_placement(observation_candidates(alone), 0) is not None


def test_object_rows_place_each_object_at_its_first_proposer_listing(cases):
    """The default rule: each object where the proposer lists it first."""
    episode = Episode("geometric")
    observation = episode.reset(cases[4], 0)
    episode.step(make_dblf().act(observation))
    observation = episode.observe()
    rows = encode(observation, FeatureSpec.default("tapnet")).actions
    listed = propose(observation, ProposerConfig(k=64))
    assert len(rows) == len(observation.shown) and len({r.object_id for r in rows}) == len(rows)
    for row in rows:
        first = next(c for c in listed if c.object_index == row.object_id)
        assert row == first.action
    dblf_rows = encode(observation, FeatureSpec.default("tapnet", placement="dblf")).actions
    assert rows != dblf_rows  # the rule is not ignored


def test_features_are_bounded_and_padded(cases):
    for agent in AGENTS:
        env = ListedActionEnv(agent, cases)
        obs, _ = env.reset(seed=0, options={"case_index": 5})  # a hard case
        assert env.observation_space.contains(obs)
        items = obs["items"]
        real = env.action_masks()
        assert (items[~real] == 0).all() and (items[real, 0] == 1).all()


def test_hold_out_keeps_the_first_cases_of_each_level(cases):
    train, held = hold_out(cases, 1)
    assert [c.episode_id for c in held] == [cases[0].episode_id, cases[2].episode_id,
                                            cases[4].episode_id]  # fmt: skip
    assert len(train) == 3
    with pytest.raises(ConfigError, match="leaves none to train on"):
        hold_out(cases, 2)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"agent": "ppo"}, "agent"),
        ({"reward": "volume"}, "reward"),
        ({"steps": 0}, "steps"),
        ({"lr": 2.0}, "lr"),
        ({"gamma": 1.5}, "gamma"),
    ],
)
def test_bad_training_config_names_the_field(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        RLTrainConfig(**kwargs)


def test_rl_policies_build_without_importing_torch():
    code = (
        "import sys, packlab.policies as p; p.make_policy('irbpp'); p.make_policy('tapnet');"
        "p.make_policy('irbpp-random'); assert 'torch' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_random_row_baselines_play_valid_seeded_episodes(cases):
    for name in ("irbpp-random", "tapnet-random"):
        first = run_episode(cases[2], make_policy(name), seed=3, backend="geometric")
        again = run_episode(cases[2], make_policy(name), seed=3, backend="geometric")
        assert all(s.valid for s in first.steps)
        assert [s.action for s in first.steps] == [s.action for s in again.steps]


def test_missing_shipped_agent_says_how_to_train_one(monkeypatch, tmp_path, cases):
    pytest.importorskip("sb3_contrib")
    monkeypatch.setattr(rl_policy, "SHIPPED_MODELS", tmp_path)
    with pytest.raises(ConfigError, match="packlab train rl --agent tapnet"):
        make_policy("tapnet").reset(cases[0], 0)
