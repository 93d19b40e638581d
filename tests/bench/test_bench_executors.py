"""The same bench run on every executor gives the same episode records (timings aside).

``packlab bench --executor process`` in this process (one worker) and on a pool (two), and on
Ray (slow): identical records and scores; the executor is saved in config.json.
"""

from __future__ import annotations

import json

import pytest
from record_helpers import without_timing

from packlab.bench.records import read_record_file, record_key
from packlab.cli.main import main
from packlab.core.records import to_builtins

POLICIES = "dblf,ffp,random,oracle"


def bench(cases, out, executor: str, workers: int) -> dict:
    argv = [
        "bench",
        "--cases",
        str(cases),
        "--backend",
        "geometric",
        "--policies",
        POLICIES,
        "--seeds",
        "0,1",
        "--executor",
        executor,
        "--workers",
        str(workers),
        "--out",
        str(out),
        "--no-progress",
        "--no-figures",
    ]
    assert main(argv) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["execution"]["executor"] == executor and config["execution"]["workers"] == workers
    records = read_record_file(out / "episodes.jsonl").records
    by_key = {record_key(r): without_timing(to_builtins(r)) for r in records}
    assert len(by_key) == len(records) == 4 * 4 * 2  # every episode once
    return by_key


@pytest.mark.parametrize(
    "executor, workers",
    [
        ("process", 2),
        ("process", 3),
        pytest.param("ray", 2, marks=pytest.mark.slow),
    ],
)
def test_every_executor_gives_the_same_records(
    tiny_suite, tmp_path, capsys, executor, workers, request
):
    if executor == "ray":
        request.getfixturevalue("ray_cluster")  # one cluster for every Ray test
    reference = bench(tiny_suite, tmp_path / "serial", "process", 1)
    assert bench(tiny_suite, tmp_path / executor, executor, workers) == reference
    # The scores too (table.md also shows timings, which differ).
    first, then = (
        json.loads((tmp_path / run / "summary.json").read_text()) for run in ("serial", executor)
    )
    for part in ("table", "per_case", "counts", "errors"):
        assert without_timing(first[part]) == without_timing(then[part]), part


def test_the_cli_default_executor_and_workers_come_from_the_config():
    from packlab.bench.config import RunConfig
    from packlab.cli.main import build_parser

    args = build_parser().parse_args(["bench"])
    assert (args.executor, args.workers) == (RunConfig().executor, RunConfig().workers)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["bench", "--executor", "dask"])
