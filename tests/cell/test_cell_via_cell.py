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
from packlab.cell.step import MeasuredBox, judge, shown_items
from packlab.cell.via_cell import CellPolicy, episode_action, tapped_modes
from packlab.cli.main import main
from packlab.core.types import Action, HistoryEntry, Observation, Unparsable
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


def test_an_answer_names_the_shown_box_its_segment_lies_on():
    a, b, c = object(), object(), object()  # the buffer image's segments, in image order
    # Shown boxes 0, 1, 2 lie under segments c, a, b.
    state = SimpleNamespace(buffer=SimpleNamespace(found=(a, b, c), estimates=(c, a, b)))
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
    assert episode_action(answer(placed), state) == Action(1, 1, 2, 3)
    aside = {"object_id": 2, "rotation": 0, "x": -1, "y": -1}
    assert episode_action(answer(aside), state) == Action.set_aside(0)
    beyond = {"object_id": 5, "rotation": 0, "x": 0, "y": 0}
    assert episode_action(answer(beyond), state).object_id >= 3  # out of range here too
    assert isinstance(episode_action(answer(None), state), Unparsable)


class _ServiceOrder:
    """plan-fast in this process, shown the buffer as the service shows it: boxes in the order
    of their segments in the buffer image, the service's ids and history (``cell.step``)."""

    name = "plan-fast"

    def __init__(self, tap):
        self._policy, self._tap = make_policy("plan-fast"), tap

    def reset(self, start, seed):
        self._policy.reset(start, seed)
        self._history, self._next_id = [], 0

    def act(self, observation):
        buffer = self._tap.last.buffer
        shown_of = [next(i for i, e in enumerate(buffer.estimates) if e is f) for f in buffer.found]
        boxes = tuple(MeasuredBox(j, f.size_mm, None) for j, f in enumerate(buffer.found))
        shown = shown_items(boxes, observation.container, self._next_id)
        self._next_id += len(shown)
        seen = Observation(
            step_index=len(self._history),
            container=observation.container,
            heightmap=observation.heightmap.copy(),
            shown=shown,
            history=tuple(self._history),
            remaining=observation.remaining,
        )
        action = self._policy.act(seen)
        valid = judge(action, seen)[0] is None
        self._history.append(HistoryEntry(observation.heightmap, shown, action, valid))
        return Action(shown_of[action.object_id], action.rotation, action.x, action.y)


def test_where_the_records_differ_only_the_order_of_the_boxes_does(client):
    """A case where plan-fast, in-process, takes another of two boxes of the same size than the
    service's plan-fast: shown the boxes in the service's order, it gives the service's records."""
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
    assert cell["metrics"]["overall"] == here["metrics"]["overall"]
    assert cell != here  # another carton of the same size went first
    modes, tap = tapped_modes(honest)
    assert record(_ServiceOrder(tap), modes) == cell
