"""The online protocol: next k boxes in arrival order, place the first, stop at the
first box that fits nowhere; space utilization counts only what was placed."""

import numpy as np
import pytest
from layered_cases import make_layered_case

from packlab.core.errors import ConfigError
from packlab.core.feasibility import fits_somewhere, observation_candidates
from packlab.core.packing_protocol import BUFFER, PackingProtocol, saved_protocol
from packlab.core.types import Action, Box, Case, Container, ShownItem, Unparsable
from packlab.metrics import space_utilization
from packlab.policies import make_policy
from packlab.sim.episode import INVALID_REASONS, Episode, run_episode

BPP1 = PackingProtocol("online", 1)


def _stuck_case() -> Case:
    """A 4 x 4-cell, 100 mm tall container: two 4 x 2 x 60 boxes fill the floor, the third
    (4 x 4 x 60) then fits nowhere (60 + 60 > 100), and a fourth small box would fit."""
    container = Container((100, 100, 100))
    boxes = (
        Box(0, (100, 50, 60)),
        Box(1, (100, 50, 60)),
        Box(2, (100, 100, 60)),
        Box(3, (25, 25, 20)),
    )
    return Case("stuck", container, buffer_size=4, objects=boxes, seed=3)


def test_online_k1_places_in_arrival_order():
    case = make_layered_case(2, cells=(20, 16), layer_heights_mm=(100, 100), buffer_size=5)
    result = run_episode(case, make_policy("dblf"), seed=4, backend="geometric", protocol=BPP1)
    arrival = [b.internal_id for b in case.objects]
    processed = [s.internal_id for s in result.steps]
    assert processed == arrival[: len(processed)]
    assert all(len(s.shown) == 1 and s.shown[0].internal_id == s.internal_id for s in result.steps)
    assert all(s.valid for s in result.steps)


def test_online_lookahead_shows_the_next_k_in_order_and_no_shuffle():
    case = make_layered_case(2, cells=(20, 16), layer_heights_mm=(100, 100), buffer_size=2)
    arrival = [b.internal_id for b in case.objects]
    for seed in (0, 7):  # the run seed shuffles the buffer protocol's view, not this one
        ep = Episode("geometric", protocol=PackingProtocol("online", 3))
        obs = ep.reset(case, seed)
        assert [s.internal_id for s in obs.shown] == arrival[:3]
        assert obs.must_place_first and obs.placeable(0) and not obs.placeable(1)
        ep.step(Action(0, 0, 0, 0))
        assert [s.internal_id for s in ep.observe().shown] == arrival[1:4]


def test_online_action_on_another_index_is_invalid_and_sets_the_first_aside():
    case = _stuck_case()
    ep = Episode("geometric", protocol=PackingProtocol("online", 3))
    ep.reset(case, 0)
    step = ep.step(Action(object_id=1, rotation=0, x=0, y=0))
    assert not step.valid and step.reason == "not_first" and "not_first" in INVALID_REASONS
    assert step.internal_id == 0  # the box that had to be placed, set aside
    assert ep.metrics().n_set_aside == 1
    # An unusable answer also processes the first box (no seeded draw among the shown).
    step = ep.step(Unparsable("?", "test"))
    assert not step.valid and step.internal_id == 1


def test_online_episode_ends_at_the_first_box_that_fits_nowhere():
    case = _stuck_case()
    ep = Episode("geometric", protocol=BPP1)
    ep.reset(case, 0)
    ep.step(Action(0, 0, 0, 0))
    assert not ep.done
    ep.step(Action(0, 0, 0, 2))
    assert ep.done and ep.stopped_at == 2  # box 3 would fit, but the episode is over
    metrics = ep.metrics()
    outcome = ep.online_outcome(metrics)
    assert outcome is not None
    assert outcome.stopped_at == 2 and outcome.unprocessed == 2
    placed = 2 * 100 * 50 * 60
    assert metrics.inside_volume_mm3 == placed
    assert outcome.space_utilization == pytest.approx(placed / 100**3)
    assert outcome.space_utilization == space_utilization(placed, case.container)


