"""The MuJoCo backend's shortcuts give what the long way gives, bit for bit.

The backend collides a held box alone while the place skill moves it (``_collide_with``),
sums the wrist's contact readings as arrays (``_side_load``, ``_wrench``), keeps the
heightmap's per-box regions and their maximum from settle to settle (``_rasterise``), reads
every box's pose in one gather (``poses``) and keeps per-episode index arrays; an episode
played on a backend that already played others is the episode a fresh backend plays. Each test
compares against the long way on messy piles (boxes dropped anywhere with noisy execution:
tilted, leaning and pressed into each other).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from packlab.core.types import Action
from packlab.datagen.generator import build_case
from packlab.policies import make_policy
from packlab.sim.episode import Episode, run_episode
from packlab.sim.heightmap import box_top_region, compose_regions
from packlab.sim.modes import episode_modes
from packlab.sim.physics.mujoco_backend import MujocoBackend

pytestmark = pytest.mark.physics

HONEST = episode_modes("perceived", "noisy", "structured-light", "depth")


def _messy_action(observation, rng: np.random.Generator) -> Action:
    """A shown box, turned or not, anywhere its footprint fits: piles that lean and topple."""
    k = int(rng.integers(len(observation.shown)))
    rotation = int(rng.integers(2))
    l, w, _ = observation.shown[k].size_cells
    fx, fy = (w, l) if rotation else (l, w)
    nx, ny = observation.heightmap.shape
    x, y = int(rng.integers(max(nx - fx, 0) + 1)), int(rng.integers(max(ny - fy, 0) + 1))
    return Action(k, rotation, x, y)


def _messy_episode(case, seed: int = 0) -> tuple[Episode, MujocoBackend]:
    backend = MujocoBackend()
    episode = Episode(backend, execution=HONEST.execution)
    episode.reset(case, seed)
    return episode, backend


def _messy_backend(case, steps: int, seed: int = 0) -> MujocoBackend:
    """A backend after ``steps`` messy placements of ``case`` (noisy execution)."""
    episode, backend = _messy_episode(case, seed)
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        episode.step(_messy_action(episode.observe(), rng))
    return backend


def _contacts_of(data: mujoco.MjData, geom: int) -> list[tuple]:
    contact = data.contact
    mine = (contact.geom1 == geom) | (contact.geom2 == geom)
    return [
        (
            int(contact.geom1[i]),
            int(contact.geom2[i]),
            contact.dist[i],
            tuple(contact.pos[i]),
            tuple(contact.frame[i]),
        )
        for i in np.flatnonzero(mine)
    ]


def _masks(backend: MujocoBackend) -> tuple[np.ndarray, ...]:
    model = backend._model
    return (
        model.geom_contype.copy(),
        model.geom_conaffinity.copy(),
        model.body_contype.copy(),
        model.body_conaffinity.copy(),
    )


def test_a_box_collided_alone_has_exactly_the_contacts_of_the_whole_scene():
    case = build_case(20_002, "hard")
    backend = _messy_backend(case, 14)
    model, data = backend._model, backend._data
    placed = np.flatnonzero(backend._placed)
    assert len(placed) >= 10
    unmasked = _masks(backend)
    rng = np.random.default_rng(3)
    compared = touching = 0
    for index in placed.tolist():
        geom = int(backend._geom_ids[index])
        pose = backend._qpos_slice(index)
        start = data.qpos[pose].copy()
        for _ in range(6):
            # Pushed into its neighbours: moves of up to 15 mm sideways and down, a small turn.
            data.qpos[pose.start : pose.start + 3] = start[:3] + rng.uniform(-0.015, 0.015, 3)
            depth = backend._penetration(geom)  # the held box collided alone
            alone = _contacts_of(data, geom)
            assert data.ncon == len(alone)  # nothing but its own contacts
            backend._whole_scene()
            assert all(np.array_equal(a, b) for a, b in zip(_masks(backend), unmasked))
            mujoco.mj_kinematics(model, data)
            mujoco.mj_collision(model, data)
            whole = _contacts_of(data, geom)
            assert alone == whole
            assert depth == (-min(c[2] for c in whole) if whole else 0.0)
            compared += 1
            touching += bool(whole)
        data.qpos[pose] = start
    backend._whole_scene()
    assert compared >= 60 and touching >= compared // 2


def test_placing_and_settling_leave_every_box_colliding_as_its_state_says():
    case = build_case(20_003, "medium")
    backend = _messy_backend(case, 8)
    model = backend._model
    active = (backend._placed & ~backend._frozen).astype(np.int32)
    assert backend._colliding_only is None
    assert np.array_equal(model.geom_contype[backend._geom_ids], active)
    assert np.array_equal(model.geom_conaffinity[backend._geom_ids], active)
    assert np.array_equal(model.body_contype[backend._body_ids], active)
    assert np.array_equal(model.body_conaffinity[backend._body_ids], active)


def test_kept_heightmap_regions_compose_to_the_heightmap_of_all_of_them():
    case = build_case(20_004, "hard")
    episode, backend = _messy_episode(case, 1)
    rng = np.random.default_rng(1)
    grid, cell = case.container.cells, case.container.cell_xy_mm
    while not episode.done:
        episode.step(_messy_action(episode.observe(), rng))
        heightmap = episode.heightmap
        regions = backend._regions
        assert sorted(regions) == np.flatnonzero(backend._placed).tolist()
        assert np.array_equal(heightmap, compose_regions(grid, regions.values()))
        # Every kept region is the one sampled at its kept pose, and that pose is within the
        # reuse tolerance of the box's pose now.
        positions, quats = backend.poses()
        for i, region in regions.items():
            pose = backend._sampled_pose[i]
            again = box_top_region(grid, cell, backend._sizes_mm[i], pose[:3], pose[3:])
            assert (region is None) == (again is None)
            if region is not None:
                assert region[:4] == again[:4]
                assert np.array_equal(region[4], again[4], equal_nan=True)
            assert np.abs(pose[:3] - positions[i]).max() <= 0.02
            assert np.abs(pose[3:] - quats[i]).max() <= 1e-5


def test_poses_are_each_placed_box_s_own_free_joint_pose():
    case = build_case(20_005, "medium")
    backend = _messy_backend(case, 6)
    positions, quats = backend.poses()
    for i, placed in enumerate(backend._placed):
        if not placed:
            assert np.isnan(positions[i]).all() and np.isnan(quats[i]).all()
            continue
        q = backend._data.qpos[backend._qpos_slice(i)]
        assert np.array_equal(positions[i], q[:3] / 1e-3)
        assert np.array_equal(quats[i], q[3:])


def _record(result) -> dict:
    record = result.to_record()
    record.pop("policy_time_s")
    for step in record["steps"]:
        for key in ("wall_time_s", "decision_s", "decision_cpu_s"):
            step.pop(key, None)
    record["metrics"].pop("wall_time_s")
    return record


@pytest.mark.parametrize("honest", [False, True], ids=["exact", "perceived-noisy"])
def test_episodes_in_a_row_on_one_backend_equal_fresh_ones(honest):
    modes = HONEST if honest else episode_modes()
    plays = [(build_case(20_006, "medium"), "random", 0), (build_case(20_007, "easy"), "dblf", 2)]

    def play(backend, case, policy, seed):
        result = run_episode(
            case,
            make_policy(policy),
            seed=seed,
            backend=backend,
            perceiver=modes.perceiver,
            execution=modes.execution,
        )
        steps = [(s.positions_mm.tobytes(), s.quaternions.tobytes()) for s in result.steps]
        return _record(result), steps

    shared = MujocoBackend()
    in_a_row = [play(shared, *p) for p in plays + plays]
    fresh = [play(MujocoBackend(), *p) for p in plays]
    assert in_a_row == fresh + fresh


def test_contact_sums_are_the_one_at_a_time_sums():
    from packlab.sim.physics.mujoco_backend import _added_in_order

    rng = np.random.default_rng(0)
    values = [0.0, -0.0, 1e-300, -1e-300, 1.0, -1.0, 3.3e10, -2.5e-5, 0.1, 0.7]
    for _ in range(3000):
        n = int(rng.integers(0, 12))
        rows = rng.choice(values, size=(n, 3)) * rng.choice([1.0, rng.normal()], size=(n, 3))
        loop = np.zeros(3)
        for row in rows:
            loop += row
        summed = _added_in_order(rows)
        assert np.array_equal(summed, loop)
        assert np.array_equal(np.signbit(summed), np.signbit(loop))


def _side_load_one_at_a_time(backend: MujocoBackend, geom: int, address: int):
    """The wrist's side reading summed contact by contact (the reference for ``_side_load``)."""
    model, data = backend._model, backend._data
    centre = data.qpos[address : address + 2].copy()
    force, torque, pressure, total = np.zeros(2), 0.0, np.zeros(2), 0.0
    if backend._penetration(geom) <= 0.0:
        return force, torque, centre
    backend._whole_scene()
    mujoco.mj_forward(model, data)
    wrench, contacts = np.zeros(6), data.contact
    mine = (contacts.geom1 == geom) | (contacts.geom2 == geom)
    for i in np.flatnonzero(mine & (np.abs(contacts.frame[:, 2]) <= 0.5)).tolist():
        mujoco.mj_contactForce(model, data, i, wrench)
        on_box = wrench[0] * contacts.frame[i, :2] * (1.0 if contacts.geom2[i] == geom else -1.0)
        force += on_box
        r = contacts.pos[i, :2] - centre
        torque += float(r[0] * on_box[1] - r[1] * on_box[0])
        pressure += abs(wrench[0]) * contacts.pos[i, :2]
        total += abs(wrench[0])
    return force, torque, pressure / total if total > 0 else centre


