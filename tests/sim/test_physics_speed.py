"""The MuJoCo backend's speed shortcuts give what the long way gives, bit for bit.

The place skill's held box (``_HeldBox``) collides once per pose and solves once per state,
answers a side load with nothing across a side without a solve (``_position_stage`` in its
place), and the skill's flush turn does not read a torque it does not need
(``skip_side_load``); the normal forces are one gather on elliptic cones; the settle's rest test
asks one moving box first (``_surely_moving``). Each is compared with the long way: every
reading collided and solved afresh, the force read contact by contact, every box tested.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from test_physics_shortcuts import (
    _messy_backend,
    _same,
    _side_load_one_at_a_time,
    _wrench_one_at_a_time,
)

from packlab.datagen.generator import build_case
from packlab.sim.physics.mujoco_backend import (
    MujocoBackend,
    _HeldBox,
    _net_squared_speeds,
    _squared_speeds,
    _surely_moving,
)

pytestmark = pytest.mark.physics


def _resting_pile(case_id: int, steps: int, seed: int = 1) -> MujocoBackend:
    """A messy pile left to settle until boxes sleep."""
    backend = _messy_backend(build_case(case_id, "hard"), steps, seed=seed)
    backend._whole_scene()
    for _ in range(600):
        mujoco.mj_step(backend._model, backend._data)
    return backend


def _long_way(backend: MujocoBackend, geom: int, address: int, op: str, arg):
    """One reading the long way: collided (and solved) afresh, forces contact by contact."""
    if op == "penetration":
        return backend._penetration(geom)
    if op in ("side_load", "skip_side_load"):
        reading = _side_load_one_at_a_time(backend, geom, address)
        return None if op == "skip_side_load" else reading
    if op == "wrench":
        return _wrench_one_at_a_time(backend, geom, address, arg)
    if op == "touching":
        backend._penetration(geom)
        return backend._touching(geom)
    if op == "touching_back":
        return backend._touching_back(geom, arg)
    assert op == "deepest_across"
    return backend._deepest_across(geom, arg)


def _short_way(held: _HeldBox, op: str, arg):
    if op in ("penetration", "side_load", "touching"):
        return getattr(held, op)()
    if op == "skip_side_load":
        return held.skip_side_load()
    return getattr(held, op)(arg)


def _equal(a, b) -> bool:
    if isinstance(a, tuple):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b))
    if isinstance(a, (set, type(None))):
        return a == b
    return _same(a, b)


@pytest.mark.parametrize(("case_id", "seed"), [(20_012, 0), (20_010, 1)])
def test_held_box_readings_and_sleep_are_the_long_ways(case_id, seed):
    """Two identical piles: one read through ``_HeldBox`` (its memos and shortcuts), one the
    long way, the same moves and readings on both; every reading and the sleep state after
    each must agree, and the state after the last must step the same."""
    short, long_ = _resting_pile(case_id, 12, seed), _resting_pile(case_id, 12, seed)
    assert np.array_equal(short._data.qpos, long_._data.qpos)
    placed = np.flatnonzero(short._placed)
    trees = short._model.body_treeid[short._body_ids[placed]]
    assert (short._data.tree_asleep[trees] >= 0).sum() >= 3  # boxes to wake
    rng = np.random.default_rng(case_id)
    ops = ["penetration", "side_load", "skip_side_load", "wrench", "touching", "touching_back"]
    ops += ["deepest_across"]
    readings = woken = 0
    for index in placed[::2].tolist():
        geom = int(short._geom_ids[index])
        pose = short._qpos_slice(index)
        held = _HeldBox(short, index)
        poses = [short._data.qpos[pose].copy()]
        for _ in range(40):
            if rng.random() < 0.3:  # back to a pose met before
                target = poses[int(rng.integers(len(poses)))]
            else:
                target = poses[0].copy()
                target[:3] += rng.uniform(-0.012, 0.012, 3)
                poses.append(target)
            for backend in (short, long_):
                backend._data.qpos[pose] = target
            for _ in range(int(rng.integers(1, 4))):
                op = ops[int(rng.integers(len(ops)))]
                arg = int(rng.integers(2)) if "across" in op or "back" in op else None
                if op == "wrench":
                    arg = target[:2] + rng.uniform(-0.05, 0.05, 2)
                asleep = long_._data.tree_asleep.copy()
                expected = _long_way(long_, geom, pose.start, op, arg)
                got = _short_way(held, op, arg)
                assert _equal(got, expected), (op, got, expected)
                assert np.array_equal(short._data.tree_asleep, long_._data.tree_asleep), op
                woken += not np.array_equal(asleep, long_._data.tree_asleep)
                readings += 1
        for backend in (short, long_):
            backend._data.qpos[pose] = poses[0]
    assert readings >= 200 and woken >= 1
    short._whole_scene()
    long_._whole_scene()
    for _ in range(50):
        mujoco.mj_step(short._model, short._data)
        mujoco.mj_step(long_._model, long_._data)
    assert np.array_equal(short._data.qpos, long_._data.qpos)
    assert np.array_equal(short._data.qvel, long_._data.qvel)


def test_normal_forces_are_mj_contact_force_s():
    backend = _resting_pile(20_013, 12)
    model, data = backend._model, backend._data
    assert backend._elliptic
    mujoco.mj_forward(model, data)
    contacts = np.arange(data.ncon)
    assert len(contacts) >= 10
    expected, wrench = np.empty(len(contacts)), np.zeros(6)
    for k, i in enumerate(contacts.tolist()):
        mujoco.mj_contactForce(model, data, i, wrench)
        expected[k] = wrench[0]
    got = backend._normal_forces(contacts[::-1])
    assert np.array_equal(got, expected[::-1])
    assert np.array_equal(backend._normal_forces(contacts[:0]), np.zeros(0))
    backend._elliptic = False  # the loop, as on pyramidal cones
    assert np.array_equal(backend._normal_forces(contacts), expected)


def _full_test(vel: np.ndarray, now: np.ndarray, before: np.ndarray, span: float, limits):
    """The settle's rest test of every box (``MujocoBackend._settle``'s full check)."""
    dof_idx = np.arange(vel.size).reshape(-1, 6)
    speed2 = _squared_speeds(vel.ravel(), dof_idx)
    moving = (speed2 >= limits).any(axis=1)
    net2 = _net_squared_speeds(before, now, span)
    return moving, moving & (net2 >= limits).any(axis=1)


def test_the_quick_rest_test_says_moving_only_where_the_full_test_does():
    rng = np.random.default_rng(0)
    limits = np.array([0.01, 0.05]) ** 2
    span = 0.02
    quick_said = 0
    for _ in range(400):
        n = 8
        # Speeds spread over the thresholds, some of them exactly at one.
        vel = rng.normal(size=(n, 6)) * rng.choice([0.001, 0.005, 0.03], size=(n, 1))
        vel[0] = [0.01, 0.0, 0.0, 0.0, 0.0, 0.0]
        vel[1] = [0.0, 0.0, 0.0, 0.0, 0.05, 0.0]
        before = np.zeros((n, 7))
        before[:, :3] = rng.uniform(-1, 1, (n, 3))
        before[:, 3] = 1.0
        now = before.copy()
        step = rng.normal(size=(n, 3)) * rng.choice([1e-5, 2e-4, 1e-3], size=(n, 1))
        step[2] = [0.01 * span, 0.0, 0.0]  # net speed exactly at the threshold
        now[:, :3] += step
        by_velocity, moving = _full_test(vel, now, before, span, limits)
        for i in range(n):
            lim = (float(limits[0]), float(limits[1]))
            early = _surely_moving(vel[i], now[i, :3], None, span, lim)
            late = _surely_moving(vel[i], now[i, :3], before[i, :3], span, lim)
            assert not early or by_velocity[i]
            assert not late or moving[i]
            quick_said += late
            if vel[i, :3] @ vel[i, :3] > 4 * limits[0] and step[i] @ step[i] > 4e-4 * span**2:
                assert late  # clearly moving: the quick test sees it
    assert quick_said > 100
    assert not _surely_moving(vel[0], now[0, :3], None, span, (float(limits[0]), 1.0))
