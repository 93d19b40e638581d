"""The settle region: while a placement settles, boxes away from the motion are frozen and the
rest test runs every few steps; stacks end where simulating every box step by step puts them."""

import numpy as np
import pytest
from layered_cases import make_layered_case
from settle_motion import movement_mm

from packlab.core.errors import ConfigError
from packlab.core.types import Box, Container
from packlab.policies import make_policy
from packlab.sim.episode import run_episode
from packlab.sim.physics.mujoco_backend import MujocoBackend, PhysicsConfig

pytestmark = pytest.mark.physics

#: The settle before the settle region: every box simulated, the rest test after every step.
STEP_BY_STEP = PhysicsConfig()  # the default: every box simulated, tested after every step
REGION = PhysicsConfig(freeze=True, rest_check_steps=4)


def _spy(backend: MujocoBackend, monkeypatch) -> dict[str, set[int]]:
    """Record which boxes ``backend`` freezes and thaws (thaws at the settle's end apart)."""
    seen: dict[str, set[int]] = {"frozen": set(), "thawed": set()}
    freeze, thaw = backend._freeze, backend._thaw

    def spy_freeze(indices):
        seen["frozen"].update(int(i) for i in indices)
        freeze(indices)

    def spy_thaw(indices):
        seen["thawed"].update(int(i) for i in indices)
        thaw(indices)

    monkeypatch.setattr(backend, "_freeze", spy_freeze)
    monkeypatch.setattr(backend, "_thaw", spy_thaw)
    return seen


def test_a_settle_freezes_the_boxes_away_from_the_drop_and_thaws_them_after(monkeypatch):
    backend = MujocoBackend(REGION)
    boxes = (Box(0, (100, 100, 50)), Box(1, (100, 100, 50)), Box(2, (100, 100, 50)))
    backend.reset(Container((500, 200, 300)), boxes)
    backend.place(1, 0, (400, 0, 0))
    backend.place(0, 0, (0, 0, 0))  # box 1 calms down meanwhile
    far = backend.poses()[0][1].copy()
    seen = _spy(backend, monkeypatch)
    step = backend.place(2, 0, (0, 0, 50))  # onto box 0, 300 mm from box 1
    assert step.settled
    assert seen["frozen"] == {1}  # box 0 carries the drop: simulated with it
    assert not backend._frozen.any()  # all thawed, colliding as themselves again
    model = backend._model
    assert (model.geom_contype[backend._geom_ids] == 1).all()
    assert (model.geom_contype[backend._frozen_geom_ids] == 0).all()
    assert (model.body_gravcomp[backend._body_ids] == 0).all()
    assert np.array_equal(backend.poses()[0][1], far)  # a frozen box does not move at all
    assert backend.poses()[0][2][2] == pytest.approx(75.0, abs=0.5)


def test_a_frozen_box_thaws_when_a_falling_box_comes_near_and_is_pushed_as_before(monkeypatch):
    # A slab dropped on a narrow post, three quarters overhanging, tips onto a low box 30 mm
    # beyond the post: 20 mm below the slab, too far to be simulated at first, hit as it tips.
    boxes = (Box(0, (25, 100, 40)), Box(1, (100, 100, 20)), Box(2, (60, 100, 20)))

    def play(physics: PhysicsConfig, seen=None) -> MujocoBackend:
        backend = MujocoBackend(physics)
        backend.reset(Container((300, 100, 200)), boxes)
        backend.place(0, 0, (0, 0, 0))
        backend.place(2, 0, (55, 0, 0))
        if seen is not None:
            seen.update(_spy(backend, monkeypatch))
        backend.place(1, 0, (0, 0, 40))
        backend.finish()
        return backend

    seen: dict[str, set[int]] = {}
    region, full = play(REGION, seen), play(STEP_BY_STEP)
    assert 2 in seen["frozen"] and 2 in seen["thawed"]
    slab, full_slab = region.poses()[0][1], full.poses()[0][1]
    assert slab[2] < 45  # it tipped (centre 50 mm up when level on the post)
    assert np.abs(slab - full_slab).max() < 1.0  # and came to rest where the full settle put it
    assert np.abs(region.poses()[0][2] - full.poses()[0][2]).max() < 1.0


