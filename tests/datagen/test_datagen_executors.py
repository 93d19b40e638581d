"""``packlab generate`` on every executor makes the same dataset (timings aside).

``--executor process`` in this process (one worker) and on a pool (two), and Ray (slow):
identical episode and step rows, images, SFT files, shard markers and info.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
from record_helpers import without_timing

from packlab.cli.main import main
from packlab.datagen import format as fmt


def contents(root: Path) -> dict[str, Any]:
    """Every file of a dataset: parquet as rows, JSON as data (timings removed), others as bytes.
    The README is left out: it is written from info.json, which is compared."""
    out: dict[str, Any] = {}
    for path in sorted(p for p in root.rglob("*") if p.is_file() and p.name != "README.md"):
        name = str(path.relative_to(root))
        if path.suffix == ".parquet":
            out[name] = without_timing(pq.read_table(path).to_pylist())
        elif path.suffix == ".json":
            out[name] = without_timing(json.loads(path.read_text()))
        else:
            out[name] = path.read_bytes()
    return out


def generate(out: Path, executor: str, workers: int) -> dict[str, Any]:
    argv = [
        "generate",
        "--difficulty",
        "easy,hard",
        "--episodes",
        "3,2",
        "--seed",
        "2",
        "--shard-size",
        "2",
        "--validation",
        "geometric",
        "--image-size",
        "48",
        "--executor",
        executor,
        "--workers",
        str(workers),
        "--out",
        str(out),
        "--no-progress",
    ]
    assert main(argv) == 0
    found = contents(out)
    for kind in (fmt.STEPS_DIR, fmt.EPISODES_DIR, fmt.IMAGES_DIR, fmt.SHARDS_DIR):
        assert any(name.startswith(f"{kind}/") for name in found), kind
    assert f"{fmt.META_DIR}/info.json" in found
    return found


@pytest.mark.parametrize(
    "executor, workers",
    [
        ("process", 2),
        pytest.param("ray", 2, marks=pytest.mark.slow),
    ],
)
def test_every_executor_makes_the_same_dataset(tmp_path, capsys, executor, workers, request):
    if executor == "ray":
        request.getfixturevalue("ray_cluster")  # one cluster for every Ray test
    reference = generate(tmp_path / "serial", "process", 1)
    assert generate(tmp_path / executor, executor, workers) == reference


def test_the_cli_default_executor_and_workers_come_from_the_options():
    from packlab.cli.main import build_parser
    from packlab.datagen.engine import RunOptions

    args = build_parser().parse_args(["generate", "--out", "x"])
    assert (args.executor, args.workers) == (RunOptions("x").executor, RunOptions("x").workers)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["generate", "--out", "x", "--executor", "serial"])
