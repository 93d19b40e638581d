"""``--size-prior``: perceived runs name the prior on box sizes perception was given (``grid``,
the default, or ``none``) in their identity, default directory, table and comparisons."""

from __future__ import annotations

import json
from typing import get_args

import pytest
from bench_helpers import run_tiny

from packlab.bench.compare import compare_markdown
from packlab.bench.config import (
    RunConfig,
    check_resumable,
    resolve,
    saved_sensing,
    sensing_identity,
)
from packlab.bench.options import RunConfig as OptionsRunConfig
from packlab.cli.bench import config_from_args
from packlab.cli.main import build_parser
from packlab.core.choices import DEFAULT_SIZE_PRIOR, SizePrior
from packlab.core.errors import ConfigError
from packlab.sim.sensing import perception


def test_the_bench_and_perception_name_the_same_priors():
    assert get_args(SizePrior) == ("grid", "none") and DEFAULT_SIZE_PRIOR == "grid"
    assert perception.SizePrior is SizePrior
    assert OptionsRunConfig().size_prior == DEFAULT_SIZE_PRIOR


def test_the_prior_enters_the_identity_of_perceived_runs_only(tiny_suite):
    grid = resolve(RunConfig(cases=str(tiny_suite), observation="perceived")).to_json()
    none = resolve(
        RunConfig(cases=str(tiny_suite), observation="perceived", size_prior="none")
    ).to_json()
    assert grid["sensing"]["size_prior"] == "grid" and none["sensing"]["size_prior"] == "none"
    assert "size_prior" not in sensing_identity(RunConfig(cases=str(tiny_suite)))
    with pytest.raises(ConfigError, match="'sensing.size_prior' = 'grid' here, 'none' now"):
        check_resumable(grid, none, tiny_suite)
    # A perceived run directory written before the prior was a choice snapped to the grid.
    old = {**grid, "sensing": {k: v for k, v in grid["sensing"].items() if k != "size_prior"}}
    assert saved_sensing(old["sensing"])["size_prior"] == "grid"
    check_resumable(old, grid, tiny_suite)
    with pytest.raises(ConfigError, match="size_prior"):
        check_resumable(old, none, tiny_suite)


def test_the_prior_gets_its_own_default_directory(tiny_suite):
    base = resolve(RunConfig(cases=str(tiny_suite), observation="perceived")).out.name
    none = resolve(RunConfig(cases=str(tiny_suite), observation="perceived", size_prior="none"))
    assert none.out.name == f"{base}-size-prior-none"
    assert none.episode_modes().perceiver.size_prior == "none"


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"observation": "perceived", "size_prior": "cm"}, "size-prior = 'cm': unknown"),
        ({"size_prior": "none"}, "size-prior = 'none': only used with --observation perceived"),
    ],
)
def test_a_bad_prior_is_refused_naming_the_option(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        RunConfig(**kwargs)


def test_the_cli_flag_sets_the_field(capsys):
    parser = build_parser()
    args = parser.parse_args(["bench", "--observation", "perceived", "--size-prior", "none"])
    assert config_from_args(args).size_prior == "none"
    assert config_from_args(parser.parse_args(["bench"])).size_prior == "grid"
    with pytest.raises(SystemExit):
        parser.parse_args(["bench", "--size-prior", "cm"])
    assert "--size-prior" in capsys.readouterr().err


def test_tables_and_comparisons_name_the_prior(tiny_suite, tmp_path):
    run_tiny(tiny_suite, tmp_path / "exact")
    run_tiny(tiny_suite, tmp_path / "grid", observation="perceived", noise="none")
    run_tiny(tiny_suite, tmp_path / "raw", observation="perceived", noise="none", size_prior="none")
    assert "size prior" not in (tmp_path / "exact" / "table.md").read_text().splitlines()[0]
    for name, prior in (("grid", "grid"), ("raw", "none")):
        assert (
            f", size prior {prior}," in (tmp_path / name / "table.md").read_text().splitlines()[0]
        )
        summary = json.loads((tmp_path / name / "summary.json").read_text())
        assert summary["sensing"]["size_prior"] == prior
    both = compare_markdown([tmp_path / "grid", tmp_path / "raw"])
    assert "| grid (size prior grid) |" in both and "| raw (size prior none) |" in both
