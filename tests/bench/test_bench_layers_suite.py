"""``packlab-bench-layers-v1``: v1's recipe in the reference benchmark's arrival
order, bundled and checksummed; every case arrives layer by layer."""

from __future__ import annotations

import pytest
from bench_helpers import oracle_records

from packlab.bench.suites import (
    DEFAULT_SUITE,
    SUITES,
    SuiteSpec,
    build_suite,
    file_sha256,
    load_suite,
    resolve_cases,
    suite_files,
    write_suite,
)
from packlab.core.errors import ConfigError
from packlab.datagen import CaseConfig
from packlab.datagen.seeds import seed_domain
from packlab.datagen.validate import plan_problems

LAYERS_SUITE = "packlab-bench-layers-v1"


def test_the_layers_suite_is_registered_with_its_own_seed_and_order():
    spec, v1 = SUITES[LAYERS_SUITE], SUITES[DEFAULT_SUITE]
    assert spec.order == "layers" and v1.order == "removal"
    assert spec.counts == v1.counts and spec.domain == v1.domain == "bench"
    assert spec.seed != v1.seed
    assert spec.case_config == CaseConfig(order="layers") and v1.case_config == CaseConfig()


def test_every_case_of_the_layers_suite_arrives_layer_by_layer():
    cases = load_suite(LAYERS_SUITE)
    assert len(cases) == 60 and len({c.episode_id for c in cases}) == 60
    assert {d: sum(c.difficulty == d for c in cases) for d in ("easy", "medium", "hard")} == {
        "easy": 20,
        "medium": 20,
        "hard": 20,
    }
    assert {seed_domain(c.seed) for c in cases} == {"bench"}
    for case in cases:
        assert case.generator["order"] == "layers"
        assert case.generator["user_seed"] == SUITES[LAYERS_SUITE].seed
        plan = {p.internal_id: p for p in case.gt_plan}
        layers = [plan[b.internal_id].layer_index for b in case.objects]  # object_sequence
        assert layers == sorted(layers), case.episode_id
        # Supports first: replaying the plan in arrival order drops every box flat on its cells.
        assert plan_problems(case) == [], case.episode_id


def test_the_layers_suite_resolves_by_name():
    source = resolve_cases(LAYERS_SUITE)
    assert source.label == LAYERS_SUITE and source.origin == f"suite:{LAYERS_SUITE}"
    assert len(source.cases) == 60


def test_the_oracle_scores_one_on_the_layers_suite_geometric(tmp_path):
    records = oracle_records(LAYERS_SUITE, tmp_path / "run")
    assert len(records) == 60 and {r["status"] for r in records} == {"ok"}
    assert min(r["metrics"]["overall"] for r in records) == pytest.approx(1.0)


def test_a_suite_spec_rejects_a_bad_order():
    with pytest.raises(ConfigError, match="order = 'zigzag'"):
        SuiteSpec("x", counts=(("easy", 1),), seed=1, order="zigzag")


@pytest.mark.physics
def test_the_layers_suite_is_reproducible_from_its_seed(tmp_path):
    spec = SUITES[LAYERS_SUITE]
    _, digest = write_suite(spec, build_suite(spec), tmp_path)
    assert digest == file_sha256(suite_files(LAYERS_SUITE)[0])
