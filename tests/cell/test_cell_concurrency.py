"""Eight sessions at once on a live server: no error, and each answers as if alone."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import pytest
from cell_scenes import PRESET, LiveServer, generated_case, in_process

from packlab.cell.client import CellClient
from packlab.cell.simulated import planned_steps, session_request, simulated_camera

SESSIONS = 8
STEPS = 3


def one_cell(url: str, case, steps) -> list[tuple[int, int, int, int]]:
    """A cell packing one container: open, step, close; its (box, rotation, x, y) per step."""
    with CellClient(url) as client:
        opened = client.open(session_request(case, PRESET, steps[0]))
        answers = []
        for scene in steps:
            answer = client.step(
                opened.session_id,
                scene.container_image.depth_mm,
                scene.buffer.image.depth_mm,
                remaining=scene.remaining,
                buffer_camera=simulated_camera(scene.buffer.image),
            )
            answers.append((answer.box.index, answer.placement.rotation, *answer.placement.cell))
        client.close(opened.session_id)
        return answers


@pytest.mark.parametrize("workers", [1, 2], ids=["in-process", "two-planner-processes"])
def test_eight_sessions_at_once(workers):
    cells = []
    for i in range(SESSIONS):
        case = generated_case("medium" if i % 2 else "easy", seed=40 + i)
        steps = planned_steps(case, PRESET, steps=STEPS, seed=i)
        expected = [(a.object_id, a.rotation, a.x, a.y) for a, _, _ in in_process(case, steps)]
        cells.append((case, steps, expected))
    with LiveServer(workers) as url, ThreadPoolExecutor(SESSIONS) as pool:
        futures = [pool.submit(one_cell, url, case, steps) for case, steps, _ in cells]
        results = [f.result(timeout=300) for f in futures]
        with CellClient(url) as client:
            health = client.health()
    assert results == [expected for _, _, expected in cells]
    assert health.sessions == 0 and health.workers == workers
