"""``packlab bench`` on the command line: describe, run a case file, one-line errors."""

from __future__ import annotations

from packlab.cli.main import main


def test_describe_prints_the_suite_statistics(capsys):
    assert main(["bench", "--describe"]) == 0
    out = capsys.readouterr().out
    assert "packlab-bench-v1" in out and "easy" in out and "hard" in out and "steps" in out


def test_run_a_case_file_and_resume(tiny_suite, tmp_path, capsys):
    argv = [
        "bench",
        "--cases",
        str(tiny_suite),
        "--backend",
        "geometric",
        "--policies",
        "dblf,oracle",
        "--seeds",
        "0-1",
        "--difficulty",
        "easy",
        "--out",
        str(tmp_path / "run"),
        "--workers",
        "1",
        "--no-progress",
        "--no-figures",
    ]
    assert main(argv) == 0
    captured = capsys.readouterr()
    rows = [line.split("|")[1].strip() for line in captured.out.splitlines() if "|" in line]
    assert "DBLF" in rows and "Oracle (gt plan)" in rows
    assert "Easy Overall" in captured.out and "8 episodes run" in captured.err
    assert main(argv) == 0
    assert "0 episodes run" in capsys.readouterr().err


def test_bad_flags_are_one_line_errors(tiny_suite, tmp_path, capsys):
    code = main(["bench", "--cases", str(tiny_suite), "--seeds", "x", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.strip()
    assert (
        code == 2
        and err.startswith("packlab bench: error: seeds = 'x'")
        and len(err.splitlines()) == 1
    )
    code = main(["bench", "--cases", str(tmp_path / "missing.jsonl")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "missing.jsonl" in err and len(err.splitlines()) == 1
