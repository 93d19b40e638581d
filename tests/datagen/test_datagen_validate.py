"""Replay validation: plan checks, rejection reasons, and the mujoco replay of generated plans."""

from __future__ import annotations

from dataclasses import replace

import pytest
from datagen_helpers import make_dataset, tiny_config, tree_bytes

from packlab.datagen.config import CaseConfig, ValidationConfig
from packlab.datagen.generator import build_case
from packlab.datagen.seeds import case_seed
from packlab.datagen.validate import check_case, judge, plan_problems, replay


def _case(difficulty="medium", slot=0, layout="layered"):
    return build_case(
        case_seed(12, "train", difficulty, slot), difficulty, CaseConfig(layout=layout)
    )


def test_plan_problems_catch_broken_plans():
    case = _case()
    assert plan_problems(case) == []
    plan = list(case.gt_plan)
    moved = replace(plan[0], x=plan[0].x + 1, cell_min=(plan[0].x + 1, *plan[0].cell_min[1:]))
    assert plan_problems(replace(case, gt_plan=(moved, *plan[1:])))
    swapped = replace(case, gt_plan=tuple(reversed(plan)), objects=tuple(reversed(case.objects)))
    assert any("drops to" in p for p in plan_problems(swapped))  # top objects first: unsupported
    assert plan_problems(replace(case, gt_plan=None)) == ["case has no gt_plan"]
    assert (
        check_case(replace(case, gt_plan=(moved, *plan[1:])), ValidationConfig()).reason
        == "plan_check"
    )


def test_judge_reasons():
    trajectory = replay(_case(), backend="geometric")
    assert judge(trajectory, 0.99) == ""
    bad_step = replace(
        trajectory,
        valid=(False, *trajectory.valid[1:]),
        reasons=("out_of_bounds", *trajectory.reasons[1:]),
    )
    assert judge(bad_step, 0.99) == "invalid_step:out_of_bounds"
    low = replace(trajectory, metrics=replace(trajectory.metrics, overall=0.9))
    assert judge(low, 0.99) == "overall_below_min"


def test_replay_records_what_the_policy_saw():
    case = _case("hard", 1)
    t = replay(case, backend="geometric", run_seed=3)
    assert len(t.steps) == len(case.objects) and all(t.valid)
    assert t.steps[0].heightmap.max() == 0
    assert [s.remaining for s in t.steps] == list(range(len(case.objects), 0, -1))
    assert all(len(s.shown) == min(case.buffer_size, s.remaining) for s in t.steps)


@pytest.mark.physics
@pytest.mark.parametrize("layout", ["layered", "stepped"])
def test_mujoco_replay_accepts_generated_plans(layout):
    for difficulty in ("easy", "medium", "hard"):
        for slot in range(3):
            verdict = check_case(
                _case(difficulty, slot, layout), ValidationConfig(backend="mujoco")
            )
            assert verdict.accepted, (difficulty, slot, verdict.reason)
            assert verdict.trajectory.metrics.overall >= 0.99


@pytest.mark.physics
def test_physics_dataset_is_byte_identical(tmp_path):
    cfg = tiny_config(episodes=(2, 1, 1), validation=ValidationConfig(backend="mujoco"))
    make_dataset(tmp_path / "a", cfg)
    make_dataset(tmp_path / "b", cfg)
    assert tree_bytes(tmp_path / "a") == tree_bytes(tmp_path / "b")