def _wrench_one_at_a_time(backend: MujocoBackend, geom: int, address: int, axis_xy):
    """The wrist's full reading summed contact by contact (the reference for ``_wrench``)."""
    model, data = backend._model, backend._data
    centre = data.qpos[address : address + 2].copy()
    force, torque = np.zeros(3), 0.0
    pressure, total = np.zeros((2, 2)), np.zeros(2)
    if backend._penetration(geom) <= 0.0:
        return force, torque, centre, centre.copy()
    backend._whole_scene()
    mujoco.mj_forward(model, data)
    wrench, contacts = np.zeros(6), data.contact
    mine = (contacts.geom1 == geom) | (contacts.geom2 == geom)
    for i in np.flatnonzero(mine).tolist():
        mujoco.mj_contactForce(model, data, i, wrench)
        on_box = wrench[0] * contacts.frame[i, :3] * (1.0 if contacts.geom2[i] == geom else -1.0)
        force += on_box
        r = contacts.pos[i, :2] - axis_xy
        torque += float(r[0] * on_box[1] - r[1] * on_box[0])
        kind = int(abs(contacts.frame[i, 2]) > 0.5)
        pressure[kind] += abs(wrench[0]) * contacts.pos[i, :2]
        total[kind] += abs(wrench[0])
    side, support = (pressure[k] / total[k] if total[k] > 0 else centre for k in (0, 1))
    return force, torque, side, support


