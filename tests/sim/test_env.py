"""The Gymnasium adapter: registered id, check_env, reward accounting and determinism."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from layered_cases import make_layered_case

import packlab.sim.env  # noqa: F401  (registers the id)
from packlab.core.errors import ConfigError
from packlab.sim.env import ENV_ID, PackEnv


def test_check_env_on_registered_id():
    env = gym.make(ENV_ID)
    check_env(env.unwrapped, skip_render_check=True)


def _masked_rollout(env, seed):
    obs, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    total, trace = 0.0, [info["case_id"]]
    done = False
    while not done:
        valid = np.flatnonzero(obs["action_mask"])
        action = int(rng.choice(valid))
        obs, reward, done, _truncated, info = env.step(action)
        total += reward
        trace.append((action, round(reward, 12)))
    return total, info, trace


def test_return_equals_final_success_ratio_and_masked_actions_are_valid():
    cases = [
        make_layered_case(s, cells=(20, 16), layer_heights_mm=(100, 80), pieces=4) for s in range(3)
    ]
    env = PackEnv(cases, backend="geometric")
    total, info, _ = _masked_rollout(env, seed=4)
    assert info["valid"]
    assert total == pytest.approx(info["metrics"]["success_ratio"])


def test_same_seed_same_rollout_and_action_round_trip():
    env = PackEnv(backend="geometric")
    assert _masked_rollout(env, 9)[2] == _masked_rollout(env, 9)[2]
    a = env.decode_action(12345 % env.action_space.n)
    assert env.encode_action(a) == 12345 % env.action_space.n


def test_render_rgb_array():
    env = PackEnv(backend="geometric", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8


def _full_recomputation_rollout(env, case_index, seed):
    """Step ``env`` with masked and some invalid actions; check each reward against the change
    in ``Episode.metrics().success_ratio`` (the full recomputation the reward used to be)."""
    obs, _ = env.reset(seed=seed, options={"case_index": case_index})
    rng = np.random.default_rng(seed)
    before, total, done, info = 0.0, 0.0, False, {}
    while not done:
        valid = np.flatnonzero(obs["action_mask"])
        if valid.size and rng.random() < 0.8:
            action = int(rng.choice(valid))
        else:
            action = int(rng.integers(env.action_space.n))  # may be out of bounds or a bad id
        obs, reward, done, _, info = env.step(action)
        full = env._episode.metrics().success_ratio
        assert reward == full - before  # exactly the same float, not approximately
        before, total = full, total + reward
    assert total == pytest.approx(info["metrics"]["success_ratio"])


#: (case, rollout seed) pairs: small layered cases, plus one with a low rim where, on MuJoCo, a
#: late placement knocks a box out of the container (a negative reward).
_REWARD_ROLLOUTS = [
    *(
        (make_layered_case(s, cells=(12, 10), layer_heights_mm=(100, 80), pieces=3), 10 + s)
        for s in range(3)
    ),
    (
        make_layered_case(2, cells=(12, 10), layer_heights_mm=(100, 80, 80), pieces=3, rim_mm=200),
        10,
    ),
]


@pytest.mark.parametrize(
    "backend", ["geometric", pytest.param("mujoco", marks=pytest.mark.physics)]
)
def test_incremental_reward_equals_full_recomputation(backend):
    env = PackEnv([case for case, _ in _REWARD_ROLLOUTS], backend=backend)
    for i, (_, seed) in enumerate(_REWARD_ROLLOUTS):
        _full_recomputation_rollout(env, case_index=i, seed=seed)


def test_perceived_and_noisy_modes_through_gym_make():
    """The bench's modes on the Gymnasium env: check_env passes, a masked rollout runs, the
    noise-free perceived env sees the exact state, and a re-plan flag comes with each step."""
    cases = [make_layered_case(s, cells=(16, 12), pieces=4) for s in range(2)]
    env = gym.make(
        ENV_ID,
        cases=cases,
        backend="mujoco",
        observation="perceived",
        execution="noisy",
        noise="structured-light",
    )
    check_env(env.unwrapped, skip_render_check=True)
    _total, info, _ = _masked_rollout(env.unwrapped, seed=1)
    assert isinstance(info["replan"], bool) and "metrics" in info
    exact = PackEnv(cases, backend="mujoco")
    clean = PackEnv(cases, backend="mujoco", observation="perceived", noise="none")
    # A perfect sensor sees the exact heightmap and sizes, each box's longer side first (which
    # side a catalogue calls l is a label no camera sees), listed in its own order (the
    # segments' in the buffer image), and its episodes run to the end.
    exact_obs, _ = exact.reset(seed=3)
    clean_obs, _ = clean.reset(seed=3)
    np.testing.assert_array_equal(clean_obs["heightmap"], exact_obs["heightmap"])
    long_first = exact_obs["buffer"].copy()
    long_first[:, :2] = np.sort(long_first[:, :2], axis=1)[:, ::-1]

    def rows(buffer):
        return sorted(map(tuple, np.asarray(buffer).tolist()))

    assert rows(clean_obs["buffer"]) == rows(long_first)
    total, info, _ = _masked_rollout(clean, 3)
    assert total == pytest.approx(info["metrics"]["success_ratio"])
    with pytest.raises(ConfigError, match="observation"):
        PackEnv(cases, observation="seen")


def test_buffer_names_sides_longer_first_by_default_and_catalogue_on_request():
    """The env's exact observation names sides as the bench does (longer first by default);
    ``sides="catalogue"`` shows the case's own (l, w, h), the reference paper's protocol. The
    RL training env takes the same switch."""
    from packlab.rl.envs import ListedActionEnv

    case = make_layered_case(2, pieces=5)
    assert any(b.size_mm[0] < b.size_mm[1] for b in case.objects)
    default, catalogue = PackEnv([case]), PackEnv([case], sides="catalogue")
    named, _ = default.reset(seed=0)
    own, _ = catalogue.reset(seed=0)
    shown = named["buffer"][named["buffer_mask"] == 1]
    assert (shown[:, 0] >= shown[:, 1]).all()
    assert sorted(map(tuple, own["buffer"][own["buffer_mask"] == 1])) == sorted(
        tuple(case.box_by_id(s.internal_id).size_mm) for s in catalogue._episode.observe().shown
    )
    assert (own["buffer"] != named["buffer"]).any()
    assert ListedActionEnv("irbpp", [case])._episode._sides == "longer-first"
    assert ListedActionEnv("irbpp", [case], sides="catalogue")._episode._sides == "catalogue"


@pytest.mark.parametrize("size_prior", ["grid", "none"])
def test_the_perceived_env_takes_the_size_prior(size_prior):
    """Pack-v0 and the RL agents' env pass ``size_prior`` to perception: off-grid cartons are
    shown snapped to the 25 mm / 2 mm grids with ``grid`` and as measured with ``none``."""
    from packlab.datagen.config import CaseConfig
    from packlab.datagen.generator import build_case
    from packlab.rl.envs import ListedActionEnv

    case = build_case(2**51 + 17, "easy", CaseConfig(sizes="off-grid"))
    env = PackEnv([case], observation="perceived", noise="none", size_prior=size_prior)
    obs, _ = env.reset(seed=0)
    sizes = obs["buffer"][obs["buffer_mask"] == 1]
    on_grid = (sizes[:, :2] % 25 == 0).all() and (sizes[:, 2] % 2 == 0).all()
    assert on_grid == (size_prior == "grid")
    rl_env = ListedActionEnv("irbpp", [case], observation="perceived", noise="none",
                             size_prior=size_prior)  # fmt: skip
    rl_env.reset(seed=0)
    listed = np.array([s.size_mm for s in rl_env._episode.observe().shown])
    assert (listed[:, :2] % 25 == 0).all() == (size_prior == "grid")
    with pytest.raises(ConfigError, match="size_prior"):
        PackEnv([case], observation="perceived", size_prior="cm")
