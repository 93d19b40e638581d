"""Issue 26: a place skill that acts only on what the robot knows.

The release height comes from the observed heightmap, the executed pose carries the grasped
box's pose-estimate error, and the seat pushes toward the sides the observed heightmap shows
flush (``packlab.sim.execution.seat_sides``), by guarded moves that stop on contact force
(``MujocoBackend._seat``), never by probing the true scene.
"""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core.types import Action, Box, Case, Container
from packlab.sim.episode import Episode
from packlab.sim.execution import ExecutionNoise, perturb_drop, seat_sides
from packlab.sim.physics.mujoco_backend import MujocoBackend
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


# -- grasp errors -----------------------------------------------------------------------------


def test_grasp_errors_shift_the_executed_pose_by_the_error_reversed():
    noise = ExecutionNoise(xy_sigma_mm=2.0, yaw_sigma_deg=1.0, release_mm=5.0)
    args = (noise, (100, 100, 0), (200, 100), (1000, 1000))
    plain = perturb_drop(*args, np.random.default_rng(7))
    shifted = perturb_drop(*args, np.random.default_rng(7), (1.5, -2.0, 0.4))
    assert shifted.offset_mm == pytest.approx((plain.offset_mm[0] - 1.5, plain.offset_mm[1] + 2.0))
    assert shifted.yaw_deg == pytest.approx(plain.yaw_deg - 0.4)
    # Without arm noise the grasp error alone moves the drop.
    alone = perturb_drop(SEAT_ONLY, *args[1:], np.random.default_rng(0), (1.0, 0.0, 0.5))
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
    # Seen 40 mm too low, the second box's descent stops on the first (_lift_clear).
    assert lower.step(Action(0, 0, 0, 0)).drop_mm == (0, 0, 60)
    assert lower.backend.poses()[0][1, 2] == pytest.approx(150.0, abs=1.0)


# -- the guarded push on the backend ------------------------------------------------------------


def _pushed(sides, yaw_deg=0.0, neighbour=(100, 100, 100), size=(100, 100, 100)):
    """Box 1 dropped 3 mm +x (and ``yaw_deg``) of its plan flush against box 0 on -x, seated
    toward ``sides``: gap (mm, ``_gap``) between their x faces, z centre (mm), yaw (deg)."""
    backend = MujocoBackend()
    backend.reset(Container((600, 400, 400)), [Box("n", neighbour), Box("b", size)])
    backend.place(0, 0, (0, 0, 0))
    backend.place(
        1,
        0,
        (neighbour[0], 0, 0),
        offset_mm=(3.0, 0.0),
        yaw_deg=yaw_deg,
        comply_mm=10.0,
        seat_mm=5.0,
        seat_sides=sides,
    )
    positions, quats = backend.poses()
    yaw = np.degrees(2 * np.arctan2(quats[1, 3], quats[1, 0]))
    gap = _gap(positions[1, 0] - positions[0, 0], (neighbour[0] + size[0]) / 2)
    return gap, positions[1, 2], float(yaw)


def test_the_guarded_push_stops_on_contact_and_only_where_told():
    assert _pushed((-1, 0))[0] == pytest.approx(0.0, abs=0.3)
    # Not told: the sim's neighbour is not looked for.
    assert _pushed((0, 0))[0] == pytest.approx(3.0, abs=0.3)
    # Told +x, but nothing within 5 mm past the plan: back to where it started.
    assert _pushed((1, 0))[0] == pytest.approx(3.0, abs=0.3)


def test_a_heavy_box_pushed_against_a_light_one_is_not_lifted_onto_it():
    # 0.25 kg neighbour, 12 kg box: the light neighbour yields before the force threshold.
    gap, z, _ = _pushed((-1, 0), size=(300, 400, 400))
    assert z == pytest.approx(200.0, abs=1.0)
    assert gap == pytest.approx(0.0, abs=0.5)


def test_a_turned_box_pushed_against_a_face_is_turned_flush_by_the_contact():
    # Against the 300 mm face of a neighbour as long as the box: the corner touches first and
    # the contact's torque turns the box flush (no squaring to the planned yaw by fiat).
    gap, _, yaw = _pushed((-1, 0), yaw_deg=2.0, neighbour=(100, 300, 100), size=(100, 300, 100))
    assert abs(yaw) < 0.3
    assert gap == pytest.approx(0.0, abs=0.3)
    _, _, kept = _pushed((0, 0), yaw_deg=2.0, neighbour=(100, 300, 100), size=(100, 300, 100))
    assert kept == pytest.approx(2.0, abs=0.3)
