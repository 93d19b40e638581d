"""The rim rule and tie-breaking shared by every heuristic."""

from __future__ import annotations

import heuristics_reference as ref
import numpy as np
from heuristics_strategies import EQUAL_VOLUME_SHAPES, LEVEL_HEIGHTS_MM, packing_states
from hypothesis import given, settings
from hypothesis import strategies as st

from packlab.core.feasibility import search_candidates
from packlab.core.types import Action
from packlab.policies.heuristics import SCORERS
from packlab.policies.heuristics.select import (
    TIE_BREAKS,
    choose,
    quantise,
    ranked,
    rim_pool,
    to_action,
)


def test_in_rim_candidates_win_even_with_worse_keys() -> None:
    hm = np.zeros((2, 1), dtype=np.int32)
    # Object 0 is 150 mm tall: above the 100 mm rim everywhere.
    c = search_candidates(hm, [ref.shown_item(0, 1, 1, 150), ref.shown_item(1, 1, 1, 50)], 100)
    prefers_object_0 = c.obj  # lower is better: object 0 would win on this key alone
    assert to_action(c, choose(c, (prefers_object_0,))) == Action(1, 0, 0, 0)


def test_without_in_rim_candidates_the_lowest_top_pool_is_used() -> None:
    hm = np.array([[0], [10]], dtype=np.int32)
    c = search_candidates(hm, [ref.shown_item(0, 1, 1, 150), ref.shown_item(1, 1, 1, 120)], 100)
    assert not c.fits_in_rim.any()
    pool = rim_pool(c)
    assert set(zip(c.obj[pool], c.x[pool])) == {(1, 0)}  # top 120, both rotations
    # A key preferring x = 1 cannot leave the pool; the two rotations tie -> rotation 0.
    assert to_action(c, choose(c, (-c.x,))) == Action(1, 0, 0, 0)


def test_remaining_ties_go_to_scan_order() -> None:
    hm = np.zeros((2, 2), dtype=np.int32)
    c = search_candidates(hm, [ref.shown_item(0, 1, 1, 20), ref.shown_item(1, 1, 1, 20)], 100)
    assert choose(c, ()) == 0
    assert to_action(c, choose(c, (np.zeros(len(c)),))) == Action(0, 0, 0, 0)
    assert to_action(c, choose(c, (-c.obj, -c.y))) == Action(1, 0, 0, 1)


def test_no_candidates_chooses_nothing() -> None:
    c = search_candidates(np.zeros((1, 1), dtype=np.int32), [ref.shown_item(0, 2, 2, 10)], 100)
    assert choose(c, ()) is None


def test_quantise_makes_float_near_ties_exact() -> None:
    a = np.array([0.1 + 0.2, 0.3])
    assert a[0] != a[1] and quantise(a)[0] == quantise(a)[1]


@settings(max_examples=150, deadline=None)
@given(
    st.one_of(
        packing_states(),
        packing_states(max_items=4, shapes=EQUAL_VOLUME_SHAPES, heights=LEVEL_HEIGHTS_MM),
    ),
    st.sampled_from(TIE_BREAKS),
    st.sampled_from(["dblf", "hm", "mta", "ffp"]),
)
def test_ranked_orders_the_pool_as_choose_would_pick_it_again_and_again(state, tie, name):
    # ranked(...)[0] is choose's pick, and each next one is choose's pick with those before it
    # removed (the key of a removed candidate set to +inf keeps it out of the minimum).
    heights, shown, rim = state
    c = search_candidates(heights, shown, rim)
    keys = tuple(np.asarray(k, dtype=np.float64) for k in SCORERS[name](c))
    order = ranked(c, keys, tie_break=tie)
    pool = rim_pool(c)
    assert sorted(order.tolist()) == pool.tolist()
    if pool.size == 0:
        assert choose(c, keys, tie) is None
        return
    gone = np.zeros(len(c), dtype=bool)
    for i in order[:4]:
        first = (np.where(gone, np.inf, 0.0),)  # a leading key that rules out the removed ones
        assert choose(c, first + keys, tie) == int(i)
        gone[i] = True
