"""The bench's sensing switches: --observation, --execution, --noise (opt-in, part of the
identity), and --sides (longer first by default; always part of the identity)."""

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
    run_sides,
    saved_sensing,
    sensing_identity,
)
from packlab.cli.bench import config_from_args
from packlab.cli.main import build_parser
from packlab.core.choices import DEFAULT_SIDES, UNRECORDED_SIDES
from packlab.core.errors import ConfigError
from packlab.sim.modes import DEFAULT_NOISE


def test_defaults_are_exact_with_sides_named_longer_first(tiny_suite):
    config = RunConfig(cases=str(tiny_suite))
    assert (config.observation, config.execution, config.noise) == ("exact", "exact", DEFAULT_NOISE)
    assert config.sides == DEFAULT_SIDES == "longer-first"
    run = resolve(config)
    saved = run.to_json()
    # The side names are always written: a run directory says which names its records used.
    assert (
        saved["sensing"]
        == sensing_identity(config)
        == {
            "observation": "exact",
            "execution": "exact",
            "noise": DEFAULT_NOISE,
            "sides": "longer-first",
        }
    )
    modes = run.episode_modes()
    assert modes.perceiver is None and modes.execution is None
    assert modes.sides == "longer-first"
    assert run.out.name == f"bench-{run.source.label}"


def test_old_run_directories_resume_only_under_the_catalogues_names(tiny_suite):
    """A config.json written before the side names were always recorded has no ``sides`` (an
    exact run: no ``sensing`` at all); it was made with the catalogue's names and resumes only
    under them, never silently under the new default."""
    current = resolve(RunConfig(cases=str(tiny_suite))).to_json()
    catalogue = resolve(RunConfig(cases=str(tiny_suite), sides="catalogue")).to_json()
    old = {k: v for k, v in catalogue.items() if k != "sensing"}
    assert saved_sensing(None)["sides"] == UNRECORDED_SIDES == "catalogue"
    with pytest.raises(ConfigError, match=r"'sensing.sides' = 'catalogue' here.*--sides catalogue"):
        check_resumable(old, current, tiny_suite)
    check_resumable(old, catalogue, tiny_suite)
    assert run_sides(old) == "catalogue" and run_sides(None) == DEFAULT_SIDES
    # An exact run made with --sides longer-first before it became the default resumes as is.
    lf_before = {**old, "sensing": {**current["sensing"], "noise": "stereo"}}
    check_resumable(lf_before, current, tiny_suite)
    assert run_sides(lf_before) == "longer-first"
    # Perceived runs always named sides longer first, recorded or not.
    perceived = resolve(RunConfig(cases=str(tiny_suite), observation="perceived")).to_json()
    old_perceived = {**perceived, "sensing": dict(perceived["sensing"])}
    del old_perceived["sensing"]["sides"]
    check_resumable(old_perceived, perceived, tiny_suite)


def test_an_old_run_directory_is_refused_then_resumed_end_to_end(tiny_suite, tmp_path):
    out = tmp_path / "old"
    first = run_tiny(tiny_suite, out, sides="catalogue", seeds=(0,))
    config_path = out / "config.json"
    saved = json.loads(config_path.read_text())
    assert saved["sensing"]["sides"] == "catalogue"
    del saved["sensing"]  # as an older version wrote an exact run's config.json
    config_path.write_text(json.dumps(saved))
    with pytest.raises(ConfigError, match="--sides catalogue resumes it"):
        run_tiny(tiny_suite, out, seeds=(0,))
    resumed = run_tiny(tiny_suite, out, sides="catalogue", seeds=(0,))
    assert resumed.ran == 0 and resumed.already_done == first.planned
    assert resumed.summary.table == first.summary.table


