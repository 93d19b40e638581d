"""Training and tuning refuse a suite case by its content: renamed, reseeded,
re-exported (JSONL, the reference's parquet layout) or with its sides named the other way round,
a bundled suite case or a reference benchmark case is still refused; generated cases pass."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest

from packlab.bench.suites import SUITES, load_suite
from packlab.cases import load_cases, write_reference
from packlab.cases.fingerprint import case_fingerprint, set_fingerprint
from packlab.cases.known import (
    known_cases,
    read_reference,
    read_suites,
    reference_file,
    suites_file,
)
from packlab.cli.main import main
from packlab.core.errors import ConfigError
from packlab.core.types import Box, Case
from packlab.datagen import generate_cases
from packlab.datagen.guard import require_training_cases
from packlab.datagen.seeds import case_seed

BENCH = "packlab-bench-v1"
ROOT = Path(__file__).resolve().parents[1]
TRAIN_SEED = case_seed(4402, "train", "hard", 3)


def _disguised(case: Case, n: int = 0) -> Case:
    """The case under another name and a training-domain seed, as if generated for training."""
    return dataclasses.replace(case, episode_id=f"train-s4402-hard-{n:05d}", seed=TRAIN_SEED)


def _swapped(case: Case) -> Case:
    """Every box with its l and w named the other way round (the --sides naming)."""
    boxes = tuple(
        dataclasses.replace(b, size_mm=(b.size_mm[1], b.size_mm[0], b.size_mm[2]))
        for b in case.objects
    )
    return dataclasses.replace(case, objects=boxes)


def _refused(cases: list[Case], source: str, suite_id: str) -> str:
    with pytest.raises(ConfigError) as err:
        require_training_cases(cases, source)
    line = str(err.value)
    assert "\n" not in line and source in line and "has the content of" in line
    assert repr(suite_id) in line and repr(cases[0].episode_id) in line
    return line


@pytest.mark.parametrize("suite", list(SUITES))
def test_a_renamed_and_reseeded_suite_case_is_refused(suite):
    case = load_suite(suite)[7]
    line = _refused([_disguised(case)], "cases.jsonl", case.episode_id)
    assert suite in line


def test_a_reseeded_hand_seed_case_is_refused_too():
    """A bench case given a small (hand-made) seed must be refused too."""
    case = load_suite(BENCH)[0]
    hand = dataclasses.replace(case, seed=17, episode_id="hand-1")
    _refused([hand], "hand.jsonl", case.episode_id)


def test_a_side_swapped_suite_case_is_refused():
    case = load_suite(BENCH)[45]
    assert case.objects[0].size_mm[0] != case.objects[0].size_mm[1]
    assert case_fingerprint(_swapped(case)) == case_fingerprint(case)
    _refused([_disguised(_swapped(case))], "sides.jsonl", case.episode_id)


def test_a_reordered_case_is_another_case():
    """Arrival order is content: the same boxes in another order are not the suite case."""
    case = load_suite(BENCH)[50]
    objects = case.objects[1:] + case.objects[:1]
    assert case_fingerprint(dataclasses.replace(case, objects=objects)) != case_fingerprint(case)


def test_the_suite_exported_to_jsonl_and_renamed_is_refused(tmp_path):
    out = tmp_path / "bench.jsonl"
    assert main(["cases", "export", BENCH, "--format", "jsonl", "--out", str(out)]) == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    for n, row in enumerate(rows):
        row.update(episode_id=f"train-s1-easy-{n:05d}", seed=case_seed(1, "train", "easy", n))
    renamed = tmp_path / "train.jsonl"
    renamed.write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert main(["train", "rl", "--cases", str(renamed), "--out", str(tmp_path / "run")]) == 2
    cases = load_cases(renamed)
    _refused(cases, str(renamed), load_suite(BENCH)[0].episode_id)


def test_the_suite_in_the_reference_layout_reseeded_is_refused(tmp_path):
    disguised = [_disguised(c, n) for n, c in enumerate(load_suite(BENCH))]
    write_reference(disguised, tmp_path / "ref")
    cases = load_cases(tmp_path / "ref")
    assert {c.seed for c in cases} == {TRAIN_SEED}
    _refused(cases, "ref", load_suite(BENCH)[0].episode_id)


def test_reference_benchmark_rows_without_their_origin_are_refused():
    """`packlab cases export` drops `origin`; the reference's cases are known by content."""
    reference = load_cases(ROOT / "tests" / "data" / "reference_bench")
    plain = [dataclasses.replace(c, origin=None, seed=TRAIN_SEED) for c in reference]
    line = _refused(plain[:1], "ref.jsonl", reference[0].episode_id)
    assert "reference PackLab-Bench" in line


def test_the_bundled_reference_fingerprints_are_the_fixture_s():
    reference = load_cases(ROOT / "tests" / "data" / "reference_bench")
    want = {case_fingerprint(c): c.episode_id for c in reference}
    assert read_reference(reference_file()) == want


def test_every_suite_case_is_known_and_generated_cases_pass():
    known = known_cases()
    for name in SUITES:
        assert all(case_fingerprint(c) in known for c in load_suite(name))
    cases = [
        c
        for lv in ("easy", "medium", "hard")
        for c in generate_cases(lv, 5, 3, False, domain="train")
    ]
    assert require_training_cases(cases, "train.jsonl") == cases
    assert not {case_fingerprint(c) for c in cases} & set(known)


def test_the_shipped_suite_fingerprints_are_the_bundled_suites_own():
    """A suite added or rebuilt without `python scripts/guard_fingerprints.py` fails here."""
    script = ROOT / "scripts" / "guard_fingerprints.py"
    done = subprocess.run(
        [sys.executable, str(script), "--check"], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert len(read_suites(suites_file())) == sum(len(load_suite(name)) for name in SUITES)


def test_a_set_fingerprint_ignores_order_and_names():
    cases = load_suite(BENCH)[:5]
    prints = [case_fingerprint(c) for c in cases]
    assert set_fingerprint(prints) == set_fingerprint(reversed(prints))
    assert set_fingerprint(prints) != set_fingerprint(prints[:4])
    box = Box(internal_id=0, size_mm=(100, 200, 50))
    one = dataclasses.replace(cases[0], objects=(box,))
    assert case_fingerprint(one) != case_fingerprint(cases[0])
