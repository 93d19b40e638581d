"""The Rerun export: .rrd files read back with rerun's own reader; ``packlab viz rerun``.

Needs the ``viewer`` extra (rerun-sdk); the test command installs it.
"""

from __future__ import annotations

import socket
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from layered_cases import make_layered_case
from viz_policies import OutOfBoundsAtStep1

from packlab.bench.config import RunConfig
from packlab.bench.records import read_records
from packlab.bench.runner import run_bench
from packlab.cases import save_cases
from packlab.cli.main import main
from packlab.sim.episode import run_episode
from packlab.viz.rerun_export import ViewerTarget, export_live, viewer_listening

rerun = pytest.importorskip("rerun", reason="the viewer extra (rerun-sdk) is not installed")
from rerun.chunk import RrdReader

STEP = "step"


def read_rrd(path: Path) -> dict[str, list]:
    """Entity path -> the arrow rows logged to it, as dicts (column name -> value), in order.

    Static rows have no ``step`` key. The file is read with rerun's own reader.
    """
    rows: dict[str, list] = defaultdict(list)
    for chunk in RrdReader(path).stream().to_chunks():
        for row in chunk.to_record_batch().to_pylist():
            rows[chunk.entity_path.lstrip("/")].append(row)
    for logged in rows.values():
        logged.sort(key=lambda r: (r.get(STEP) is not None, r.get(STEP) or 0))
    return dict(rows)


def steps_of(rows: list) -> list[int]:
    return [r[STEP] for r in rows if r.get(STEP) is not None]


@pytest.fixture(scope="module")
def case():
    return make_layered_case(5, episode_id="rerun-5")


@pytest.fixture(scope="module")
def live_rrd(case, tmp_path_factory):
    out = tmp_path_factory.mktemp("rrd") / "live.rrd"
    exported = export_live(case, OutOfBoundsAtStep1(), "oob1", ViewerTarget(out), 0, "geometric")
    return out, exported


def test_live_export_holds_one_entity_per_box_and_one_frame_per_step(case, live_rrd):
    out, exported = live_rrd
    rows = read_rrd(out)
    n = len(case.objects)
    assert exported.saved == out and exported.steps == n and exported.streamed_to is None
    boxes = {e.removeprefix("world/boxes/") for e in rows if e.startswith("world/boxes/")}
    assert boxes == {str(b.internal_id) for b in case.objects}
    for entity in ("heightmap/tensor", "heightmap/image", "log", "buffer", "world/buffer"):
        assert steps_of(rows[entity]) == list(range(n)), entity
    assert steps_of(rows["timing/policy_ms"]) == list(range(n))
    assert {"world", "world/container", "case"} <= set(rows)
    assert steps_of(rows["summary"]) == [n - 1]


def test_live_export_boxes_sit_at_the_episode_poses(case, live_rrd):
    out, _ = live_rrd
    rows = read_rrd(out)
    result = run_episode(case, OutOfBoundsAtStep1(), 0, "geometric")
    positions, quats = result.steps[-1].positions_mm, result.steps[-1].quaternions
    set_aside = result.steps[1].internal_id
    for i, box in enumerate(case.objects):
        logged = rows[f"world/boxes/{box.internal_id}"]
        assert len(logged) == 1  # geometric boxes never move: logged once, when placed
        placed_at = next(s.step_index for s in result.steps if s.internal_id == box.internal_id)
        assert logged[0][STEP] == placed_at
        if box.internal_id == set_aside:  # on the shelf beside the container
            assert logged[0]["Boxes3D:centers"][0][0] * 1e3 > case.container.size_mm[0]
            continue
        np.testing.assert_allclose(
            np.array(logged[0]["Boxes3D:centers"][0]) * 1e3, positions[i], atol=1e-3
        )
        w, x, y, z = quats[i]
        np.testing.assert_allclose(logged[0]["Boxes3D:quaternions"][0], [x, y, z, w], atol=1e-6)
        half = np.array(logged[0]["Boxes3D:half_sizes"][0]) * 2e3
        np.testing.assert_allclose(half, box.size_mm, atol=1e-3)


def test_heightmap_tensor_is_the_heightmap_after_each_step(case, live_rrd):
    out, _ = live_rrd
    tensors = read_rrd(out)["heightmap/tensor"]
    result = run_episode(case, OutOfBoundsAtStep1(), 0, "geometric")
    last = tensors[-1]["Tensor:data"][0]
    assert last["shape"] == list(case.container.cells)
    assert max(last["buffer"]) == max(result.metrics.max_height_mm, 0)


