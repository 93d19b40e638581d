"""RunConfig validation and resolution: bad input is one clear error naming the field."""

from __future__ import annotations

import pytest

from packlab.bench.config import RunConfig, check_resumable, default_policies, parse_seeds, resolve
from packlab.core.errors import ConfigError


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"seeds": ()}, "seeds"),
        ({"seeds": (0, 0)}, "repeated"),
        ({"seeds": (-1,)}, "non-negative"),
        ({"backend": "bullet"}, "backend = 'bullet'"),
        ({"executor": "dask"}, "executor = .dask."),
        ({"workers": -1}, "workers"),
        ({"policies": ("dblf", "nope")}, "'nope' is not a registered policy"),
        ({"policies": ("dblf", "dblf")}, "repeated"),
    ],
)
def test_bad_values_are_one_line_errors(kwargs, match):
    with pytest.raises(ConfigError, match=match) as err:
        RunConfig(**kwargs)
    assert "\n" not in str(err.value)


def test_parse_seeds():
    assert parse_seeds("0,1,2") == (0, 1, 2)
    assert parse_seeds("3-5") == (3, 4, 5)
    with pytest.raises(ConfigError, match="seeds = 'a'"):
        parse_seeds("a")


def test_resolve_fills_defaults(tiny_suite, tmp_path):
    run = resolve(RunConfig(cases=str(tiny_suite), backend="geometric"))
    assert run.policies == default_policies(run.cases)
    assert "oracle" in run.policies and "random" in run.policies
    # The shipped learned policies play by default (ONNX, core install); the text-answer VLM,
    # a server endpoint and the proposer only when named.
    assert {"vlm", "irbpp", "tapnet"} <= set(run.policies)
    assert not {"vlm-small", "endpoint", "proposer", "plan"} & set(run.policies)
    assert run.difficulties == ("easy", "hard")
    assert str(run.out).endswith("bench-tiny") and run.workers >= 1 and run.physics is None
    mj = resolve(RunConfig(cases=str(tiny_suite)))
    assert mj.physics and mj.physics_config().max_settle_steps == mj.physics["max_settle_steps"]


def test_difficulty_filter_and_unknown_difficulty(tiny_suite):
    run = resolve(RunConfig(cases=str(tiny_suite), backend="geometric", difficulties=("hard",)))
    assert {c.difficulty for c in run.cases} == {"hard"} and len(run.cases) == 2
    with pytest.raises(ConfigError, match="difficulty = 'medium'.*present: easy, hard"):
        resolve(RunConfig(cases=str(tiny_suite), backend="geometric", difficulties=("medium",)))


def test_identity_mismatch_names_the_field(tmp_path):
    with pytest.raises(ConfigError, match="field 'seeds' = \\[0\\] here, \\[0, 1\\] now"):
        check_resumable(
            {"format": "x", "seeds": [0]},
            {"format": "x", "seeds": [0, 1]},
            tmp_path / "config.json",
        )
    with pytest.raises(ConfigError, match="'physics.impratio' = '<absent>' here, 1.0 now") as err:
        check_resumable(
            {"physics": {"a": 1, "b": 2}},
            {"physics": {"a": 1, "b": 2, "impratio": 1.0}},
            tmp_path / "config.json",
        )
    assert "'physics.a'" not in str(err.value)


def test_physics_overrides_are_typed_checked_and_part_of_the_identity(tiny_suite):
    from packlab.bench.config import parse_physics

    overrides = parse_physics(["max_settle_steps=1000", "sleep=false", "friction=0.4"])
    assert overrides == (("max_settle_steps", 1000), ("sleep", False), ("friction", 0.4))
    run = resolve(RunConfig(cases=str(tiny_suite), physics_overrides=overrides))
    assert (
        run.to_json()["physics"]["max_settle_steps"] == 1000 and run.physics_config().sleep is False
    )
    with pytest.raises(ConfigError, match="'nope' is not a PhysicsConfig field"):
        resolve(RunConfig(cases=str(tiny_suite), physics_overrides=(("nope", 1),)))
    with pytest.raises(ConfigError, match="only the mujoco backend"):
        RunConfig(backend="geometric", physics_overrides=overrides)
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        parse_physics(["max_settle_steps"])


def test_policy_args_parse_and_must_name_a_policy_that_runs(tiny_suite):
    from packlab.bench.config import parse_policy_args

    assert parse_policy_args(["vlm:model=runs/x", "vlm:max_new_tokens=32"]) == (
        ("vlm", "model", "runs/x"),
        ("vlm", "max_new_tokens", 32),
    )
    with pytest.raises(ConfigError, match="POLICY:KEY=VALUE"):
        parse_policy_args(["vlm=model"])
    with pytest.raises(ConfigError, match="'endpoint' is not among the policies to run"):
        resolve(
            RunConfig(
                cases=str(tiny_suite),
                backend="geometric",
                policy_args=(("endpoint", "model", "x"),),
            )
        )


def test_cases_without_a_plan_leave_the_oracle_out_by_default(tmp_path):
    from dataclasses import replace

    from bench_helpers import tiny_cases

    from packlab.cases import save_cases

    path = tmp_path / "noplan.jsonl"
    save_cases([replace(c, gt_plan=None) for c in tiny_cases()], path)
    run = resolve(RunConfig(cases=str(path), backend="geometric"))
    assert "oracle" not in run.policies and "dblf" in run.policies
