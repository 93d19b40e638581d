"""Execution noise (``packlab.sim.execution``) and noisy drops on the mujoco backend."""

from __future__ import annotations

import numpy as np
import pytest
from layered_cases import make_layered_case

from packlab.core.errors import ConfigError
from packlab.policies import make_policy
from packlab.sim.episode import Episode, run_episode
from packlab.sim.execution import (
    EXACT_DROP,
    EXECUTION_PRESETS,
    ExecutionNoise,
    execution_noise,
    perturb_drop,
)

NOISY = ExecutionNoise(xy_sigma_mm=5.0, yaw_sigma_deg=3.0, release_mm=10.0, comply_mm=10.0)


def _drops(noise: ExecutionNoise, seed: int, n: int = 20):
    rng = np.random.default_rng(seed)
    return [perturb_drop(noise, rng) for _ in range(n)]


def test_zero_noise_is_the_exact_drop_and_presets_grow():
    assert _drops(ExecutionNoise(), 0) == [EXACT_DROP] * 20
    assert execution_noise("none").is_zero
    sigmas = [EXECUTION_PRESETS[p].xy_sigma_mm for p in ("none", "structured-light", "stereo")]
    assert sigmas == sorted(sigmas) and sigmas[0] == 0 < sigmas[1]


def test_perturbation_is_seeded_and_moves_the_drop():
    a, b, c = _drops(NOISY, 3), _drops(NOISY, 3), _drops(NOISY, 4)
    assert a == b and a != c
    offsets = np.array([d.offset_mm for d in a])
    assert np.abs(offsets).max() > 1.0 and {d.release_mm for d in a} == {10.0}
    assert np.abs([d.yaw_deg for d in a]).max() > 0.5


def test_offsets_are_the_noise_alone_nothing_clamps_or_corrects_them():
    # The executed drop is the arm's noise minus the grasp error, whatever lies
    # around; a box the noise pushes into a wall is slid off it by the place skill's descent.
    big = ExecutionNoise(xy_sigma_mm=50.0, yaw_sigma_deg=5.0)
    draws = np.random.default_rng(0).normal(size=(200, 3))
    rng = np.random.default_rng(0)
    for dx, dy, dyaw in draws:
        d = perturb_drop(big, rng, (1.0, -2.0, 0.5))
        assert d.offset_mm == pytest.approx((dx * 50.0 - 1.0, dy * 50.0 + 2.0))
        assert d.yaw_deg == pytest.approx(dyaw * 5.0 - 0.5)


@pytest.mark.parametrize("field", ["xy_sigma_mm", "yaw_sigma_deg", "release_mm", "comply_mm"])
def test_bad_noise_is_refused_by_name(field):
    with pytest.raises(ConfigError, match=field):
        ExecutionNoise(**{field: -1.0})
    with pytest.raises(ConfigError, match="noise"):
        execution_noise("laser")  # type: ignore[arg-type]


def test_geometric_backend_refuses_noisy_execution():
    episode = Episode("geometric", execution=NOISY)
    with pytest.raises(ConfigError, match="execution = 'noisy'.*geometric"):
        episode.reset(make_layered_case(0), 0)


def _record(result):
    rec = result.to_record()
    rec.pop("policy_time_s")
    rec["metrics"].pop("wall_time_s")
    for step in rec["steps"]:
        for timed in ("wall_time_s", "decision_s", "decision_cpu_s"):  # clocks differ
            step.pop(timed)
    return rec


@pytest.mark.physics
def test_zero_noise_execution_is_exact_execution():
    case = make_layered_case(1, pieces=5)
    exact = run_episode(case, make_policy("dblf"), 0, backend="mujoco")
    zero = run_episode(case, make_policy("dblf"), 0, backend="mujoco", execution=ExecutionNoise())
    rec = _record(zero)
    assert all(s.pop("executed") == [0.0, 0.0, 0.0, 0.0] for s in rec["steps"] if s["valid"])
    # Noisy execution counts what the place skill did: nothing, every drop exact.
    assert rec["metrics"].pop("skill") == {}
    assert all("skill" not in s for s in rec["steps"])
    assert rec == _record(exact)


@pytest.mark.physics
def test_noisy_execution_is_seeded_and_lands_boxes_off_plan():
    case = make_layered_case(1, pieces=5)
    runs = [
        run_episode(case, make_policy("dblf"), seed, backend="mujoco", execution=NOISY)
        for seed in (0, 0, 1)
    ]
    assert _record(runs[0]) == _record(runs[1])
    assert _record(runs[0]) != _record(runs[2])
    exact = run_episode(case, make_policy("dblf"), 0, backend="mujoco")
    # Same decisions on the first step (same observation), but the box settles elsewhere.
    first_exact, first_noisy = exact.steps[0], runs[0].steps[0]
    assert first_noisy.drop_mm == first_exact.drop_mm
    moved = np.abs(first_noisy.positions_mm - first_exact.positions_mm)
    assert np.nanmax(moved) > 0.5
    assert {len(s.to_record()["executed"]) for s in runs[0].steps if s.valid} == {4}


# The place skill (comply and seat) is tested in test_place_skill.py.
