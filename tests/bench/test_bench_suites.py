"""The bundled suite: checksum verified on load, a changed file refused, stats as described."""

from __future__ import annotations

import shutil

import pytest

from packlab.bench.describe import describe_cases, format_description
from packlab.bench.suites import (
    DEFAULT_SUITE,
    SUITES,
    SuiteIntegrityError,
    build_suite,
    file_sha256,
    load_suite,
    resolve_cases,
    suite_files,
)
from packlab.core.errors import ConfigError
from packlab.datagen.seeds import seed_domain


def test_bundled_suite_verifies_and_matches_its_spec():
    cases = load_suite(DEFAULT_SUITE)
    spec = SUITES[DEFAULT_SUITE]
    assert len(cases) == spec.n_cases == 60
    by_level = {d: [c for c in cases if c.difficulty == d] for d, _ in spec.counts}
    assert {d: len(v) for d, v in by_level.items()} == {"easy": 20, "medium": 20, "hard": 20}
    assert {d: {c.buffer_size for c in v} for d, v in by_level.items()} == {
        "easy": {3},
        "medium": {5},
        "hard": {10},
    }
    assert len({c.episode_id for c in cases}) == 60
    # Bench seeds live in their own domain: disjoint from every training seed by construction.
    assert {seed_domain(c.seed) for c in cases} == {"bench"}
    assert all(c.gt_plan is not None and len(c.gt_plan) == len(c.objects) for c in cases)


def _copy_suite(tmp_path):
    for f in suite_files(DEFAULT_SUITE):
        shutil.copy(f, tmp_path / f.name)
    return suite_files(DEFAULT_SUITE, tmp_path)


def test_an_unchanged_copy_loads(tmp_path):
    _copy_suite(tmp_path)
    assert len(load_suite(DEFAULT_SUITE, tmp_path)) == 60


def test_a_modified_copy_is_refused_with_a_clear_error(tmp_path):
    cases_path, _ = _copy_suite(tmp_path)
    text = cases_path.read_text()
    cases_path.write_text(text.replace('"buffer_size":3', '"buffer_size":4', 1))
    with pytest.raises(SuiteIntegrityError) as err:
        load_suite(DEFAULT_SUITE, tmp_path)
    msg = str(err.value)
    assert str(cases_path) in msg and "does not match" in msg and "new suite version" in msg


def test_a_missing_checksum_is_refused(tmp_path):
    _, checksum = _copy_suite(tmp_path)
    checksum.unlink()
    with pytest.raises(SuiteIntegrityError, match="checksum file missing"):
        load_suite(DEFAULT_SUITE, tmp_path)


def test_a_checksum_file_for_another_file_is_refused(tmp_path):
    _, checksum = _copy_suite(tmp_path)
    checksum.write_text("0" * 64 + "  other.jsonl\n")
    with pytest.raises(SuiteIntegrityError, match="no checksum line"):
        load_suite(DEFAULT_SUITE, tmp_path)


def test_resolve_cases_takes_a_suite_name_or_a_file(tiny_suite):
    suite = resolve_cases(None)
    assert (
        suite.label == DEFAULT_SUITE
        and suite.origin == f"suite:{DEFAULT_SUITE}"
        and len(suite.cases) == 60
    )
    other = resolve_cases(str(tiny_suite))
    assert (
        other.label == "tiny" and len(other.cases) == 4 and other.sha256 == file_sha256(tiny_suite)
    )
    with pytest.raises(ConfigError, match="neither a registered suite"):
        resolve_cases("no-such-suite")


def test_describe_reports_table1_quantities():
    stats = {s.name: s for s in describe_cases(load_suite())}
    assert list(stats) == ["easy", "medium", "hard", "all"]
    assert stats["all"].steps == sum(stats[d].steps for d in ("easy", "medium", "hard"))
    # The paper's Table 1 ranges, measured on the file (not copied from the spec).
    assert 4 <= stats["easy"].objects.low and stats["easy"].objects.high <= 8
    assert 9 <= stats["medium"].objects.low and stats["medium"].objects.high <= 18
    assert 19 <= stats["hard"].objects.low and stats["hard"].objects.high <= 32
    assert stats["hard"].layers.low >= 3 and stats["hard"].layers.high <= 4
    text = format_description(DEFAULT_SUITE, list(stats.values()))
    assert "hard" in text and str(stats["all"].steps) in text


@pytest.mark.physics
def test_the_bundled_file_is_reproducible_from_its_seeds(tmp_path):
    """Provenance: regenerating from the spec gives the bundled bytes.

    (Else: a new suite version.)
    """
    from packlab.bench.suites import write_suite

    spec = SUITES[DEFAULT_SUITE]
    _, digest = write_suite(spec, build_suite(spec), tmp_path)
    assert digest == file_sha256(suite_files(DEFAULT_SUITE)[0])
