"""Every heuristic's vectorised scores and choice agree with the slow reference loops."""

from __future__ import annotations

import heuristics_reference as ref
import numpy as np
from heuristics_strategies import EQUAL_VOLUME_SHAPES, LEVEL_HEIGHTS_MM, packing_states
from hypothesis import given, settings
from hypothesis import strategies as st

from packlab.core.feasibility import search_candidates
from packlab.policies.heuristics import dblf, ffp, hm, mta, sdf
from packlab.policies.heuristics.select import FLOAT_DECIMALS, TIE_BREAKS, choose

EXAMPLES = settings(max_examples=100, deadline=None)
#: Both tie-break rules, drawn per example so each test covers both.
TIES = st.sampled_from(TIE_BREAKS)


def states(max_cells: int = 6):
    """Random states, and states whose boxes share one volume (ties between objects)."""
    return st.one_of(
        packing_states(max_cells=max_cells),
        packing_states(
            max_cells=max_cells, max_items=4, shapes=EQUAL_VOLUME_SHAPES, heights=LEVEL_HEIGHTS_MM
        ),
    )


def _both(state):
    heights, shown, rim = state
    return heights, rim, search_candidates(heights, shown, rim), ref.candidates(heights, shown, rim)


@EXAMPLES
@given(states(), TIES)
def test_dblf_and_ffp_agree(state, tie) -> None:
    _, _, c, slow = _both(state)
    assert choose(c, dblf.score(c), tie) == ref.choose(slow, lambda k: (k.z, k.x, k.y), tie)
    assert choose(c, ffp.score(c), tie) == ref.choose(slow, lambda k: (), tie)


@EXAMPLES
@given(states(), TIES)
def test_hm_agrees(state, tie) -> None:
    heights, _, c, slow = _both(state)
    increase = [ref.hm_increase_mm3(heights, k) for k in slow]
    assert hm.heightmap_increase_mm3(c).tolist() == increase
    assert choose(c, hm.score(c), tie) == ref.choose(
        slow, lambda k: (ref.hm_increase_mm3(heights, k), k.z, k.x, k.y), tie
    )


@EXAMPLES
@given(states(), TIES)
def test_mta_agrees(state, tie) -> None:
    heights, rim, c, slow = _both(state)
    contact = [ref.contact_mm2(heights, rim, k) for k in slow]
    assert mta.contact_area_mm2(c).tolist() == contact
    by_index = {id(k): a for k, a in zip(slow, contact)}
    assert choose(c, mta.score(c), tie) == ref.choose(
        slow, lambda k: (-by_index[id(k)], k.z, k.x, k.y), tie
    )


@settings(max_examples=40, deadline=None)
@given(states(max_cells=5), TIES)
def test_sdf_agrees(state, tie) -> None:
    heights, rim, c, slow = _both(state)
    if not slow:
        assert len(c) == 0
        return
    v = 25
    layers = max(k.top for k in slow) // v + 2
    field = ref.brute_gap_field(heights, rim, v, layers, sdf.TRUNCATION_MM)
    gaps = np.array([ref.mean_surface_gap_mm(field, k, v) for k in slow])
    np.testing.assert_allclose(sdf.mean_surface_gap_mm(c), gaps, atol=1e-9)
    volumes = [int(np.prod(s)) for s in c.shown_sizes_mm]
    scores = [
        k.z + sdf.SDF_WEIGHT * g + sdf.SIZE_PENALTY_MM * (1 - volumes[k.obj] / max(volumes))
        for k, g in zip(slow, gaps)
    ]
    by_index = {id(k): round(s, FLOAT_DECIMALS) for k, s in zip(slow, scores)}
    assert choose(c, sdf.score(c), tie) == ref.choose(
        slow, lambda k: (by_index[id(k)], k.z, k.x, k.y), tie
    )
