"""``packlab-bench-cut-v1``: cut layouts (boxes of many heights, no flat layers) in
their support order, bundled and checksummed; the oracle reaches 1.0 on every case."""

from __future__ import annotations

from bench_helpers import oracle_records

from packlab.bench.suites import SUITES, load_suite, resolve_cases
from packlab.datagen import CaseConfig
from packlab.datagen.seeds import seed_domain
from packlab.datagen.validate import plan_problems

CUT_SUITE = "packlab-bench-cut-v1"


def test_the_cut_suite_is_registered_with_its_family_order_and_own_seed():
    spec = SUITES[CUT_SUITE]
    assert spec.case_config == CaseConfig(layout="cut", order="support")
    assert spec.counts == (("easy", 20), ("medium", 20), ("hard", 20))
    assert spec.seed not in {s.seed for n, s in SUITES.items() if n != CUT_SUITE}


def test_every_cut_case_has_mixed_heights_and_arrives_on_its_support():
    cases = load_suite(CUT_SUITE)
    assert len(cases) == 60 and len({c.episode_id for c in cases}) == 60
    assert {seed_domain(c.seed) for c in cases} == {"bench"}
    assert [c.buffer_size for c in cases] == [3] * 20 + [5] * 20 + [10] * 20
    # Not layers: boxes of one height throughout happen (a small cuboid cut once in z), but
    # rarely (measured: 1 case of 60).
    assert sum(len({b.size_mm[2] for b in c.objects}) > 1 for c in cases) >= 55
    for case in cases:
        assert case.generator["layout"] == "cut" and case.generator["order"] == "support"
        # Supports first: replaying the plan in arrival order drops every box flat on its cells.
        assert plan_problems(case) == [], case.episode_id


def test_the_oracle_scores_one_on_the_cut_suite_geometric(tmp_path):
    assert resolve_cases(CUT_SUITE).label == CUT_SUITE
    records = oracle_records(CUT_SUITE, tmp_path / "run")
    assert len(records) == 60 and {r["status"] for r in records} == {"ok"}
    assert all(r["metrics"]["overall"] == 1.0 for r in records)