def test_modes_enter_the_identity(tiny_suite):
    perceived = resolve(RunConfig(cases=str(tiny_suite), observation="perceived", noise="stereo"))
    saved = perceived.to_json()
    assert "sensing" in IDENTITY_KEYS
    assert saved["sensing"] == {
        "observation": "perceived",
        "execution": "exact",
        "noise": "stereo",
        "segmentation": "depth",
        "size_prior": "grid",
        "sides": "longer-first",
    }
    assert perceived.episode_modes().perceiver is not None
    # The same policies (the default list of a perceived run leaves the oracle out).
    exact = resolve(RunConfig(cases=str(tiny_suite), policies=perceived.policies)).to_json()
    with pytest.raises(ConfigError, match="'sensing.observation' = 'exact' here"):
        check_resumable(exact, saved, tiny_suite)


def test_each_mode_gets_its_own_default_run_directory(tiny_suite):
    """With no --out, runs of the modes one after another do not land in one directory (whose
    identity would refuse the second); the exact default keeps its old name, the catalogue's side
    names get their own."""
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
    catalogue = resolve(RunConfig(cases=str(tiny_suite), sides="catalogue"))
    assert catalogue.out.name == f"{exact}-catalogue"


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
        "sides": "longer-first",
        "size_prior": "grid",
    }
    exact_sensing = json.loads((tmp_path / "exact" / "summary.json").read_text())["sensing"]
    assert exact_sensing["sides"] == "longer-first"
    # Exact against perceived is an ablation of the same cases and seeds: rows say which is which.
    both = compare_markdown([tmp_path / "exact", tmp_path / "seen"])
    assert "| exact (observation exact) |" in both
    assert (
        "| seen (observation perceived, noise none, segmentation depth, size prior grid) |" in both
    )
    assert "seen2" in compare_markdown([tmp_path / "seen", tmp_path / "seen2"])


def test_catalogue_side_names_stay_selectable_and_enter_the_identity(tiny_suite):
    named = resolve(RunConfig(cases=str(tiny_suite), sides="catalogue"))
    saved = named.to_json()
    assert saved["sensing"] == {
        "observation": "exact",
        "execution": "exact",
        "noise": "structured-light",
        "sides": "catalogue",
    }
    assert named.episode_modes().sides == "catalogue"
    default = resolve(RunConfig(cases=str(tiny_suite))).to_json()
    with pytest.raises(ConfigError, match="'sensing.sides' = 'catalogue' here, 'longer-first' now"):
        check_resumable(saved, default, tiny_suite)
    with pytest.raises(ConfigError, match="sides = 'catalogue': perceived observation"):
        resolve(RunConfig(cases=str(tiny_suite), observation="perceived", sides="catalogue"))
    parser = build_parser()
    args = parser.parse_args(["bench", "--sides", "catalogue"])
    assert config_from_args(args).sides == "catalogue"


def test_remaining_can_be_hidden_and_is_then_part_of_the_identity(tiny_suite, tmp_path):
    """--remaining hidden: observations carry None, the identity and default directory say so,
    and a run made with it is not resumed as one without it; the default leaves the identity
    as every run made before the switch wrote it."""
    default = resolve(RunConfig(cases=str(tiny_suite)))
    assert "remaining" not in default.to_json()["sensing"]
    assert default.episode_modes().show_remaining
    hidden = resolve(RunConfig(cases=str(tiny_suite), remaining="hidden"))
    assert hidden.to_json()["sensing"]["remaining"] == "hidden"
    assert not hidden.episode_modes().show_remaining
    assert hidden.out.name.endswith("-remaining-hidden")
    with pytest.raises(ConfigError, match="remaining"):
        check_resumable(hidden.to_json(), default.to_json(), tiny_suite)
    outcome = run_tiny(tiny_suite, tmp_path / "hidden", remaining="hidden", policies=("plan-fast",))
    assert outcome.summary.policies == ("plan-fast",)
    args = build_parser().parse_args(["bench", "--remaining", "hidden"])
    assert config_from_args(args).remaining == "hidden"
    with pytest.raises(ConfigError, match="remaining"):
        RunConfig(remaining="unknown")  # type: ignore[arg-type]


def test_perceived_runs_leave_the_oracle_out_of_the_default_policies(tiny_suite):
    exact = resolve(RunConfig(cases=str(tiny_suite)))
    seen = resolve(RunConfig(cases=str(tiny_suite), observation="perceived"))
    assert "oracle" in exact.policies and "oracle" not in seen.policies
