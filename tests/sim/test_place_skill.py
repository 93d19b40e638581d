"""A place skill that acts only on what the robot knows.

The command (``PlaceCommand``) comes from the size the robot was shown and the observed
heightmap, the executed pose carries the grasped box's pose-estimate error, the descent yields
to contact forces (``place_skill.descend``) and the seat pushes toward the sides the observed
heightmap shows flush (``packlab.sim.execution.seat_sides``), by guarded moves that stop on
contact force (``place_skill.seat``), never by probing the true scene, never squaring the yaw
or moving to the plan.
"""

from __future__ import annotations

from dataclasses import replace

import msgspec
import numpy as np
import pytest

from packlab.core.types import Action, Box, Case, Container
from packlab.sim.episode import Episode
from packlab.sim.execution import (
    ExecutionNoise,
    execution_noise,
    full_faces,
    perturb_drop,
    place_command,
    seat_sides,
)
from packlab.sim.physics.mujoco_backend import MujocoBackend
from packlab.sim.physics.place_skill import PlaceCommand
from packlab.sim.replan import Perception, Scene

pytestmark = pytest.mark.physics

SEAT_ONLY = ExecutionNoise(comply_mm=10.0, seat_mm=5.0)  # no arm noise: only grasp errors


# -- seat sides from the observed heightmap --------------------------------------------------


def test_seat_sides_are_walls_or_neighbours_rising_above_the_bottom():
    hm = np.zeros((8, 6), dtype=np.int32)
    # Against the -x and -y walls.
    assert seat_sides(hm, 0, 0, (2, 2), 0) == (-1, -1)
    # Against the +x and +y walls only.
    assert seat_sides(hm, 6, 4, (2, 2), 0) == (1, 1)
    # In the open: nothing to push against.
    assert seat_sides(hm, 3, 2, (2, 2), 0) == (0, 0)
    hm[2, 3] = 10  # one cell of the -x strip rises 10 mm: a face
    assert seat_sides(hm, 3, 2, (2, 2), 0) == (-1, 0)
    assert seat_sides(hm, 3, 2, (2, 2), 1) == (0, 0)  # 9 mm over the bottom: no face
    hm[3:5, 4] = 30  # a neighbour on +y
    assert seat_sides(hm, 3, 2, (2, 2), 0) == (-1, 1)
    hm[3:5, 1] = 30  # and on -y: a tight slot, the minimum side wins
    assert seat_sides(hm, 3, 2, (2, 2), 0) == (-1, -1)


def test_full_faces_are_walls_or_neighbours_along_the_whole_footprint():
    hm = np.zeros((8, 6), dtype=np.int32)
    assert full_faces(hm, 0, 0, (2, 2), 0, (-1, -1)) == (True, True)  # two walls
    assert full_faces(hm, 3, 2, (2, 2), 0, (0, 0)) == (False, False)  # nothing to push on
    hm[2, 2] = 30  # a neighbour beside one of the two cells of the -x strip: part of the face
    assert seat_sides(hm, 3, 2, (2, 2), 0)[0] == -1
    assert full_faces(hm, 3, 2, (2, 2), 0, (-1, 0)) == (False, False)
    hm[2, 3] = 30  # now beside both
    assert full_faces(hm, 3, 2, (2, 2), 0, (-1, 0)) == (True, False)
    assert full_faces(hm, 3, 2, (2, 2), 21, (-1, 0)) == (False, False)  # 9 mm over the bottom


# -- grasp errors -----------------------------------------------------------------------------


def test_grasp_errors_shift_the_executed_pose_by_the_error_reversed():
    noise = ExecutionNoise(xy_sigma_mm=2.0, yaw_sigma_deg=1.0, release_mm=5.0)
    plain = perturb_drop(noise, np.random.default_rng(7))
    shifted = perturb_drop(noise, np.random.default_rng(7), (1.5, -2.0, 0.4))
    assert shifted.offset_mm == pytest.approx((plain.offset_mm[0] - 1.5, plain.offset_mm[1] + 2.0))
    assert shifted.yaw_deg == pytest.approx(plain.yaw_deg - 0.4)
    # Without arm noise the grasp error alone moves the drop.
    alone = perturb_drop(SEAT_ONLY, np.random.default_rng(0), (1.0, 0.0, 0.5))
    assert not alone.is_exact and alone.offset_mm == (-1.0, 0.0) and alone.yaw_deg == -0.5


