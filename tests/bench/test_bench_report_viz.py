"""Figures and replays: report figures from files, ``packlab viz episode``, deterministic replay."""

from __future__ import annotations

import pytest

from packlab.bench.config import RunConfig
from packlab.bench.records import read_records
from packlab.bench.replay import replay_record
from packlab.bench.report import build_report, load_run
from packlab.bench.runner import run_bench
from packlab.cli.main import main


@pytest.fixture(scope="module")
def geometric_run(tmp_path_factory):
    from bench_helpers import write_tiny_suite

    root = tmp_path_factory.mktemp("run")
    suite = write_tiny_suite(root)
    cfg = RunConfig(
        cases=str(suite),
        out=str(root / "run"),
        backend="geometric",
        policies=("dblf", "sdf", "random", "oracle"),
        seeds=(0, 1),
        workers=1,
        progress=False,
    )
    run_bench(cfg, figures=False)
    return root / "run"


def _is_png(path):
    return (
        path.is_file()
        and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        and path.stat().st_size > 5000
    )


def test_report_writes_the_three_figures(geometric_run):
    _, _, paths = build_report(geometric_run, case_id="hard-3", seed=1)
    names = {p.name for p in paths}
    assert {
        "summary.json",
        "table.md",
        "overall_by_case.png",
        "overall_average.png",
        "packing_hard-3_seed1.png",
    } <= names
    assert all(_is_png(p) for p in paths if p.suffix == ".png")


def test_report_picks_a_hard_case_by_default(geometric_run):
    _, _, paths = build_report(geometric_run)
    packing = [p for p in paths if p.name.startswith("packing_")]
    assert len(packing) == 1 and packing[0].name.startswith("packing_hard-")


def test_replay_reproduces_the_recorded_episode(geometric_run):
    run = load_run(geometric_run)
    cases = {c.episode_id: c for c in run.cases}
    for rec in run.records[:6]:
        replay = replay_record(cases[rec.case_id], rec)
        assert replay.matches_record and len(replay.heightmaps) == len(rec.steps)


def test_viz_episode_cli(geometric_run, tmp_path, capsys):
    out = tmp_path / "ep.png"
    code = main(
        [
            "viz",
            "episode",
            str(geometric_run),
            "--case",
            "hard-4",
            "--policy",
            "dblf",
            "--seed",
            "1",
            "--out",
            str(out),
        ]
    )
    assert code == 0 and _is_png(out)


def test_viz_episode_cli_unknown_case_is_one_line(geometric_run, tmp_path, capsys):
    code = main(
        [
            "viz",
            "episode",
            str(geometric_run / "episodes.jsonl"),
            "--case",
            "nope",
            "--policy",
            "dblf",
            "--out",
            str(tmp_path / "x.png"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and "nope" in err and len(err.splitlines()) == 1


def test_bench_report_cli_prints_the_table(geometric_run, capsys):
    assert main(["bench", "report", str(geometric_run), "--no-figures"]) == 0
    assert "| SDF-Pack " in capsys.readouterr().out  # the 120-column view pads its names
    assert main(["bench", "report", str(geometric_run), "--no-figures", "--wide"]) == 0
    assert "| SDF-Pack |" in capsys.readouterr().out  # table.md's layout


@pytest.mark.parametrize("seed", ["-1", "99999"])
def test_bench_report_refuses_a_seed_the_run_did_not_play(geometric_run, capsys, seed):
    code = main(["bench", "report", str(geometric_run), "--no-figures", "--seed", seed])
    err = capsys.readouterr().err.strip()
    assert code == 2 and f"seed = {int(seed)}" in err and len(err.splitlines()) == 1


@pytest.mark.physics
def test_mujoco_replay_is_deterministic(tiny_suite, tmp_path):
    cfg = RunConfig(
        cases=str(tiny_suite),
        out=str(tmp_path / "run"),
        policies=("random",),
        seeds=(3,),
        difficulties=("hard",),
        workers=1,
        progress=False,
    )
    run_bench(cfg, figures=False)
    run = load_run(tmp_path / "run")
    cases = {c.episode_id: c for c in run.cases}
    for rec in read_records(tmp_path / "run" / "episodes.jsonl"):
        assert replay_record(cases[rec.case_id], rec).matches_record


def test_a_catalogue_run_replays_under_its_own_side_names(tmp_path, capsys):
    """A recorded rotation refers to the sides the run showed: a run with the catalogue's names
    (or one made before they were recorded) replays under them, read from its config.json."""
    import json

    from bench_helpers import run_tiny, write_tiny_suite

    from packlab.bench.config import run_sides

    suite = write_tiny_suite(tmp_path)
    run_tiny(suite, tmp_path / "run", sides="catalogue", policies=("random",), seeds=(3,))
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    assert run_sides(saved) == "catalogue"
    run = load_run(tmp_path / "run")
    cases = {c.episode_id: c for c in run.cases}
    records = list(read_records(tmp_path / "run" / "episodes.jsonl"))
    assert all(
        replay_record(cases[r.case_id], r, sides="catalogue").matches_record for r in records
    )
    # Under the other names the random policy's rotations would lay some boxes the other way.
    assert not all(replay_record(cases[r.case_id], r).matches_record for r in records)
    # packlab viz episode reads the names from the run directory (a figure, no warning).
    rec = records[0]
    code = main(
        ["viz", "episode", str(tmp_path / "run"), "--case", rec.case_id, "--policy", "random",
         "--out", str(tmp_path / "fig.png")]
    )  # fmt: skip
    assert code == 0 and "warning" not in capsys.readouterr().err
