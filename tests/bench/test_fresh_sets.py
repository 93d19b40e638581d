"""`packlab cases fresh`: a case set made like a bundled suite from a training-domain seed, the
command behind every "fresh generated set" figure (the same cases as the data engine's
`generate_cases(level, n, seed, True, domain="train")` with the suite's family and order)."""

from __future__ import annotations

import pytest

from packlab.bench.suites import SUITES, fresh_spec
from packlab.cases import load_cases
from packlab.cases.fingerprint import case_fingerprint
from packlab.cli.main import main
from packlab.core.errors import ConfigError
from packlab.datagen import generate_cases
from packlab.datagen.config import ValidationConfig
from packlab.datagen.guard import require_training_cases


@pytest.mark.parametrize("name", sorted(SUITES))
def test_a_fresh_spec_keeps_the_suites_recipe_in_the_training_domain(name):
    suite = SUITES[name]
    spec = fresh_spec(name, 4721)
    assert (spec.layout, spec.order, spec.counts) == (suite.layout, suite.order, suite.counts)
    assert (spec.domain, spec.seed) == ("train", 4721)
    assert fresh_spec(name, 4721, per_level=2).counts == tuple((d, 2) for d, _ in suite.counts)


@pytest.mark.parametrize(
    ("name", "seed", "per_level", "says"),
    [
        ("packlab-bench-v9", 1, None, "unknown"),
        ("packlab-bench-v1", -1, None, "seed = -1"),
        ("packlab-bench-v1", True, None, "seed = True"),
        ("packlab-bench-v1", 1, 0, "per_level = 0"),
    ],
)
def test_a_bad_fresh_spec_is_refused_naming_the_value(name, seed, per_level, says):
    with pytest.raises(ConfigError, match=says):
        fresh_spec(name, seed, per_level)


def test_the_command_writes_the_data_engines_cases_and_keeps_an_existing_file(tmp_path, capsys):
    out = tmp_path / "fresh.jsonl"
    args = ["cases", "fresh", "packlab-bench-layers-v1", "--seed", "4721", "--out", str(out)]
    assert main([*args, "--per-level", "1", "--validation", "geometric"]) == 0
    cases = load_cases(out)
    geometric = ValidationConfig(backend="geometric")
    expected = [
        case
        for level in ("easy", "medium", "hard")
        for case in generate_cases(
            level,
            1,
            4721,
            True,
            config=SUITES["packlab-bench-layers-v1"].case_config,
            validation=geometric,
            domain="train",
        )
    ]
    assert [case_fingerprint(c) for c in cases] == [case_fingerprint(c) for c in expected]
    assert [c.episode_id for c in cases] == [
        f"train-s4721-{level}-00000" for level in ("easy", "medium", "hard")
    ]
    # Cases the suite never held: the training guard, which refuses a suite case by content,
    # lets them through.
    assert len(require_training_cases(cases, str(out))) == 3
    written = out.read_bytes()
    capsys.readouterr()
    assert main([*args, "--per-level", "1"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert out.read_bytes() == written