# -- episodes on a scripted scene ---------------------------------------------------------------


def _case(n: int = 2, size: tuple[int, int, int] = (100, 100, 100)) -> Case:
    return Case(
        episode_id="skill",
        container=Container((400, 100, 300)),
        objects=tuple(Box(f"b{i}", size) for i in range(n)),
        buffer_size=1,
        seed=0,
    )


def _perceiver(grasp=(0.0, 0.0, 0.0), hide=False, raise_mm=0):
    """A perceiver that sees the true heightmap (or an empty one with ``hide``), ``raise_mm``
    higher, and reports ``grasp`` as every shown object's pose-estimate error."""

    def perceive(scene: Scene, rng: np.random.Generator) -> Perception:
        seen = np.zeros_like(scene.heightmap) if hide else scene.heightmap + raise_mm
        sizes = tuple(tuple(int(v) for v in scene.sizes_mm[i]) for i in scene.shown)
        return Perception(seen.astype(np.int32), sizes, grasp_errors=(grasp,) * len(sizes))

    return perceive


def _gap(distance_mm: float, sizes_mm: float) -> float:
    """Gap (mm) between two boxes' true faces from their centres' distance and mean size (0:
    touching; their collision boxes, 0.5 mm inset per side, are then 1 mm apart)."""
    return distance_mm - sizes_mm


def _row_x(perceiver, execution=SEAT_ONLY) -> tuple[Episode, np.ndarray]:
    """Two 100 mm boxes into a row from the -x wall; settled x centres (mm)."""
    episode = Episode("mujoco", perceiver=perceiver, execution=execution)
    episode.reset(_case(), 0)
    for x in (0, 4):  # cells of 25 mm
        episode.step(Action(0, 0, x, 0))
    return episode, episode.backend.poses()[0][:, 0]


def test_a_perceived_neighbour_is_pushed_toward_and_the_box_ends_flush():
    # The robot's estimate is 3 mm off toward -x, so each box lands 3 mm toward +x.
    episode, x = _row_x(_perceiver(grasp=(-3.0, 0.0, 0.0)))
    assert [s.executed.offset_mm for s in episode.steps] == [(3.0, 0.0)] * 2
    assert [s.executed.seat_sides for s in episode.steps] == [(-1, -1), (-1, -1)]
    # Flush: the true faces touch (the skill backs off the collision insets), not 3 mm apart.
    assert x[0] == pytest.approx(50.0, abs=0.3)
    assert _gap(x[1] - x[0], 100) == pytest.approx(0.0, abs=0.3)


def test_a_neighbour_missing_from_the_heightmap_is_not_pushed_toward():
    # Same scene, but the heightmap the robot sees does not show the first box: the second
    # box's -x side reads as open floor, so it is not pushed there, whatever the sim holds.
    episode, x = _row_x(_perceiver(grasp=(-3.0, 0.0, 0.0), hide=True))
    assert episode.steps[1].executed.seat_sides == (0, -1)
    assert x[0] == pytest.approx(50.0, abs=0.3)  # the -x wall is known from the container
    assert _gap(x[1] - x[0], 100) == pytest.approx(3.0, abs=0.3)  # the error stays


def test_exact_observation_seats_on_the_exact_heightmap():
    # No perceiver: arm noise only, seat sides from the exact heightmap (the neighbour shows).
    arm = ExecutionNoise(xy_sigma_mm=2.0, comply_mm=10.0, seat_mm=5.0)
    episode, x = _row_x(None, arm)
    assert episode.steps[1].executed.seat_sides == (-1, -1)
    assert _gap(x[1] - x[0], 100) == pytest.approx(0.0, abs=0.3)