def _same(a, b) -> bool:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return np.array_equal(a, b) and np.array_equal(np.signbit(a), np.signbit(b))


def test_wrist_readings_are_the_contact_by_contact_sums():
    case = build_case(20_008, "hard")
    backend = _messy_backend(case, 12, seed=2)
    data = backend._data
    rng = np.random.default_rng(5)
    read = pressed = 0
    for index in np.flatnonzero(backend._placed).tolist():
        geom, pose = int(backend._geom_ids[index]), backend._qpos_slice(index)
        start = data.qpos[pose].copy()
        for _ in range(4):
            data.qpos[pose.start : pose.start + 3] = start[:3] + rng.uniform(-0.01, 0.01, 3)
            moved = data.qpos.copy()
            axis = start[:2] + rng.uniform(-0.05, 0.05, 2)
            expected = _side_load_one_at_a_time(backend, geom, pose.start)
            data.qpos[:] = moved
            got = backend._side_load(geom, pose.start)
            assert all(_same(e, g) for e, g in zip(expected, got))
            data.qpos[:] = moved
            expected = _wrench_one_at_a_time(backend, geom, pose.start, axis)
            data.qpos[:] = moved
            got = backend._wrench(geom, pose.start, axis)
            assert all(_same(e, g) for e, g in zip(expected, got))
            read += 1
            pressed += bool(np.any(expected[0]))
        data.qpos[pose] = start
    backend._whole_scene()
    assert read >= 40 and pressed >= read // 3
