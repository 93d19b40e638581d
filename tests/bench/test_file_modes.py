"""Results and datasets are written with the user's umask, like any other file the user makes
(atomic writes through mkstemp used to leave cases.jsonl and meta/config.json at 0600)."""

from __future__ import annotations

import os
import stat

import pytest

from packlab.cli.main import main
from packlab.sim.env import demo_cases_path


@pytest.fixture(params=[0o022, 0o027])
def umask(request):
    old = os.umask(request.param)
    try:
        yield request.param
    finally:
        os.umask(old)


def _modes(root) -> dict[str, int]:
    return {str(p.relative_to(root)): stat.S_IMODE(p.stat().st_mode) for p in root.rglob("*")}


def test_bench_run_directory_follows_the_umask(tmp_path, umask, capsys):
    run = tmp_path / "run"
    assert (
        main(
            [
                "bench",
                "--cases",
                demo_cases_path(),
                "--backend",
                "geometric",
                "--policies",
                "dblf",
                "--seeds",
                "0",
                "--workers",
                "2",
                "--out",
                str(run),
                "--no-progress",
            ]
        )
        == 0
    )
    modes = _modes(run)
    for name in ("cases.jsonl", "config.json", "episodes.jsonl", "summary.json", "table.md"):
        assert modes.pop(name) == 0o666 & ~umask, name
    # Everything else (figures, the lock, the invocation log) too; directories 0777 less umask.
    for name, mode in modes.items():
        assert mode == (0o777 if (run / name).is_dir() else 0o666) & ~umask, name


def test_generated_dataset_follows_the_umask(tmp_path, umask, capsys):
    out = tmp_path / "data"
    assert (
        main(
            [
                "generate",
                "--difficulty",
                "easy",
                "--episodes",
                "2",
                "--validation",
                "geometric",
                "--workers",
                "1",
                "--image-size",
                "16",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 0
    )
    modes = _modes(out)
    assert modes["meta/config.json"] == modes["meta/info.json"] == 0o666 & ~umask
    assert modes["data/steps/easy-00000.parquet"] == 0o666 & ~umask
    for name, mode in modes.items():
        assert mode == (0o777 if (out / name).is_dir() else 0o666) & ~umask, name