def test_the_release_height_follows_the_perceived_heightmap():
    episode = Episode("mujoco", perceiver=_perceiver(raise_mm=30))
    episode.reset(_case(), 0)
    first = episode.step(Action(0, 0, 0, 0))
    assert first.drop_mm == (0, 0, 30)  # the floor seen 30 mm high: released from there
    second = episode.step(Action(0, 0, 0, 0))  # onto the first box, seen 30 mm too high
    assert second.drop_mm == (0, 0, 130)
    # Both land where the physics puts them: on the floor, then on the first box.
    np.testing.assert_allclose(episode.backend.poses()[0][:, 2], [50.0, 150.0], atol=1.0)
    lower = Episode("mujoco", perceiver=_perceiver(raise_mm=-40))
    lower.reset(_case(), 0)
    lower.step(Action(0, 0, 0, 0))
    # Seen 40 mm too low, the second box's descent stops on the first (exact execution:
    # MujocoBackend._lift_clear).
    assert lower.step(Action(0, 0, 0, 0)).drop_mm == (0, 0, 60)
    assert lower.backend.poses()[0][1, 2] == pytest.approx(150.0, abs=1.0)


# -- the guarded push on the backend ------------------------------------------------------------


def _command(
    centre,
    size,
    sides=(0, 0),
    seen_top=0.0,
    bottom=0.0,
    release=0.0,
    comply=10.0,
    seat=5.0,
    full=(True, True),
):
    """The command of a box of perceived ``size`` (rotation 0) centred at ``centre``."""
    return PlaceCommand(
        centre_mm=centre,
        footprint_mm=(float(size[0]), float(size[1])),
        bottom_mm=bottom,
        height_mm=float(size[2]),
        release_mm=release,
        seen_top_mm=seen_top,
        comply_mm=comply,
        seat_mm=seat,
        seat_sides=sides,
        full_faces=full,
    )


def _yaw(quat) -> float:
    return float(np.degrees(2 * np.arctan2(quat[3], quat[0])))


def _pushed(
    sides,
    yaw_deg=0.0,
    neighbour=(100, 100, 100),
    size=(100, 100, 100),
    seat=5.0,
    offset=(3, 0),
    full=(True, True),
):
    """Box 1 dropped ``offset`` mm (x, y) (and ``yaw_deg``) off its plan flush against box 0 on -x,
    seated toward ``sides``: gap (mm, ``_gap``) between their x faces, z centre (mm), yaw
    (deg)."""
    backend = MujocoBackend()
    backend.reset(Container((600, 400, 400)), [Box("n", neighbour), Box("b", size)])
    backend.place(0, 0, (0, 0, 0))
    centre = (neighbour[0] + size[0] / 2, size[1] / 2)
    command = _command(centre, size, sides, neighbour[2], seat=seat, full=full)
    backend.execute(1, 0, command, offset, yaw_deg)
    positions, quats = backend.poses()
    gap = _gap(positions[1, 0] - positions[0, 0], (neighbour[0] + size[0]) / 2)
    return gap, positions[1, 2], _yaw(quats[1])


def test_the_guarded_push_stops_on_contact_and_only_where_told():
    assert _pushed((-1, 0))[0] == pytest.approx(0.0, abs=0.3)
    # Not told: the sim's neighbour is not looked for.
    assert _pushed((0, 0))[0] == pytest.approx(3.0, abs=0.3)
    # Told +x, but nothing within 5 mm past the plan: back to where it started.
    assert _pushed((1, 0))[0] == pytest.approx(3.0, abs=0.3)


def test_a_heavy_box_pushed_against_a_light_one_is_not_lifted_onto_it():
    # 0.25 kg neighbour, 12 kg box: the light neighbour yields before the force threshold,
    # so the push presses a few mm in; its reach counts from the command (the robot does not
    # know its 3 mm error), so it needs 8 mm to get there and press.
    gap, z, _ = _pushed((-1, 0), size=(300, 400, 400), seat=8.0)
    assert z == pytest.approx(200.0, abs=1.0)
    assert gap == pytest.approx(0.0, abs=0.5)


def test_a_turned_box_pushed_against_a_face_is_turned_flush_by_the_contact():
    # Against the 300 mm face of a neighbour as long as the box: the corner touches first and
    # the contact's torque turns the box flush (no squaring to the planned yaw by fiat).
    gap, _, yaw = _pushed((-1, 0), yaw_deg=2.0, neighbour=(100, 300, 100), size=(100, 300, 100))
    assert abs(yaw) < 0.3
    assert gap == pytest.approx(0.0, abs=0.3)
    # Not pushed, and 6 mm off the neighbour and 10 mm off the -y wall so its corners (5.2 mm
    # and 1.7 mm out at 2 degrees) touch nothing on the way down: it keeps its error. (Closer,
    # the descent meets the neighbour's corner or the wall, and that contact turns it:
    # physics, not fiat.)
    _, _, kept = _pushed(
        (0, 0), yaw_deg=2.0, neighbour=(100, 300, 100), size=(100, 300, 100), offset=(6, 10)
    )
    assert kept == pytest.approx(2.0, abs=0.01)


