"""Episodes are scored at rest, or say they were not: settle caps, records and run counts."""

import math

import msgspec
import mujoco
import numpy as np
import pytest
from settle_motion import movement_mm

from packlab.bench.summary import summarize
from packlab.bench.table import render_markdown
from packlab.bench.task import run_task
from packlab.core.records import episode_from_json, to_builtins
from packlab.core.types import Action, Box, Case, Container, PlanStep
from packlab.sim.episode import Episode
from packlab.sim.physics.mujoco_backend import MujocoBackend, PhysicsConfig, _net_squared_speeds

pytestmark = pytest.mark.physics

#: Per-placement cap far shorter than the slab's topple (about 0.3 s), final cap left at 10 s.
SHORT_STEP_CAP = PhysicsConfig(max_settle_steps=20)
#: Caps too short for anything to come to rest.
TINY_CAPS = PhysicsConfig(max_settle_steps=5, final_max_settle_steps=5)


def _toppling_slab_case() -> Case:
    """A narrow post and a slab dropped on it with three quarters overhanging: the slab topples.

    Its plan (both at cell 0, 0) lets the oracle replay it through the bench's ``run_task``.
    """
    container = Container((150, 100, 200))
    plan = (
        PlanStep(0, 0, 0, (0, 0, 0), (1, 4, 20), 0, 0, 0),
        PlanStep(1, 1, 1, (0, 0, 20), (4, 4, 10), 0, 0, 0),
    )
    return Case(
        "topple",
        container,
        1,
        (Box(0, (25, 100, 40)), Box(1, (100, 100, 20))),
        seed=0,
        gt_plan=plan,
    )


def _play(case: Case, physics: PhysicsConfig, actions) -> Episode:
    ep = Episode("mujoco", physics)
    ep.reset(case, 0)
    for action in actions:
        ep.step(action)
    return ep


def test_a_settle_longer_than_the_step_cap_finishes_in_the_final_settle_and_is_at_rest():
    ep = _play(_toppling_slab_case(), SHORT_STEP_CAP, [Action(0, 0, 0, 0), Action(0, 0, 0, 0)])
    last = ep.steps[-1]
    assert last.settled is False  # the topple outlasted the 20-step placement cap ...
    assert max(last.max_linear_speed / 0.01, last.max_angular_speed / 0.05) >= 1.0
    record = last.to_record()
    assert record["settled"] is False and record["max_linear_speed_mps"] == round(
        last.max_linear_speed, 6
    )
    m = ep.metrics()
    # ... and the final settle, under its own cap, ran until everything was still.
    assert m.at_rest is True and m.unsettled_steps == 1
    assert 0 < m.final_settle_steps < SHORT_STEP_CAP.final_max_settle_steps
    assert m.residual_linear_mps < 0.01 and m.residual_angular_radps < 0.05
    assert movement_mm(ep.backend, 250) < 0.5  # the scored poses are the final ones


def test_a_pile_that_cannot_settle_within_tiny_caps_is_flagged_and_counted():
    case = _toppling_slab_case()
    ep = _play(case, TINY_CAPS, [Action(0, 0, 0, 0), Action(0, 0, 0, 0)])
    m = ep.metrics()
    assert m.at_rest is False and m.final_settle_steps == TINY_CAPS.final_max_settle_steps
    assert max(m.residual_linear_mps / 0.01, m.residual_angular_radps / 0.05) >= 1.0
    assert m.unsettled_steps >= 1 and not all(s.settled for s in ep.steps)
    assert 0.0 <= m.overall <= 1.0  # still scored

    flagged = run_task(case, "oracle", 0, "mujoco", physics=TINY_CAPS)
    calm = run_task(case, "oracle", 0, "mujoco")
    assert flagged.status == calm.status == "ok"
    assert flagged.metrics.at_rest is False and calm.metrics.at_rest is True
    calm = msgspec.structs.replace(calm, policy="calm")
    summary = summarize([flagged, calm])
    assert summary.counts["oracle"].not_at_rest == 1
    assert summary.counts["oracle"].unsettled_steps == flagged.metrics.unsettled_steps >= 1
    assert summary.counts["calm"].not_at_rest == 0
    assert summary.counts["oracle"].max_residual_linear_mps == flagged.metrics.residual_linear_mps
    table = render_markdown(summary)
    assert "| unsettled steps | not at rest |" in table
    details = table.split("### Run details", 1)[1].split("###", 1)[0]
    oracle_row = next(line for line in details.splitlines() if line.startswith("| Oracle"))
    assert f"| {flagged.metrics.unsettled_steps} | 1 |" in oracle_row


def test_old_records_without_rest_fields_still_summarise():
    rec = to_builtins(run_task(_toppling_slab_case(), "oracle", 0, "geometric"))
    del rec["format"]  # written before records carried their version: migrated on reading
    for key in ("unsettled_steps", "at_rest", "residual_linear_mps", "residual_angular_radps"):
        rec["metrics"].pop(key)
    rec["metrics"]["capped_placements"] = 2
    counts = summarize([episode_from_json(rec, "old")]).counts["oracle"]
    assert counts.unsettled_steps == 2 and counts.not_at_rest == 0


