"""``packlab bench --via-cell URL``: the bench's honest episodes played by the policy of a live
cell service, which sees only the rendered depth images and calibrations, give the records of
the same run in-process (timings aside; on these cases no decision falls between two boxes of
the same measured size, the one place the two may differ: docs/cell.md); an unreachable service
or one that cannot serve the bench's policy stops the run before it starts, in one line."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
from cell_scenes import LiveServer, free_port, generated_case

from packlab.cases import save_cases
from packlab.cell import schema
from packlab.cell.via_cell import CellPolicy, episode_action, tapped_modes
from packlab.cli.main import main
from packlab.core.types import Action, Unparsable
from packlab.policies import make_policy
from packlab.sim.episode import run_episode
from packlab.sim.modes import episode_modes

HONEST = [
    "--observation",
    "perceived",
    "--execution",
    "noisy",
    "--noise",
    "structured-light",
]
#: Record keys that time the run (wall or CPU seconds): the only ones the two paths may differ in.
TIMES = {"timing", "decision_s", "decision_cpu_s", "wall_time_s", "policy_time_s"}


def _untimed(value):
    if isinstance(value, dict):
        return {k: _untimed(v) for k, v in value.items() if k not in TIMES}
    if isinstance(value, list):
        return [_untimed(v) for v in value]
    return value


def _records(out) -> dict:
    lines = (out / "episodes.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]
    return {(r["case_id"], r["seed"]): _untimed(r) for r in records}


def _bench(cases, out, *extra) -> int:
    return main(
        [
            "bench",
            "--cases",
            str(cases),
            "--policies",
            "plan-fast",
            "--seeds",
            "0,1",
            "--workers",
            "1",
            "--no-progress",
            "--no-html",
            "--no-figures",
            "--out",
            str(out),
            *HONEST,
            *extra,
        ]
    )


@pytest.fixture(scope="module")
def small_cases(tmp_path_factory):
    """Two small generated cases (the training seed space; never a bench suite's)."""
    path = tmp_path_factory.mktemp("cases") / "cases.jsonl"
    save_cases([generated_case("easy", seed=11), generated_case("easy", seed=12, slot=1)], path)
    return path


def test_via_cell_records_equal_the_in_process_honest_run(small_cases, tmp_path, capsys):
    assert _bench(small_cases, tmp_path / "here") == 0
    with LiveServer() as url:
        assert _bench(small_cases, tmp_path / "cell", "--via-cell", url) == 0
    here, cell = _records(tmp_path / "here"), _records(tmp_path / "cell")
    assert len(here) == 4 and all(r["status"] == "ok" for r in here.values())
    assert cell == here
    config = json.loads((tmp_path / "cell" / "config.json").read_text())
    assert config["execution"]["via_cell"] == url


def test_an_unreachable_service_stops_the_run_in_one_line(small_cases, tmp_path, capsys):
    url = f"http://127.0.0.1:{free_port()}"
    assert _bench(small_cases, tmp_path / "out", "--via-cell", url) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"via-cell = {url!r}: no cell service answered" in err
    assert "packlab cell serve" in err
    assert not (tmp_path / "out" / "episodes.jsonl").exists()


def test_a_service_without_the_bench_policy_stops_the_run(
    small_cases, tmp_path, capsys, monkeypatch
):
    monkeypatch.setattr("packlab.cell.app.available_policies", lambda: ["dblf", "random"])
    with LiveServer() as url:
        assert _bench(small_cases, tmp_path / "out", "--via-cell", url) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"via-cell = {url!r}: the service cannot serve 'plan-fast' (it serves dblf, random)" in (
        err
    )


def test_via_cell_needs_perceived_observation(small_cases, tmp_path, capsys):
    code = main(
        ["bench", "--cases", str(small_cases), "--policies", "plan-fast", "--out", str(tmp_path)]
        + ["--via-cell", "http://127.0.0.1:1", "--no-progress"]
    )
    assert code == 2
    assert "add --observation perceived" in capsys.readouterr().err


def test_an_answer_names_the_listed_box_of_its_segment():
    a, b, c = object(), object(), object()  # the buffer image's segments, in image order
    # Segment b lies on no box (noise over the table): the episode lists a and c, in that order.
    state = SimpleNamespace(buffer=SimpleNamespace(found=(a, b, c), listed=(0, 2)))
    box = {"index": 0, "size_mm": (100, 100, 100)}
    heightmap = {"cells": (1, 1), "cell_mm": 25, "values_mm": [[0]], "unseen_cells": 0}
    timings = {"decode": 0, "heightmap": 0, "segmentation": 0, "policy": 0, "total": 0}

    def answer(action):
        return schema.StepAnswer.model_validate(
            {
                "session_id": "s",
                "step_index": 0,
                "decision": "place",
                "reason": None,
                "box": box,
                "placement": None,
                "boxes": [{**box, "index": i} for i in range(3)],
                "action": action,
                "dropped_segments": 0,
                "heightmap": heightmap,
                "timings_ms": timings,
            }
        )

    placed = {"object_id": 0, "rotation": 1, "x": 2, "y": 3}
    assert episode_action(answer(placed), state) == Action(0, 1, 2, 3)
    aside = {"object_id": 2, "rotation": 0, "x": -1, "y": -1}
    assert episode_action(answer(aside), state) == Action.set_aside(1)
    on_nothing = {"object_id": 1, "rotation": 0, "x": 0, "y": 0}
    assert episode_action(answer(on_nothing), state).object_id >= 2  # names no listed box
    beyond = {"object_id": 5, "rotation": 0, "x": 0, "y": 0}
    assert episode_action(answer(beyond), state).object_id >= 2  # out of range here too
    assert isinstance(episode_action(answer(None), state), Unparsable)


def test_the_service_and_the_episode_list_the_boxes_in_one_order(client):
    """Both list the buffer's box-like segments in label order, so plan-fast served by the
    service and plan-fast in-process take the same box even between two of the same size (this
    case has such a pair), and their records are the same."""
    case = generated_case("easy", seed=26)

    def record(policy, modes):
        result = run_episode(case, policy, 0, perceiver=modes.perceiver, execution=modes.execution)
        return _untimed(json.loads(json.dumps(result.to_record())))

    honest = episode_modes("perceived", "noisy", "structured-light")
    here = record(make_policy("plan-fast"), honest)
    modes, tap = tapped_modes(honest)
    served = CellPolicy(client, "plan-fast", {}, tap, "structured-light")
    cell = record(served, modes)
    served.close()
    assert cell == here