@pytest.mark.parametrize(
    ("yaw_deg", "offset", "seat"),
    [(7.0, (20, 10), 25.0), (-7.0, (20, 10), 25.0), (9.0, (22, 12), 28.0)],
)
def test_a_box_turned_past_five_degrees_is_still_turned_flush_against_a_whole_face(
    yaw_deg, offset, seat
):
    # The stereo preset's arm (3 deg) leaves about one box in ten more than 5 deg
    # off square; the wrist yields up to WRIST_YAW_YIELD_DEG (10), so seating against a face
    # along the whole footprint still squares it. Lowered clear of the neighbour (its corner
    # 18-23 mm out), then pushed onto its face from 25-28 mm away (with a 5 deg yield the push
    # stopped on the corner and the box kept its whole error).
    gap, _, yaw = _pushed(
        (-1, 0), yaw_deg=yaw_deg, neighbour=(100, 300, 100), size=(100, 300, 100),
        offset=offset, seat=seat,
    )  # fmt: skip
    assert abs(yaw) < 0.3
    assert gap == pytest.approx(0.0, abs=0.3)


def test_only_a_face_along_the_whole_footprint_turns_the_box_in_seating():
    # Lowered clear of the neighbour (as above), then pushed onto its face: read as a whole
    # face, the contact turns the box flush; read as partial (a neighbour under part of a face
    # turns the box about the neighbour's end, not flush), it is seated without a turn.
    shape = {"yaw_deg": 2.0, "neighbour": (100, 300, 100), "size": (100, 300, 100)}
    _, _, full = _pushed((-1, 0), offset=(6, 10), seat=8.0, **shape)
    _, _, partial = _pushed((-1, 0), offset=(6, 10), seat=8.0, full=(False, True), **shape)
    assert abs(full) < 0.3
    assert partial == pytest.approx(2.0, abs=0.01)


# -- no hidden truth, a physical descent, counted recoveries ----------------------------------


def _two_sizes_episode(true_size):
    """One box of ``true_size`` on an empty floor, seen as 100 x 100 x 100 with a fixed grasp
    error, under arm noise: the step of its placement."""
    case = Case(
        episode_id="sizes",
        container=Container((400, 400, 300)),
        objects=(Box("b", true_size),),
        buffer_size=1,
        seed=0,
    )

    def perceive(scene: Scene, rng: np.random.Generator) -> Perception:
        sizes = tuple((100, 100, 100) for _ in scene.shown)
        return Perception(scene.heightmap, sizes, grasp_errors=((1.0, -1.0, 0.5),) * len(sizes))

    episode = Episode("mujoco", perceiver=perceive, execution=ExecutionNoise(2.0, 1.0, 5.0, 10.0))
    episode.reset(case, 0)
    return episode.step(Action(0, 0, 4, 4))


def test_the_command_reads_the_perceived_size_never_the_true_one():
    # Two true sizes, one perceived size and one noise draw: one command, one executed drop.
    small, large = _two_sizes_episode((100, 100, 100)), _two_sizes_episode((104, 96, 108))
    assert small.command == large.command and small.executed == large.executed
    assert small.drop_mm == large.drop_mm == (100, 100, 0)
    # Centre from the perceived footprint, top lowered to bottom + perceived height + release.
    assert small.command.centre_mm == (150.0, 150.0)
    assert (small.command.bottom_mm, small.command.height_mm) == (0.0, 100.0)
    assert small.command.release_mm == 5.0