def test_a_box_outside_the_walls_lands_on_the_floor_and_rests():
    # Something knocked over the rim falls to the floor beyond the walls: there is one.
    container = Container((100, 100, 100))
    backend = MujocoBackend()
    backend.reset(container, (Box(0, (50, 50, 40)),))
    backend.place(0, 0, (300, 0, 400))  # beyond the wall, 40 cm up
    final = backend.finish()
    assert final.settled and final.max_linear_speed < 0.01
    centre = backend.poses()[0][0]
    assert centre[0] > container.size_mm[0] and centre[2] == pytest.approx(20.0, abs=0.5)
    assert movement_mm(backend, 250) < 0.1


def test_overflowing_and_set_aside_boxes_end_at_rest_and_count_as_unpacked():
    container = Container((100, 100, 100))
    boxes = (Box(0, (100, 100, 80)), Box(1, (100, 100, 80)), Box(2, (50, 50, 50)))
    case = Case("overflow", container, 1, boxes, seed=0)
    # Box 1 lands on box 0 with its top 60 mm above the rim; box 2 is set aside (bad id).
    ep = _play(case, PhysicsConfig(), [Action(0, 0, 0, 0), Action(0, 0, 0, 0), Action(5, 0, 0, 0)])
    assert [s.valid for s in ep.steps] == [True, True, False]
    m = ep.metrics()
    assert m.at_rest and m.unsettled_steps == 0
    assert m.n_inside == 1 and m.n_set_aside == 1
    poses = ep.final_poses()
    assert poses[1].position_mm[2] == pytest.approx(120.0, abs=1.0) and poses[2] is None


def test_a_drop_inside_another_box_starts_on_top_of_it_instead():
    container = Container((200, 200, 300))
    backend = MujocoBackend()
    backend.reset(container, (Box(0, (100, 100, 50)), Box(1, (100, 100, 50))))
    backend.place(0, 0, (0, 0, 0))
    below = backend.poses()[0][0].copy()
    step = backend.place(1, 0, (0, 0, 10))  # 40 mm deep inside box 0, as a bad heightmap would say
    positions, _ = backend.poses()
    # Box 1 was raised and set down on box 0: it settles at once (left 40 mm deep, the solver
    # shoots it up and it needs about 350 steps to come down and settle), box 0 stays put.
    assert step.settled and step.settle_steps < 50
    assert positions[1][2] == pytest.approx(75.0, abs=1.0)
    assert np.abs(positions[0] - below).max() < 0.5


def _scripted_steps(backend: MujocoBackend, velocity_at):
    """A stand-in for ``mj_step`` that moves box 0 along x at ``velocity_at(step)`` m/s."""
    vel, pos = backend._qvel_slice(0), backend._qpos_slice(0)
    count = [0]

    def step(model, data):
        count[0] += 1
        v = velocity_at(count[0])
        data.qvel[vel] = (v, 0.0, 0.0, 0.0, 0.0, 0.0)
        data.qpos[pos.start] += v * model.opt.timestep

    return step


def test_vibration_in_place_is_rest_but_a_slow_steady_slide_is_not(monkeypatch):
    backend = MujocoBackend()
    backend.reset(Container((200, 200, 200)), (Box(0, (100, 100, 50)),))
    backend.place(0, 0, (0, 0, 0))
    # Solver chatter: +-5 cm/s every other step, going nowhere. Velocity alone says "moving".
    monkeypatch.setattr(
        mujoco, "mj_step", _scripted_steps(backend, lambda t: 0.05 if t % 2 else -0.05)
    )
    vibrating = backend.finish()
    assert vibrating.settled and vibrating.max_linear_speed < 0.01
    # A steady 2 cm/s slide is motion by both measures: the final settle runs into its cap.
    monkeypatch.setattr(mujoco, "mj_step", _scripted_steps(backend, lambda t: 0.02))
    sliding = backend.finish()
    assert not sliding.settled and sliding.settle_steps == PhysicsConfig().final_max_settle_steps
    assert sliding.max_linear_speed == pytest.approx(0.02)


def test_net_motion_speeds_measure_distance_and_rotation_over_the_span():
    before = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]])
    half = 0.05  # a 0.1 rad turn about z
    after = np.array([[0.003, 0.004, 0.0, math.cos(half), 0.0, 0.0, math.sin(half)]])
    lin2, ang2 = _net_squared_speeds(before, after, 0.02)[0]
    assert math.sqrt(lin2) == pytest.approx(0.25)  # 5 mm in 20 ms
    assert math.sqrt(ang2) == pytest.approx(5.0)  # 0.1 rad in 20 ms
    flipped = after.copy()
    flipped[0, 3:] *= -1  # the same orientation, the other sign of quaternion
    assert math.sqrt(_net_squared_speeds(before, flipped, 0.02)[0, 1]) == pytest.approx(5.0)


def test_geometric_episodes_are_at_rest_with_zero_residual():
    ep = Episode("geometric")
    ep.reset(_toppling_slab_case(), 0)
    ep.step(Action(0, 0, 0, 0))
    ep.step(Action(0, 0, 0, 0))
    m = ep.metrics()
    assert m.at_rest and m.unsettled_steps == 0 and m.final_settle_steps == 0
    assert m.residual_linear_mps == m.residual_angular_radps == 0.0
    assert all(s.to_record()["settled"] for s in ep.steps)


def test_final_cap_is_validated():
    from packlab.core.errors import ConfigError

    with pytest.raises(ConfigError, match="final_max_settle_steps"):
        PhysicsConfig(final_max_settle_steps=0)
    with pytest.raises(ConfigError, match="rest_motion_steps"):
        PhysicsConfig(rest_motion_steps=0)
