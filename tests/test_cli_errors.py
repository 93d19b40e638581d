"""Bad command-line input: one clear line ``packlab <cmd>: error: ...``, exit code 2, nothing
written (each case names the value that was wrong and asserts where the message says so)."""

from __future__ import annotations

import os

import pytest

from packlab.cli.main import main
from packlab.core.errors import EXIT_ABORTED, EXIT_USAGE, RunAborted
from packlab.sim.env import demo_cases_path


def _run(argv: list[str], capsys) -> tuple[int, str]:
    code = main(argv)
    return code, capsys.readouterr().err.strip()


BENCH_CASES = [
    (["--seeds", "0-100000000"], "seeds = '0-100000000': 100000001 seeds; at most 1000 per run"),
    (["--seeds", "0-600,601-1200"], "1201 seeds; at most 1000 per run"),
    (["--seeds", "5-2"], "range '5-2' runs backwards"),
    (["--seeds=-3"], "'-3' is negative"),
    (["--seeds", "4294967296"], "4294967296 is out of range"),
    (["--seeds", "0-x"], "expected integers like 0,1,2"),
    (["--seeds", ","], "seeds: give at least one run seed"),
    (["--seeds", "1,1"], "a seed is repeated"),
    (["--policies", ","], "policies = ',': empty list"),
    (["--policies", ""], "policies = '': empty list"),
    (["--policies", "dblf,nope"], "'nope' is not a registered policy"),
    (["--difficulty", ","], "difficulty = ',': empty list"),
    (["--difficulty", "extreme"], "difficulty = 'extreme': no such cases"),
    (["--workers", "-1"], "workers = -1"),
    (["--workers", "100000"], "workers = 100000: at most 512"),
    (["--episode-timeout", "-1"], "episode-timeout = -1.0"),
    (["--episode-timeout", "nan"], "episode-timeout = nan"),
    (["--episode-timeout", "inf"], "episode-timeout = inf"),
    (["--deadline", "-5"], "deadline = -5.0"),
    (["--max-transport-failures", "-1"], "max-transport-failures = -1"),
    (["--physics", "max_settle_steps=10"], "only the mujoco backend has physics settings"),
    (["--policy-arg", "dblf"], "policy-arg = 'dblf': expected POLICY:KEY=VALUE"),
    (
        ["--policy-arg", "oracle:x=1", "--policies", "dblf"],
        "policy 'oracle' is not among the policies",
    ),
    (["--policy-arg", "dblf:nope=1", "--policies", "dblf"], "policy = 'dblf': cannot be created"),
]


@pytest.mark.parametrize("flags, message", BENCH_CASES, ids=[" ".join(f) for f, _ in BENCH_CASES])
def test_bench_bad_flags(tmp_path, capsys, flags, message):
    out = tmp_path / "run"
    code, err = _run(
        [
            "bench",
            "--cases",
            demo_cases_path(),
            "--backend",
            "geometric",
            "--out",
            str(out),
            "--no-progress",
            "--no-figures",
            *flags,
        ],
        capsys,
    )
    assert code == EXIT_USAGE, err
    assert (
        err.startswith("packlab bench: error: ") and message in err and len(err.splitlines()) == 1
    )
    assert not out.exists()  # nothing written


def test_huge_seed_range_is_refused_before_allocating(capsys):
    # Ranges stay lazy until their total size is checked: a regression here builds a list of
    # 4.3e9 seeds and the test runs out of memory instead of passing.
    code, err = _run(["bench", "--seeds", "0-4294967295", "--backend", "geometric"], capsys)
    assert code == EXIT_USAGE and "4294967296 seeds; at most 1000 per run" in err


def test_out_naming_a_file_or_under_a_file(tmp_path, capsys):
    a_file = tmp_path / "afile"
    a_file.write_text("x")
    base = [
        "bench",
        "--cases",
        demo_cases_path(),
        "--backend",
        "geometric",
        "--policies",
        "dblf",
        "--seeds",
        "0",
    ]
    code, err = _run([*base, "--out", str(a_file)], capsys)
    assert code == EXIT_USAGE and f"out = '{a_file}': exists and is not a directory" in err
    code, err = _run([*base, "--out", str(a_file / "sub")], capsys)
    assert code == EXIT_USAGE and f"'{a_file}' is a file, not a directory" in err
    assert a_file.read_text() == "x"


def test_no_policies_flag_still_means_the_default_set(tmp_path, capsys):
    code, err = _run(
        [
            "bench",
            "--cases",
            demo_cases_path(),
            "--backend",
            "geometric",
            "--seeds",
            "0",
            "--workers",
            "1",
            "--out",
            str(tmp_path / "run"),
            "--no-progress",
            "--no-figures",
        ],
        capsys,
    )
    assert code == 0 and "episodes run" in err


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--difficulty", ",", "--episodes", "1"], "difficulty: give at least one"),
        (
            ["--difficulty", "easy", "--episodes", "100000000000"],
            "must be a whole number >= 0 and <= 1000000",
        ),
        (
            ["--difficulty", "easy", "--episodes", "1", "--seed", "99999999999999999999999"],
            "seed = 9999",
        ),
        (["--difficulty", "easy", "--episodes", "x"], "episodes = 'x'"),
        (["--difficulty", "easy", "--episodes", "1", "--workers", "-3"], "workers = -3"),
        (
            ["--difficulty", "easy", "--episodes", "1", "--image-size", "100000"],
            "image_size = 100000",
        ),
    ],
)
def test_generate_bad_flags(tmp_path, capsys, flags, message):
    out = tmp_path / "data"
    code, err = _run(
        ["generate", "--out", str(out), "--validation", "geometric", "--no-progress", *flags],
        capsys,
    )
    assert code == EXIT_USAGE and err.startswith("packlab generate: error: ") and message in err
    assert len(err.splitlines()) == 1 and not out.exists()


def test_generate_out_naming_a_file(tmp_path, capsys):
    a_file = tmp_path / "afile"
    a_file.write_text("x")
    code, err = _run(
        [
            "generate",
            "--difficulty",
            "easy",
            "--episodes",
            "1",
            "--out",
            str(a_file),
            "--validation",
            "geometric",
            "--no-progress",
        ],
        capsys,
    )
    assert (
        code == EXIT_USAGE and "exists and is not a directory" in err and a_file.read_text() == "x"
    )


def test_argparse_errors_exit_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "--episode-timeout", "abc"])
    assert exc.value.code == EXIT_USAGE
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "packlab bench: error: argument --episode-timeout: invalid float value: 'abc'"
    )


def test_path_errors_and_aborts_map_to_their_exit_codes(monkeypatch, capsys):
    import packlab.cli.bench as bench_cli

    def raise_(exc):
        def run(args):
            raise exc

        return run

    monkeypatch.setattr(bench_cli, "run", raise_(IsADirectoryError(21, "Is a directory", "runs/x")))
    assert _run(["bench"], capsys) == (EXIT_USAGE, "packlab bench: error: 'runs/x': Is a directory")
    monkeypatch.setattr(bench_cli, "run", raise_(RunAborted("stopped")))
    assert _run(["bench"], capsys) == (EXIT_ABORTED, "packlab bench: error: stopped")
    # An OSError about no path the user gave (a full disk) is a real failure, not bad input.
    monkeypatch.setattr(bench_cli, "run", raise_(OSError(28, os.strerror(28))))
    with pytest.raises(OSError):
        main(["bench"])