def test_a_noisy_drop_touching_nothing_keeps_its_error_yaw_and_offset():
    # Nothing squares the yaw by fiat or moves the box to the plan: in the open, a drop 3 mm
    # and 2 degrees off lands 3 mm and 2 degrees off, and the skill reports nothing done.
    backend = MujocoBackend()
    backend.reset(
        Container((600, 400, 400)), [Box("n", (100, 100, 100)), Box("b", (100, 100, 100))]
    )
    backend.place(0, 0, (0, 0, 0))
    command = _command((300.0, 200.0), (100, 100, 100), release=5.0)
    _, report = backend.execute(1, 0, command, (3.0, -2.0), 2.0)
    positions, quats = backend.poses()
    assert positions[1, :2] == pytest.approx((303.0, 198.0), abs=0.05)
    assert _yaw(quats[1]) == pytest.approx(2.0, abs=0.01)
    assert report.counts() == {}


def test_a_drop_on_a_neighbours_edge_slides_off_it_instead_of_landing_on_top():
    # Commanded flush against the neighbour, the box lands 4 mm into it (an error the robot
    # does not know): the descent meets the neighbour's top edge, reads the pressure at its
    # own -x edge and slides off; the box ends on the floor beside it.
    backend = MujocoBackend()
    backend.reset(
        Container((600, 400, 400)), [Box("n", (100, 100, 100)), Box("b", (100, 100, 100))]
    )
    backend.place(0, 0, (0, 0, 0))
    command = _command((150.0, 50.0), (100, 100, 100), seen_top=100.0, release=5.0)
    _, report = backend.execute(1, 0, command, (-4.0, 10.0), 0.5)
    positions, quats = backend.poses()
    assert report.descended and report.slid_off_edge and not report.stopped_high
    assert positions[1, 2] == pytest.approx(50.0, abs=0.5)  # on the floor
    # Beside the neighbour: its collision box clear (the simulator's 0.5 mm insets per side).
    assert positions[1, 0] - positions[0, 0] >= 100.0 - 1.1
    # Its 0.5 degree error is kept unless the neighbour's face turned it flush on the way down.
    assert _yaw(quats[1]) == pytest.approx(0.5, abs=0.01) or report.turned


def test_a_support_under_the_whole_box_stops_the_descent_high():
    # The heightmap saw the floor where a box stands (a missed neighbour): the descent is
    # carried by it with the pressure under the middle, stops, and the box is released on it.
    backend = MujocoBackend()
    backend.reset(
        Container((600, 400, 400)), [Box("n", (300, 300, 100)), Box("b", (100, 100, 100))]
    )
    backend.place(0, 0, (0, 0, 0))
    command = _command((150.0, 150.0), (100, 100, 100), seen_top=0.0, comply=5.0)
    _, report = backend.execute(1, 0, command, (0.0, 0.0), 0.0)
    assert report.descended and report.stopped_high
    assert backend.poses()[0][1, 2] == pytest.approx(150.0, abs=1.0)


def test_a_box_the_noise_puts_into_a_wall_is_slid_out_by_the_walls_force():
    backend = MujocoBackend()
    backend.reset(Container((300, 300, 300)), [Box("b", (100, 100, 100))])
    command = _command((50.0, 50.0), (100, 100, 100), release=5.0)
    _, report = backend.execute(0, 0, command, (-3.0, 0.0), 0.0)
    assert report.slid and not report.stopped_high
    positions = backend.poses()[0]
    assert positions[0, 0] == pytest.approx(50.0, abs=0.6)  # out of the wall, touching it
    assert positions[0, 2] == pytest.approx(50.0, abs=0.5)


def test_the_skill_counts_go_into_step_records_and_episode_metrics():
    from layered_cases import make_layered_case

    from packlab.policies import make_policy
    from packlab.sim.episode import run_episode

    case = make_layered_case(1, pieces=5)
    noisy = ExecutionNoise(xy_sigma_mm=5.0, yaw_sigma_deg=3.0, release_mm=10.0, comply_mm=20.0)
    rec = run_episode(case, make_policy("dblf"), 0, execution=noisy).to_record()
    steps = [s["skill"] for s in rec["steps"] if "skill" in s]
    assert steps and all(isinstance(v, int) and v > 0 for s in steps for v in s.values())
    totals: dict[str, int] = {}
    for s in steps:
        for kind, count in s.items():
            totals[kind] = totals.get(kind, 0) + count
    assert rec["metrics"]["skill"] == dict(sorted(totals.items()))
    exact = run_episode(case, make_policy("dblf"), 0).to_record()
    assert "skill" not in exact["metrics"] and all("skill" not in s for s in exact["steps"])


