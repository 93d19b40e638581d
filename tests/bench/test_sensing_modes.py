"""Issue 15's bench switches: --observation, --execution, --noise (opt-in, part of the identity)."""

from __future__ import annotations

import json

import pytest
from bench_helpers import run_tiny

from packlab.bench.compare import compare_markdown
from packlab.bench.config import (
    IDENTITY_KEYS,
    RunConfig,
    check_resumable,
    resolve,
    sensing_identity,
)
from packlab.cli.bench import config_from_args
from packlab.cli.main import build_parser
from packlab.core.errors import ConfigError
from packlab.sim.modes import DEFAULT_NOISE


def test_defaults_are_exact_and_leave_config_json_as_before(tiny_suite):
    config = RunConfig(cases=str(tiny_suite))
    assert (config.observation, config.execution, config.noise) == ("exact", "exact", DEFAULT_NOISE)
    run = resolve(config)
    saved = run.to_json()
    assert "sensing" not in saved and sensing_identity(config) is None
    modes = run.episode_modes()
    assert modes.perceiver is None and modes.execution is None
    # A run directory written before the modes existed still resumes under the defaults.
    check_resumable({k: v for k, v in saved.items() if k != "sensing"}, saved, tiny_suite)


def test_modes_enter_the_identity(tiny_suite):
    perceived = resolve(RunConfig(cases=str(tiny_suite), observation="perceived", noise="stereo"))
    saved = perceived.to_json()
    assert "sensing" in IDENTITY_KEYS
    assert saved["sensing"] == {
        "observation": "perceived",
        "execution": "exact",
        "noise": "stereo",
        "segmentation": "depth",
    }
    assert perceived.episode_modes().perceiver is not None
    exact = resolve(RunConfig(cases=str(tiny_suite))).to_json()
    with pytest.raises(ConfigError, match="'sensing' = None here"):
        check_resumable(exact, saved, tiny_suite)


def test_each_mode_gets_its_own_default_run_directory(tiny_suite):
    """With no --out, runs of the modes one after another do not land in one directory (whose
    identity would refuse the second); the exact default keeps its old name."""
    outs = [
        resolve(RunConfig(cases=str(tiny_suite), **modes)).out
        for modes in (
            {},
            {"observation": "perceived"},
            {"observation": "perceived", "execution": "noisy", "noise": "stereo"},
            {"execution": "noisy"},
        )
    ]
    truth = resolve(RunConfig(cases=str(tiny_suite), observation="perceived", segmentation="truth"))
    exact = outs[0].name
    assert exact.startswith("bench-") and len(set(outs)) == 4
    assert truth.out.name == f"{exact}-perceived-structured-light-truth-masks"
    assert outs[1].name == f"{exact}-perceived-structured-light"
    assert outs[2].name == f"{exact}-perceived-noisy-stereo"
    assert outs[3].name == f"{exact}-noisy-structured-light"


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"observation": "psychic"}, "observation = 'psychic'"),
        ({"execution": "noisy", "backend": "geometric"}, "execution = 'noisy'.*geometric"),
        ({"noise": "stereo"}, "noise = 'stereo': only used with"),
        ({"observation": "perceived", "noise": "laser"}, "noise = 'laser'"),
    ],
)
def test_bad_modes_are_refused_by_field(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        RunConfig(**kwargs)


def test_cli_flags_set_the_fields():
    parser = build_parser()
    assert config_from_args(parser.parse_args(["bench"])) == RunConfig()
    args = parser.parse_args(
        ["bench", "--observation", "perceived", "--execution", "noisy", "--noise", "none"]
    )
    config = config_from_args(args)
    assert (config.observation, config.execution, config.noise) == ("perceived", "noisy", "none")
    with pytest.raises(SystemExit):
        parser.parse_args(["bench", "--noise", "laser"])


def test_perceived_runs_record_replans_and_compare_labels_their_rows(tiny_suite, tmp_path):
    run_tiny(tiny_suite, tmp_path / "exact")
    run_tiny(tiny_suite, tmp_path / "seen", observation="perceived", noise="none")
    run_tiny(tiny_suite, tmp_path / "seen2", observation="perceived", noise="none")
    records = [
        json.loads(line) for line in (tmp_path / "seen" / "episodes.jsonl").read_text().splitlines()
    ]
    assert records and all(isinstance(r["metrics"]["replans"], int) for r in records)
    exact_records = (tmp_path / "exact" / "episodes.jsonl").read_text()
    assert "replan" not in exact_records
    summary = json.loads((tmp_path / "seen" / "summary.json").read_text())
    assert summary["sensing"] == {
        "observation": "perceived",
        "execution": "exact",
        "noise": "none",
        "segmentation": "depth",
    }
    assert "sensing" not in json.loads((tmp_path / "exact" / "summary.json").read_text())
    # Exact against perceived is an ablation of the same cases and seeds: rows say which is which.
    both = compare_markdown([tmp_path / "exact", tmp_path / "seen"])
    assert "| exact (observation exact) |" in both
    assert "| seen (observation perceived, noise none, segmentation depth) |" in both
    assert "seen2" in compare_markdown([tmp_path / "seen", tmp_path / "seen2"])


def test_sides_named_longer_first_enter_the_identity(tiny_suite):
    named = resolve(RunConfig(cases=str(tiny_suite), sides="longer-first"))
    saved = named.to_json()
    assert saved["sensing"] == {
        "observation": "exact",
        "execution": "exact",
        "noise": "structured-light",
        "sides": "longer-first",
    }
    assert named.episode_modes().sides == "longer-first"
    assert named.out.name.endswith("-longer-first")
    exact = resolve(RunConfig(cases=str(tiny_suite))).to_json()
    with pytest.raises(ConfigError, match="'sensing' = None here"):
        check_resumable(exact, saved, tiny_suite)
    with pytest.raises(ConfigError, match="sides"):
        resolve(RunConfig(cases=str(tiny_suite), observation="perceived", sides="longer-first"))
