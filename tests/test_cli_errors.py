"""Bad command-line input: one clear line ``packlab <cmd>: error: ...``, exit code 2, nothing
written (each case names the value that was wrong and asserts where the message says so)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

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
    (["--policy-arg", "dblf:nope=1", "--policies", "dblf"], "dblf:nope: unknown option"),
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
    # One line, no usage block above it (packlab.cli.parser).
    assert capsys.readouterr().err.strip() == (
        "packlab bench: error: argument --episode-timeout: invalid float value: 'abc' "
        "(see packlab bench --help)"
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


#: Bad inputs refused up front: each is one line, exit code 2, before any heavy import and before
#: a run directory exists (benchmarks/maintainers/cli_bad_input.py times them in fresh
#: interpreters).
UP_FRONT = [
    (["bench", "--policies", "dblff"], "'dblff' is not a registered policy (did you mean 'dblf'?)"),
    (["bench", "--policy-arg", "irbpp:modle=x"], "irbpp:modle: unknown option (did you mean"),
    (["bench", "--policy-arg", "irbpp:runtime=onxx"], "(did you mean 'onnx'?)"),
    (["bench", "--policy-arg", "irbpp:threads=0"], "irbpp:threads = 0: must be a whole number"),
    (["bench", "--policy-arg", "irbpp:model=nosuch"], "irbpp:model = 'nosuch': no such directory"),
    (["bench", "--policy-arg", "vlm:model=nosuch"], "vlm:model = 'nosuch': no such directory"),
    (["bench", "--policy-arg", "plan:model=x"], "policy 'plan' is not among the policies to run"),
    (["bench", "--cases", "nosuch.jsonl"], "cases = 'nosuch.jsonl': no such file or directory"),
    (["bench", "--cases", "packlab-bench-v2"], "(did you mean 'packlab-bench-v1'?)"),
    (["bench", "--seeds", "0-x"], "seeds = '0-x'"),
    (["bench", "--workers", "-1"], "workers = -1"),
    (["generate", "--difficulty", "easy", "--episodes", "0", "--out", "d"], "nothing to generate"),
    (
        ["generate", "--difficulty", "easy", "--episodes", "1", "--teacher", "plna", "--out", "d"],
        "(did you mean 'plan'?)",
    ),
]


@pytest.mark.parametrize("argv, message", UP_FRONT, ids=[" ".join(a) for a, _ in UP_FRONT])
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)  # the default run directory would be runs/... under here
    code, err = _run(argv, capsys)
    assert code == EXIT_USAGE, err
    assert len(err.splitlines()) == 1 and message in err, err
    assert list(tmp_path.iterdir()) == []  # no run directory, no dataset


def test_model_dir_without_its_files(tmp_path, capsys):
    empty = tmp_path / "agent"
    empty.mkdir()
    code, err = _run(["bench", "--policy-arg", f"irbpp:model={empty}"], capsys)
    assert code == EXIT_USAGE and "no card.json, not an RL agent directory" in err
    (empty / "card.json").write_text("{}")
    code, err = _run(["bench", "--policy-arg", f"tapnet:model={empty}"], capsys)
    assert code == EXIT_USAGE and "no onnx.json (not exported to ONNX)" in err
    assert "packlab export onnx" in err and len(err.splitlines()) == 1


def test_misspelt_subcommand_gets_the_nearest_name(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bnech"])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == EXIT_USAGE and len(err.splitlines()) == 1
    assert "invalid choice: 'bnech' (did you mean 'bench'?)" in err


_NO_HEAVY_PROBE = """
import contextlib, io, json, sys
from packlab.cli.main import main
with contextlib.redirect_stderr(io.StringIO()):
    code = main(json.loads(sys.argv[1]))
heavy = ("mujoco", "matplotlib", "plotly", "scipy", "onnxruntime", "torch", "packlab.bench.runner")
print(json.dumps([code, sorted(m for m in sys.modules if m.split(".")[0] in heavy
                                or m.startswith("packlab.bench.runner"))]))
"""


@pytest.mark.parametrize(
    "argv",
    [a for a, _ in UP_FRONT if a[0] == "bench"][:5],
    ids=lambda a: " ".join(a),
)
def test_bench_flag_errors_come_before_heavy_imports(tmp_path, argv):
    # What makes the error come in a fraction of a second: nothing heavy is loaded before it.
    done = subprocess.run(
        [sys.executable, "-c", _NO_HEAVY_PROBE, json.dumps(argv)],
        capture_output=True,
        text=True,
        check=True,
        cwd=tmp_path,
    )
    assert json.loads(done.stdout.splitlines()[-1]) == [EXIT_USAGE, []]