def test_run_details_show_the_skill_counts_and_old_records_still_read():
    from layered_cases import make_layered_case

    from packlab.bench.summary import summarize
    from packlab.bench.table import render_markdown
    from packlab.core.records import RUN_FORMAT, episode_from_json
    from packlab.policies import make_policy
    from packlab.sim.episode import run_episode

    case = make_layered_case(1, pieces=5)
    noisy = ExecutionNoise(xy_sigma_mm=5.0, yaw_sigma_deg=3.0, release_mm=10.0, comply_mm=20.0)

    def record(execution, policy):
        rec = run_episode(case, make_policy("dblf"), 0, execution=execution).to_record()
        head = {"format": RUN_FORMAT, "status": "ok", "difficulty": "easy", "n_objects": 5}
        return episode_from_json({**rec, **head, "policy": policy, "timing": {}}, "test")

    noisy_rec, old_rec = record(noisy, "dblf"), record(None, "old")
    summary = summarize([noisy_rec, old_rec])
    placements = sum(s.skill is not msgspec.UNSET for s in noisy_rec.steps)
    assert placements > 0
    assert summary.counts["dblf"].skill_per_episode == {
        "placements": float(placements),
        **{k: float(v) for k, v in noisy_rec.metrics.skill.items()},
    }
    assert summary.counts["old"].skill_per_episode is msgspec.UNSET  # no key: no counts
    table = render_markdown(summary)
    assert "### Place skill" in table and "| placements |" in table


# -- a placement that stopped high is tried again -----------------------------------------------


def _slot(size=(100, 100, 100), true_size=None):
    """A box of perceived ``size`` commanded into a slot with no slack between two 100 mm
    neighbours (x 100-200 mm), its bottom on the floor: the backend and the command."""
    backend = MujocoBackend()
    backend.reset(
        Container((300, 400, 300)),
        [Box("l", (100, 400, 100)), Box("r", (100, 400, 100)), Box("b", true_size or size)],
    )
    backend.place(0, 0, (0, 0, 0))
    backend.place(1, 0, (200, 0, 0))
    command = _command((150.0, 200.0), size, seen_top=100.0, release=10.0, comply=30.0, seat=0.0)
    return backend, command


def _draws(*draws):
    """The arm's noise draws a retry gets, in order (offset mm, yaw deg), counted as used."""
    used = []

    def redraw():
        used.append(draws[len(used)])
        return used[-1]

    return redraw, used


def test_a_placement_stopped_high_on_an_edge_is_retried_with_a_fresh_draw():
    # Turned 12 degrees the box cannot enter the slot (its turns in the descent stop at 10):
    # the descent stops on the neighbours' edges, 100 mm above its target.
    backend, command = _slot()
    _, report = backend.execute(2, 0, command, (1.0, 0.0), 12.0)
    assert report.stopped_high and not report.retried  # no redraw handed: released there
    assert backend.poses()[0][2, 2] == pytest.approx(150.0, abs=1.0)
    # The same first draw with retries: the second draw turns it 1 degree only, and it lands.
    backend, command = _slot()
    redraw, used = _draws(((0.5, 0.0), 1.0), ((9.0, 9.0), 9.0))
    _, report = backend.execute(2, 0, command, (1.0, 0.0), 12.0, redraw)
    assert report.retried == 1 and not report.stopped_high and len(used) == 1
    assert backend.poses()[0][2, 2] == pytest.approx(50.0, abs=0.5)  # in the slot
    # Every draw turned too far: two retries, then released where the last one stopped.
    backend, command = _slot()
    redraw, used = _draws(((1.0, 0.0), 12.0), ((1.0, 0.0), -12.0), ((0.0, 0.0), 0.0))
    _, report = backend.execute(2, 0, command, (1.0, 0.0), 12.0, redraw)
    assert report.retried == 2 and report.stopped_high and len(used) == 2
    assert backend.poses()[0][2, 2] == pytest.approx(150.0, abs=1.0)