@pytest.fixture(scope="module")
def run_dir(case, tmp_path_factory):
    root = tmp_path_factory.mktemp("bench")
    cases = root / "cases.jsonl"
    save_cases([case], cases)
    cfg = RunConfig(
        cases=str(cases),
        out=str(root / "run"),
        backend="geometric",
        policies=("dblf", "random"),
        seeds=(0, 1),
        workers=1,
        progress=False,
    )
    run_bench(cfg, figures=False)
    return root / "run"


def test_cli_saves_a_record_in_the_current_directory(run_dir, case, tmp_path, monkeypatch, capsys):
    # Not inside the bench run's directory: a run directory changes only when a run writes it.
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    before = sorted(p.relative_to(run_dir) for p in run_dir.rglob("*"))
    args = ["viz", "rerun", str(run_dir), "--case", case.episode_id, "--policy", "random"]
    assert main([*args, "--seed", "1"]) == 0
    name = f"{case.episode_id}_random_seed1.rrd"
    assert f"saved {name}" in capsys.readouterr().out
    out = here / name
    assert sorted(p.relative_to(run_dir) for p in run_dir.rglob("*")) == before
    record = next(
        r for r in read_records(run_dir / "episodes.jsonl") if r.policy == "random" and r.seed == 1
    )
    rows = read_rrd(out)
    assert steps_of(rows["heightmap/tensor"]) == list(range(len(record.steps)))
    assert steps_of(rows["timing/policy_ms_mean"]) == list(range(len(record.steps)))
    assert "timing/policy_ms" not in rows  # records keep no per-step latency
    assert len([e for e in rows if e.startswith("world/boxes/")]) == len(case.objects)


def test_cli_resimulates_a_record_on_request(run_dir, case, tmp_path, capsys):
    out = tmp_path / "again.rrd"
    args = ["viz", "rerun", str(run_dir / "episodes.jsonl"), "--case", case.episode_id]
    assert main([*args, "--policy", "dblf", "--resimulate", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "(re-simulated)" in captured.out and "warning" not in captured.err
    assert steps_of(read_rrd(out)["log"]) == list(range(len(case.objects)))


def test_cli_live_episode(case, tmp_path, capsys):
    cases = tmp_path / "cases.jsonl"
    save_cases([case], cases)
    out = tmp_path / "live.rrd"
    argv = ["viz", "rerun", "--live", "--policies", "dblf", "--case", case.episode_id]
    argv += ["--cases", str(cases), "--backend", "geometric", "--seed", "2", "--out", str(out)]
    assert main(argv) == 0
    assert "(live)" in capsys.readouterr().out
    assert steps_of(read_rrd(out)["timing/policy_ms"]) == list(range(len(case.objects)))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_cli_connect_without_a_viewer_saves_the_file(run_dir, case, tmp_path, capsys):
    out = tmp_path / "fallback.rrd"
    url = f"rerun+http://127.0.0.1:{_free_port()}/proxy"
    argv = ["viz", "rerun", str(run_dir), "--case", case.episode_id, "--policy", "dblf"]
    assert main([*argv, "--connect", url, "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert f"no Rerun viewer at {url}" in captured.err and out.is_file()
    assert steps_of(read_rrd(out)["log"]) == list(range(len(case.objects)))


def test_viewer_listening_probes_the_port():
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        assert viewer_listening(f"rerun+http://127.0.0.1:{port}/proxy")
    assert not viewer_listening(f"rerun+http://127.0.0.1:{_free_port()}/proxy")


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--live"], "--live runs a new episode"),
        (["--backend", "mujoco"], "--backend: only with --live"),
        (["--policy-arg", "dblf:x=1"], "--policy-arg: only with --live"),
        (["--out", "x.png"], "ends in .rrd"),
        (["--connect", "nonsense"], "not a viewer URL"),
    ],
)
def test_cli_bad_flags_are_one_line_errors(run_dir, case, extra, message, capsys):
    argv = ["viz", "rerun", str(run_dir), "--case", case.episode_id, "--policy", "dblf"]
    assert main([*argv, *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--case", "c", "--policy", "dblf"], "give RECORDS"),
        (["--live", "--case", "c", "--policy", "dblf,random"], "one policy per recording"),
        (["--live", "--case", "c", "--policy", "dblf", "--resimulate"], "only for records"),
        (["--live", "--case", "c", "--policy", "no-such-policy"], "no-such-policy"),
    ],
)
def test_cli_mode_errors(argv, message, capsys):
    assert main(["viz", "rerun", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_cli_live_unknown_case_names_the_source(case, tmp_path, capsys):
    cases = tmp_path / "cases.jsonl"
    save_cases([case], cases)
    argv = ["viz", "rerun", "--live", "--policy", "dblf", "--case", "nope", "--cases", str(cases)]
    assert main([*argv, "--backend", "geometric", "--out", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err
    assert "'nope'" in err and str(cases) in err