@pytest.mark.parametrize("seed", range(2))
def test_a_stack_settles_as_in_the_step_by_step_settle_and_stays_at_rest(seed):
    case = make_layered_case(
        seed, cells=(32, 24), layer_heights_mm=(200, 150, 100), buffer_size=3, pieces=6
    )
    fast = run_episode(case, make_policy("oracle"), seed=0, backend="mujoco", physics=REGION)
    full = run_episode(case, make_policy("oracle"), seed=0, backend="mujoco", physics=STEP_BY_STEP)
    assert fast.metrics.overall == full.metrics.overall >= 0.99
    assert fast.metrics.at_rest and fast.metrics.unsettled_steps == 0
    # The same drops, each stopped at a check: a multiple of the check interval.
    assert all(s.settle_steps % REGION.rest_check_steps == 0 for s in fast.steps)
    for key, pose in full.poses.items():
        assert pose is not None and fast.poses[key] is not None
        assert np.abs(np.subtract(fast.poses[key].position_mm, pose.position_mm)).max() < 0.5


def test_a_settle_stops_at_rest_and_the_pile_stays_where_it_stopped():
    backend = MujocoBackend(REGION)
    boxes = tuple(Box(i, (100, 100, 50)) for i in range(4))
    backend.reset(Container((300, 200, 300)), boxes)
    for i, corner in enumerate([(0, 0, 0), (100, 0, 0), (200, 0, 0), (50, 100, 0)]):
        step = backend.place(i, 0, corner)
        # A drop onto the floor rests within a few checks: two still checks 4 steps apart.
        assert step.settled and step.settle_steps <= 20
    assert movement_mm(backend, 250) < 0.1


def test_checking_every_step_without_freezing_is_the_step_by_step_settle():
    boxes = (Box(0, (100, 100, 50)), Box(1, (100, 100, 50)))
    steps = {}
    for name, physics in (("fast", REGION), ("step", STEP_BY_STEP)):
        backend = MujocoBackend(physics)
        backend.reset(Container((200, 200, 300)), boxes)
        backend.place(0, 0, (0, 0, 0))
        steps[name] = backend.place(1, 0, (0, 0, 50)).settle_steps
    # 0.5 mm of fall, then five still steps; checked every 4 steps, two still checks.
    assert steps == {"step": 11, "fast": 12}


def test_random_piles_freeze_and_thaw_deterministically():
    # Random drops make collapsing piles: boxes freeze, fall asleep, thaw next to sleeping
    # neighbours; the engine stays consistent and the records repeat exactly.
    case = make_layered_case(3, cells=(24, 20), layer_heights_mm=(150, 100), pieces=6)
    a = run_episode(case, make_policy("random"), seed=1, backend="mujoco", physics=REGION)
    b = run_episode(case, make_policy("random"), seed=1, backend="mujoco", physics=REGION)
    strip = lambda r: [
        {k: v for k, v in s.to_record().items() if k != "wall_time_s"} for s in r.steps
    ]
    assert strip(a) == strip(b) and a.poses == b.poses


def test_settle_region_settings_are_validated():
    with pytest.raises(ConfigError, match="rest_check_steps"):
        PhysicsConfig(rest_check_steps=0)
    with pytest.raises(ConfigError, match="freeze_still_steps"):
        PhysicsConfig(freeze_still_steps=0)
    with pytest.raises(ConfigError, match="freeze_margin_mm"):
        PhysicsConfig(freeze_margin_mm=-1.0)
    with pytest.raises(ConfigError, match="freeze_speed_fraction"):
        PhysicsConfig(freeze_speed_fraction=0.0)
