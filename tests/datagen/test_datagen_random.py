"""The ``random`` layout family: drawn boxes within the size rules, no ``gt_plan``,
total volume under the fill target; episodes run with every heuristic and ``plan-fast``."""

from __future__ import annotations

import hashlib
import json

import pyarrow.parquet as pq
import pytest
from datagen_helpers import make_dataset, tiny_config

from packlab.cases import case_to_dict
from packlab.core.choices import HEURISTICS
from packlab.core.errors import ConfigError
from packlab.datagen import DIFFICULTIES, CaseConfig, DatasetConfig, build_case, generate_cases
from packlab.datagen.config import ObjectLimits, ValidationConfig
from packlab.datagen.generator import draw_blueprint, fill_slot
from packlab.datagen.seeds import case_seed
from packlab.policies import make_policy
from packlab.sim.episode import run_episode

RANDOM = CaseConfig(layout="random")


def _cases(difficulty, n=12, user_seed=5):
    return [
        build_case(case_seed(user_seed, "train", difficulty, slot), difficulty, RANDOM)
        for slot in range(n)
    ]


@pytest.mark.parametrize("difficulty", list(DIFFICULTIES))
def test_random_boxes_obey_the_size_rules_and_fill_at_most_the_container(difficulty):
    lim = ObjectLimits()
    spec = DIFFICULTIES[difficulty]
    for case in _cases(difficulty):
        c = case.container
        assert case.gt_plan is None
        assert 1 <= len(case.objects) <= spec.n_objects[1]
        assert case.buffer_size == spec.buffer_size
        assert [b.internal_id for b in case.objects] == list(range(len(case.objects)))
        for b in case.objects:
            l, w, h = b.size_mm
            assert l % c.cell_xy_mm == 0 and w % c.cell_xy_mm == 0
            assert min(l, w) >= lim.min_side_mm and max(l, w) <= lim.max_aspect * min(l, w)
            assert l <= c.size_mm[0] and w <= c.size_mm[1]  # fits the floor as drawn
            assert lim.layer_height_mm[0] <= h <= lim.layer_height_mm[1]
            assert h % lim.height_step_mm == 0 and h <= c.size_mm[2]
        g = case.generator
        assert g["layout"] == "random" and g["order"] == "draw"
        assert case.total_volume_mm3 <= g["target_fill"] * c.volume_mm3 + 1
        assert case.total_volume_mm3 <= c.volume_mm3
        lo, hi = spec.height_ratio
        assert lo - 1e-6 <= g["target_fill"] <= hi + 1e-6


def test_random_cases_are_deterministic_and_load_back():
    from packlab.cases import case_from_dict

    a, b = _cases("medium", 3), _cases("medium", 3)
    assert a == b
    for case in a:
        assert case_from_dict(case_to_dict(case)) == case


def test_random_and_layers_cases_are_pinned():
    """What random and layers-order seeds produce (packlab-bench-layers-v1 depends on the
    latter): a change must bump GENERATOR_VERSION and make new suite versions."""
    digest = hashlib.sha256()
    for cfg in (RANDOM, CaseConfig(order="layers"), CaseConfig(layout="stepped", order="layers")):
        for difficulty in DIFFICULTIES:
            for case in generate_cases(difficulty, 2, seed=0, validate=False, config=cfg):
                digest.update(json.dumps(case_to_dict(case), sort_keys=True).encode())
    assert digest.hexdigest() == PINNED_DIGEST


def test_random_has_no_blueprint_and_the_oracle_refuses_it():
    seed = case_seed(5, "train", "easy", 0)
    with pytest.raises(ConfigError, match="no blueprint"):
        draw_blueprint(seed, "easy", RANDOM)
    with pytest.raises(ConfigError, match="needs a gt_plan"):
        make_policy("oracle").reset(build_case(seed, "easy", RANDOM), 0)


def test_random_slots_are_taken_without_replay():
    out = fill_slot(3, "bench", "hard", 0, RANDOM, ValidationConfig(), "bench-")
    assert out.case is not None and out.trajectory is None and out.rejected == ()
    assert len(generate_cases("easy", 2, seed=1, config=RANDOM)) == 2


@pytest.mark.parametrize("difficulty", ["easy", "medium"])
def test_every_heuristic_and_plan_fast_run_on_a_random_case(difficulty):
    case = _cases(difficulty, 1, user_seed=8)[0]
    for name in (*HEURISTICS, "plan-fast"):
        result = run_episode(case, make_policy(name), 0, backend="geometric")
        m = result.metrics
        assert len(result.steps) == len(case.objects)
        assert 0.0 <= m.overall <= 1.0 and 0.0 <= m.success_ratio <= 1.0, name


def test_a_random_dataset_needs_a_teacher_and_records_its_runs(tmp_path):
    with pytest.raises(ConfigError, match="teacher = 'oracle'.*random"):
        DatasetConfig(("easy",), (1,), case=RANDOM)
    cfg = tiny_config(difficulties=("easy",), episodes=(3,), case=RANDOM, teacher="dblf")
    info = make_dataset(tmp_path / "ds", cfg)
    assert info.counts.episodes == 3 and info.generator_config["case"]["layout"] == "random"
    rows = pq.read_table(next((tmp_path / "ds" / "data" / "episodes").glob("*.parquet")))
    assert set(rows.column("layout").to_pylist()) == {"random"}
    assert "random layout family" in (tmp_path / "ds" / "README.md").read_text()


PINNED_DIGEST = "8a794d2d04ca6ef2c6633df58bf939c902557dd9b36a46931377f6d28a15d1bd"
