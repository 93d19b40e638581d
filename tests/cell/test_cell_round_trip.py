"""A session's answers are what plan-fast picks in-process from the same perceived observation.

The container and buffer images are rendered by packlab's simulated cameras (cell_scenes.py);
the in-process side builds perceived mode's observation with packlab's own functions
(``heightmap_from_depth``, ``perceive_buffer``'s boxes, ``size_cells``) and asks its own
plan-fast, step after step, with the history it keeps itself.
"""

from __future__ import annotations

import numpy as np
import pytest
from cell_scenes import PRESET, generated_case, in_process

from packlab.cell import schema
from packlab.cell.client import CellServiceError
from packlab.cell.simulated import planned_steps, session_request, simulated_camera
from packlab.core.feasibility import placement_height
from packlab.sim.execution import seat_sides
from packlab.sim.physics.place_skill import APPROACH_MM


def _step(client, session_id, scene, **extra):
    return client.step(
        session_id,
        scene.container_image.depth_mm,
        scene.buffer.image.depth_mm,
        remaining=scene.remaining,
        buffer_camera=simulated_camera(scene.buffer.image),
        **extra,
    )


def _assert_same(answer: schema.StepAnswer, reference) -> None:
    action, heightmap, shown = reference
    np.testing.assert_array_equal(np.array(answer.heightmap.values_mm), heightmap)
    assert [b.size_mm for b in answer.boxes] == [s.size_mm for s in shown]
    assert answer.box.index == action.object_id
    assert answer.decision == "place" and answer.placement is not None
    assert (answer.placement.rotation, *answer.placement.cell) == (
        action.rotation,
        action.x,
        action.y,
    )


def test_a_session_answers_what_plan_fast_picks_in_process(client, medium_case, medium_scenes):
    opened = client.open(session_request(medium_case, PRESET, medium_scenes[0]))
    assert opened.policy == "plan-fast"
    assert opened.heightmap_cells == medium_case.container.cells
    references = in_process(medium_case, medium_scenes)
    for step, (scene, reference) in enumerate(zip(medium_scenes, references)):
        answer = _step(client, opened.session_id, scene)
        assert answer.step_index == step and answer.session_id == opened.session_id
        _assert_same(answer, reference)
    client.close(opened.session_id)


def test_a_hard_case_round_trip(client):
    case = generated_case("hard", seed=3)
    steps = planned_steps(case, PRESET, steps=3, seed=2)
    opened = client.open(session_request(case, PRESET, steps[0]))
    for scene, reference in zip(steps, in_process(case, steps)):
        _assert_same(_step(client, opened.session_id, scene), reference)


def test_the_stateless_plan_equals_a_one_step_session(client, medium_case, medium_scenes):
    scene = medium_scenes[2]
    request = session_request(medium_case, PRESET, scene)
    opened = client.open(request)
    stepped = _step(client, opened.session_id, scene)
    session = request.model_copy(update={"buffer_camera": simulated_camera(scene.buffer.image)})
    planned = client.plan(
        session,
        scene.container_image.depth_mm,
        scene.buffer.image.depth_mm,
        remaining=scene.remaining,
    )
    assert planned.session_id is None
    ignore = {"session_id", "timings_ms"}
    assert planned.model_dump(exclude=ignore) == stepped.model_dump(exclude=ignore)


def test_detections_instead_of_a_buffer_image(client, medium_case, medium_scenes):
    sizes = [[(325, 300, 210), (600, 425, 210), (300, 250, 180)] for _ in medium_scenes[:2]]
    opened = client.open(session_request(medium_case, PRESET, medium_scenes[0]))
    references = in_process(medium_case, medium_scenes[:2], sizes=sizes)
    for t, scene in enumerate(medium_scenes[:2]):
        detections = [
            schema.Detection(
                size_mm=s, pick=schema.PickPose(x_mm=100.0 * i, y_mm=0, z_mm=s[2], yaw_deg=0)
            )
            for i, s in enumerate(sizes[t])
        ]
        answer = client.step(
            opened.session_id,
            scene.container_image.depth_mm,
            detections=detections,
            remaining=scene.remaining,
        )
        _assert_same(answer, references[t])
        assert answer.dropped_segments == 0
        assert answer.box.pick is not None and answer.box.pick.x_mm == 100.0 * answer.box.index


@pytest.mark.parametrize("encoding", ["u16", "png16"])
def test_integer_encodings_give_the_same_answer(client, medium_case, encoding):
    # Noise-free, the container's depths are whole mm: u16 and PNG carry them exactly.
    steps = planned_steps(medium_case, "none", steps=2, seed=4)
    request = session_request(medium_case, "none", steps[1])
    answers = []
    for chosen in ("f32", encoding):
        opened = client.open(request)
        answers.append(
            client.step(
                opened.session_id,
                steps[1].container_image.depth_mm,
                detections=[schema.Detection(size_mm=(300, 200, 100))],
                encoding=chosen,
            )
        )
    ignore = {"session_id", "timings_ms"}
    assert answers[0].model_dump(exclude=ignore) == answers[1].model_dump(exclude=ignore)


def test_the_answer_carries_the_place_skill_s_approach(client, medium_case, medium_scenes):
    scene = medium_scenes[3]
    opened = client.open(session_request(medium_case, PRESET, scene))
    answer = _step(client, opened.session_id, scene)
    placement = answer.placement
    heightmap = np.array(answer.heightmap.values_mm)
    l, w, h = answer.box.size_mm
    fx, fy = (w, l) if placement.rotation == 1 else (l, w)
    x, y = placement.cell
    cells = (-(-fx // 25), -(-fy // 25))
    bottom = placement_height(heightmap, x, y, *cells)
    assert placement.bottom_z_mm == bottom
    assert placement.footprint_mm == (fx, fy)
    target = placement.target
    assert (target.x_mm, target.y_mm, target.z_mm) == (x * 25 + fx / 2, y * 25 + fy / 2, bottom + h)
    assert target.yaw_deg == 90.0 * placement.rotation
    approach = placement.approach
    assert approach.start_mm[2] == heightmap.max() + APPROACH_MM + h
    assert approach.release_mm[2] == bottom + h + 5.0  # structured light releases 5 mm up
    assert approach.seat_sides == seat_sides(heightmap, x, y, cells, bottom)
    assert approach.set_aside_if_stuck


def test_a_closed_session_is_gone(client, medium_case, medium_scenes):
    opened = client.open(session_request(medium_case, PRESET, medium_scenes[0]))
    client.close(opened.session_id)
    with pytest.raises(CellServiceError) as caught:
        _step(client, opened.session_id, medium_scenes[0])
    assert caught.value.status == 404