def test_a_box_still_stuck_high_after_its_retries_is_taken_out_and_set_aside():
    # As above, every draw turned too far; with set_aside_stuck the robot takes the box back
    # out instead of letting it go on the neighbours' edges: parked, not placed, no seating.
    backend, command = _slot()
    command = replace(command, set_aside_stuck=True)
    redraw, _ = _draws(((1.0, 0.0), 12.0), ((1.0, 0.0), -12.0))
    transition, report = backend.execute(2, 0, command, (1.0, 0.0), 12.0, redraw)
    assert report.retried == 2 and report.set_aside and not report.stopped_high
    assert np.isnan(backend.poses()[0][2]).all()  # no longer placed
    assert transition.heightmap.max() == 100  # the neighbours only: nothing on their tops
    # A try that lands is released as before, the setting notwithstanding.
    backend, command = _slot()
    redraw, _ = _draws(((0.5, 0.0), 1.0))
    _, report = backend.execute(
        2, 0, replace(command, set_aside_stuck=True), (1.0, 0.0), 12.0, redraw
    )
    assert report.retried == 1 and not report.set_aside
    assert backend.poses()[0][2, 2] == pytest.approx(50.0, abs=0.5)


def test_both_robot_presets_set_stuck_boxes_aside_and_the_command_carries_it():
    for preset in ("structured-light", "stereo"):
        noise = execution_noise(preset)
        assert noise.set_aside_stuck
        drop = perturb_drop(noise, np.random.default_rng(0))
        command = place_command((100, 100, 100), 0, (0, 0, 0), np.zeros((4, 4)), drop)
        assert command.set_aside_stuck
    assert not execution_noise("none").set_aside_stuck


def test_the_retry_decision_reads_the_gripper_height_against_the_command_only():
    # A box truly 150 mm tall shown as 100 mm, onto the empty floor of the slot with no error:
    # the gripper holds its top, so its descent stops on the floor 40 mm above the command's
    # release pose. The robot cannot tell that from a ledge: it retries (truth would say the
    # box rests on the floor) and each try ends the same.
    backend, command = _slot(true_size=(100, 100, 150))
    redraw, used = _draws(((0.0, 0.0), 0.0), ((0.0, 0.0), 0.0))
    _, report = backend.execute(2, 0, command, (0.0, 0.0), 0.0, redraw)
    assert report.retried == 2 and len(used) == 2
    assert backend.poses()[0][2, 2] == pytest.approx(75.0, abs=0.5)
    # Shown at its true height, the same descent ends at the release pose: no retry.
    backend, command = _slot(size=(100, 100, 150))
    redraw, used = _draws(((0.0, 0.0), 0.0))
    _, report = backend.execute(2, 0, command, (0.0, 0.0), 0.0, redraw)
    assert not report.retried and not used


def _slot_episode(seed: int, execution: ExecutionNoise | None):
    """Two neighbours then a box into the slot between them, the grasp estimate 12 degrees off
    (it stays over retries), under ``execution``: the record."""
    case = Case(
        episode_id="slot",
        container=Container((300, 400, 300)),
        objects=(Box("l", (100, 400, 100)), Box("r", (100, 400, 100)), Box("b", (100, 100, 100))),
        buffer_size=1,
        seed=0,
    )
    episode = Episode("mujoco", perceiver=_perceiver(grasp=(0.0, 0.0, -12.0)), execution=execution)
    episode.reset(case, seed)
    for x, y in ((0, 0), (8, 0), (4, 6)):  # cells of 25 mm
        episode.step(Action(0, 0, x, y))
    return episode


def test_retries_are_deterministic_and_exact_execution_never_retries():
    stereo = ExecutionNoise(
        xy_sigma_mm=5.0, yaw_sigma_deg=3.0, release_mm=10.0, comply_mm=30.0, seat_mm=25.0
    )
    first, again = _slot_episode(2, stereo), _slot_episode(2, stereo)
    assert [s.skill for s in first.steps] == [s.skill for s in again.steps]
    # The grasp's 12 degrees stay over retries: at this seed two tries stop high and the
    # third draw's arm yaw brings it within the descent's turns, into the slot.
    assert first.steps[-1].skill.retried == 2 and not first.steps[-1].skill.stopped_high
    assert first.backend.poses()[0][2, 2] == pytest.approx(50.0, abs=0.5)
    np.testing.assert_array_equal(first.backend.poses()[0], again.backend.poses()[0])
    exact = _slot_episode(2, None)
    assert all(s.skill is None for s in exact.steps)