def test_online_record_carries_utilization_and_where_it_stopped():
    result = run_episode(
        _stuck_case(), make_policy("dblf"), seed=0, backend="geometric", protocol=BPP1
    )
    metrics = result.to_record()["metrics"]
    assert len(result.steps) == 2
    assert metrics["stopped_at"] == 2 and metrics["unprocessed"] == 2
    assert metrics["space_utilization"] == pytest.approx(0.6)


def test_buffer_protocol_record_has_no_online_keys():
    result = run_episode(_stuck_case(), make_policy("dblf"), seed=0, backend="geometric")
    metrics = result.to_record()["metrics"]
    assert len(result.steps) == 4  # every box processed, as always
    assert not {"space_utilization", "stopped_at", "unprocessed"} & set(metrics)


def test_a_first_box_that_fits_nowhere_ends_the_episode_before_any_step():
    case = Case("big", Container((100, 100, 50)), 1, (Box(0, (100, 100, 60)),), seed=0)
    result = run_episode(case, make_policy("dblf"), backend="geometric", protocol=BPP1)
    assert result.steps == () and result.online is not None
    assert result.online.stopped_at == 0 and result.online.space_utilization == 0.0


def test_fits_somewhere_is_the_in_rim_mask_in_either_yaw():
    hm = np.zeros((4, 2), dtype=np.int32)
    long_box = ShownItem(0, 0, (50, 100, 40), (2, 4, 20))  # fits only turned (4 x 2)
    assert fits_somewhere(hm, long_box, 100)
    assert not fits_somewhere(hm + 70, long_box, 100)  # 70 + 40 over the rim
    assert not fits_somewhere(hm, ShownItem(0, 0, (125, 25, 10), (5, 1, 5)), 100)


def test_online_observation_restricts_the_shared_candidate_search():
    case = _stuck_case()
    obs = Episode("geometric", protocol=PackingProtocol("online", 3)).reset(case, 0)
    cands = observation_candidates(obs)
    assert len(cands) > 0 and set(cands.obj.tolist()) == {0}
    assert cands.buffer_size == 3  # the lookahead stays in the set's buffer


@pytest.mark.parametrize("name", ["dblf", "plan-fast", "random"])
def test_policies_place_only_the_first_box_online(name):
    case = make_layered_case(3, cells=(20, 16), layer_heights_mm=(100, 80), buffer_size=3)
    protocol = PackingProtocol("online", 3)
    result = run_episode(case, make_policy(name), seed=1, backend="geometric", protocol=protocol)
    assert result.steps and all(s.valid for s in result.steps)
    assert all(s.action.object_id == 0 for s in result.steps)


def test_protocol_values_and_saved_reading():
    assert saved_protocol({}) == BUFFER == saved_protocol({"protocol": "buffer"})
    online = saved_protocol({"protocol": "online", "lookahead": 3})
    assert online == PackingProtocol("online", 3) and online.label == "online (BPP-3)"
    assert online.identity() == {"protocol": "online", "lookahead": 3}
    assert BUFFER.identity() == {"protocol": "buffer"}
    with pytest.raises(ConfigError, match="lookahead"):
        PackingProtocol("buffer", 3)
    with pytest.raises(ConfigError, match="lookahead"):
        PackingProtocol("online", 0)
    with pytest.raises(ConfigError, match="protocol"):
        saved_protocol({"protocol": "bpp"})


OFFLINE = PackingProtocol("offline")


def test_offline_shows_every_unprocessed_box_and_lets_any_be_placed():
    case = make_layered_case(2, cells=(20, 16), layer_heights_mm=(100, 100), buffer_size=2)
    ep = Episode("geometric", protocol=OFFLINE)
    obs = ep.reset(case, 0)
    n = len(case.objects)
    assert len(obs.shown) == n == obs.remaining and not obs.must_place_first
    last = len(obs.shown) - 1
    ep.step(Action(last, 0, 0, 0))  # any shown box may be placed
    assert len(ep.observe().shown) == n - 1
    result = run_episode(case, make_policy("dblf"), backend="geometric", protocol=OFFLINE)
    assert len(result.steps) == n  # every box is processed, as in the buffer protocol


def test_offline_round_trips_and_takes_no_lookahead():
    assert saved_protocol(OFFLINE.identity()) == OFFLINE
    assert OFFLINE.label == "offline (every box shown)"
    with pytest.raises(ConfigError, match="only used with --protocol online"):
        PackingProtocol("offline", 3)
