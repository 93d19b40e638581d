"""The MuJoCo backend: perfect layouts stay put, flush boxes are not lifted, overhangs topple."""

import numpy as np
import pytest
from layered_cases import make_layered_case

from packlab.core.errors import ConfigError
from packlab.core.types import Action, Box, Case, Container
from packlab.metrics import plan_drift_mm
from packlab.policies import make_policy
from packlab.sim.episode import Episode, run_episode
from packlab.sim.heightmap import quat_to_matrix
from packlab.sim.physics.mujoco_backend import PhysicsConfig

pytestmark = pytest.mark.physics


@pytest.mark.parametrize("seed", range(4))
def test_oracle_replay_of_perfect_layouts_stays_put(seed):
    case = make_layered_case(
        seed, cells=(32, 24), layer_heights_mm=(200, 150, 100), buffer_size=3, pieces=6
    )
    result = run_episode(case, make_policy("oracle"), seed=seed, backend="mujoco")
    assert all(s.valid for s in result.steps)
    assert result.metrics.unsettled_steps == 0 and result.metrics.at_rest
    assert result.metrics.overall >= 0.99
    assert plan_drift_mm(case, result.poses) <= 5.0
    # Flush neighbours touch without pushing each other up: every box stays level.
    for pose in result.poses.values():
        assert quat_to_matrix(pose.quaternion)[2, 2] > 0.9999


@pytest.mark.parametrize("sides", ["longer-first", "catalogue"])
def test_oracle_is_perfect_under_either_side_names_on_mujoco(sides):
    case = make_layered_case(1, cells=(24, 20), layer_heights_mm=(150, 100), pieces=5)
    assert any(b.size_mm[0] < b.size_mm[1] for b in case.objects)  # the names differ here
    result = run_episode(case, make_policy("oracle"), seed=1, backend="mujoco", sides=sides)
    assert all(s.valid for s in result.steps)
    assert result.metrics.overall >= 0.99
    assert plan_drift_mm(case, result.poses) <= 5.0


def test_same_case_and_seed_give_identical_mujoco_records():
    case = make_layered_case(7, cells=(24, 20), layer_heights_mm=(150, 100), pieces=5)
    a = run_episode(case, make_policy("random"), seed=3, backend="mujoco")
    b = run_episode(case, make_policy("random"), seed=3, backend="mujoco")
    strip = lambda r: [
        {k: v for k, v in s.to_record().items() if k != "wall_time_s"} for s in r.steps
    ]
    assert strip(a) == strip(b)
    assert a.poses == b.poses
    assert a.metrics.overall == b.metrics.overall


def test_overhanging_box_topples_and_the_heightmap_follows_the_tilt():
    # The container is wider than the slab so the wall does not hold it up as it tips.
    container = Container((150, 100, 200))
    case = Case("overhang", container, 1, (Box(0, (25, 100, 40)), Box(1, (100, 100, 20))), seed=0)
    ep = Episode("mujoco", sides="catalogue")  # the scripted rotations are the catalogue's
    ep.reset(case, 0)
    ep.step(Action(0, 0, 0, 0))
    result = ep.step(Action(0, 0, 0, 0))  # drops at z = 40 with only its first quarter supported
    assert result.valid
    pose = ep.final_poses()[1]
    tilt = np.degrees(np.arccos(quat_to_matrix(pose.quaternion)[2, 2]))
    assert tilt > 10
    hm = ep.heightmap
    # The slab now slopes down away from the support: high near x = 0, low at the far wall.
    assert hm[0, 1] > hm[3, 1] and hm[3, 1] < 40
    assert (np.diff(hm[:4, 1]) <= 0).all()
    assert ep.metrics().n_inside == 2


def test_physics_config_is_validated():
    with pytest.raises(ConfigError, match="timestep_s"):
        PhysicsConfig(timestep_s=0)
    with pytest.raises(ConfigError, match="unknown"):
        Episode("bullet").reset(make_layered_case(0), 0)
