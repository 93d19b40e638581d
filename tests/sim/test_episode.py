"""The closed loop on the geometric backend: buffer, shuffle, invalid actions, determinism."""

from dataclasses import replace

import numpy as np
import pytest
from layered_cases import make_layered_case

from packlab.core.types import Action, Box, Case, Container, Unparsable
from packlab.policies import make_policy
from packlab.sim.episode import INVALID_REASONS, Episode, run_episode


def test_buffer_shows_first_k_unprocessed_in_shuffled_order(layered_case):
    ep = Episode("geometric")
    obs = ep.reset(layered_case, seed=5)
    ids = [b.internal_id for b in layered_case.objects]
    assert sorted(s.internal_id for s in obs.shown) == sorted(ids[:3])
    assert [s.shown_index for s in obs.shown] == [0, 1, 2]
    # Processing the object shown at index 0 refills the window from the sequence.
    first = obs.shown[0].internal_id
    ep.step(Unparsable("", "test"))  # sets aside a random shown object
    obs = ep.observe()
    assert len(obs.shown) == 3 and obs.remaining == len(ids) - 1
    assert first in ids


def test_shuffle_depends_on_case_seed_and_run_seed():
    case = make_layered_case(
        2, cells=(20, 16), layer_heights_mm=(100, 100, 100), buffer_size=5, pieces=5
    )
    orders = set()
    for run_seed in range(6):
        obs = Episode("geometric").reset(case, run_seed)
        orders.add(tuple(s.internal_id for s in obs.shown))
    assert len(orders) > 1
    a = Episode("geometric").reset(case, 3)
    b = Episode("geometric").reset(case, 3)
    assert a.shown == b.shown


@pytest.mark.parametrize("sides", ["longer-first", "catalogue"])
@pytest.mark.parametrize("seed", range(5))
def test_oracle_is_exactly_perfect_on_geometric(seed, sides):
    """Under either side names: the plan's rotations refer to the catalogue's (l, w), and the
    oracle turns those of boxes shown (w, l) (``longer-first`` where l < w)."""
    case = make_layered_case(
        seed, cells=(24, 20), layer_heights_mm=(160, 120, 80), buffer_size=3, pieces=5
    )
    assert any(b.size_mm[0] < b.size_mm[1] for b in case.objects)  # the names differ here
    result = run_episode(case, make_policy("oracle"), seed=seed, backend="geometric", sides=sides)
    assert all(s.valid for s in result.steps)
    assert result.metrics.overall == 1.0
    assert result.metrics.success_ratio == 1.0 and result.metrics.compactness == 1.0


def _two_box_case() -> Case:
    container = Container((100, 100, 100))
    boxes = (Box(0, (50, 100, 50)), Box(1, (50, 100, 50)), Box(2, (100, 50, 50)))
    return Case("tiny", container, buffer_size=2, objects=boxes, seed=1)


@pytest.mark.parametrize(
    "action, reason",
    [
        (Action(object_id=7, rotation=0, x=0, y=0), "bad_object_id"),
        (Action(object_id=-1, rotation=0, x=0, y=0), "bad_object_id"),
        (Action(object_id=0, rotation=2, x=0, y=0), "bad_rotation"),
        (Action(object_id=0, rotation=0, x=3, y=0), "out_of_bounds"),
        (Action(object_id=0, rotation=0, x=0, y=-1), "out_of_bounds"),
        (Unparsable("I think the answer is left", "no JSON object"), "unparsable"),
    ],
)
def test_invalid_action_is_recorded_and_the_episode_goes_on(action, reason):
    assert reason in INVALID_REASONS
    ep = Episode("geometric")
    ep.reset(_two_box_case(), 0)
    result = ep.step(action)
    assert not result.valid and result.reason == reason and result.drop_mm is None
    aside = result.internal_id
    while not ep.done:  # the rest is placed validly by the first-fit rule
        obs = ep.observe()
        item = obs.shown[0]
        for x in range(obs.heightmap.shape[0]):
            if x + item.size_cells[0] <= obs.heightmap.shape[0]:
                ep.step(Action(item.shown_index, 0, x, 0))
                break
    metrics = ep.metrics()
    assert metrics.invalid_by_reason == {reason: 1}
    assert metrics.n_set_aside == 1
    assert ep.final_poses()[aside] is None
    assert metrics.n_inside == 2
    assert metrics.success_ratio == pytest.approx(
        1 - _two_box_case().box_by_id(aside).volume_mm3 / ep.case.total_volume_mm3
    )


def test_out_of_bounds_sets_aside_the_chosen_object():
    ep = Episode("geometric")
    obs = ep.reset(_two_box_case(), 0)
    chosen = obs.shown[1].internal_id
    assert ep.step(Action(1, 0, 4, 0)).internal_id == chosen


def test_drop_height_is_eq2_and_above_rim_executes():
    container = Container((50, 50, 60))
    case = Case("stack", container, 1, (Box(0, (50, 50, 40)), Box(1, (25, 50, 40))))
    ep = Episode("geometric")
    ep.reset(case, 0)
    ep.step(Action(0, 0, 0, 0))
    # Box 1 is shown longer side first, (50, 25): rotation 1 lays its 25 mm side along x.
    second = ep.step(Action(0, 1, 1, 0))
    assert second.valid and second.drop_mm == (25, 0, 40)  # on top of the first box, above the rim
    metrics = ep.metrics()
    # Box 1's centre is at z = 60 = the rim: inside (closed interior). H = 80 mm.
    assert metrics.n_inside == 2 and metrics.max_height_mm == 80


def test_same_seed_same_records_geometric():
    case = make_layered_case(4, cells=(20, 16), layer_heights_mm=(100, 100), pieces=5)
    a = run_episode(case, make_policy("random"), seed=11, backend="geometric")
    b = run_episode(case, make_policy("random"), seed=11, backend="geometric")
    strip = lambda r: [
        {k: v for k, v in s.to_record().items() if k != "wall_time_s"} for s in r.steps
    ]
    assert strip(a) == strip(b) and a.metrics.overall == b.metrics.overall


def test_step_after_done_and_before_reset_are_errors():
    with pytest.raises(RuntimeError):
        Episode("geometric").observe()
    ep = Episode("geometric")
    case = replace(_two_box_case(), objects=_two_box_case().objects[:1])
    ep.reset(case, 0)
    ep.step(Action(0, 0, 0, 0))
    with pytest.raises(RuntimeError, match="finished"):
        ep.step(Action(0, 0, 0, 0))


def test_history_holds_heightmap_before_each_action(layered_case):
    ep = Episode("geometric")
    obs = ep.reset(layered_case, 0)
    policy = make_policy("oracle")
    policy.reset(layered_case, 0)
    ep.step(policy.act(obs))
    obs2 = ep.observe()
    assert len(obs2.history) == 1
    assert np.array_equal(obs2.history[0].heightmap, obs.heightmap)
    assert obs2.history[0].shown == obs.shown


def test_step_result_carries_settled_poses_of_all_boxes(layered_case):
    ep = Episode("geometric")
    obs = ep.reset(layered_case, 0)
    policy = make_policy("oracle")
    policy.reset(layered_case, 0)
    first = ep.step(policy.act(obs))
    n = len(layered_case.objects)
    assert first.positions_mm.shape == (n, 3) and first.quaternions.shape == (n, 4)
    placed = [i for i, b in enumerate(layered_case.objects) if b.internal_id == first.internal_id]
    assert not np.isnan(first.positions_mm[placed]).any()
    assert np.isnan(first.positions_mm).any(axis=1).sum() == n - 1  # the others are not placed yet
