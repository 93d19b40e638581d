"""The planner's support test and its fallback down the ranking."""

from __future__ import annotations

import numpy as np
import pytest
from layered_cases import make_layered_case

from packlab.core.errors import ConfigError
from packlab.core.feasibility import search_candidates
from packlab.core.types import ShownItem
from packlab.policies import make_policy
from packlab.policies.plan.search import _pick
from packlab.policies.plan.stability import centre_supported
from packlab.sim.episode import run_episode


def _pillar_map() -> np.ndarray:
    """8 x 4 cells: a 100 mm pillar over x = 0..1, floor elsewhere."""
    hm = np.zeros((8, 4), dtype=np.int32)
    hm[0:2, :] = 100
    return hm


def test_a_box_on_the_floor_is_always_supported():
    assert centre_supported(np.zeros((4, 4), dtype=np.int32), 0, 0, 4, 4, 0)


def test_centre_over_the_contact_cells_is_supported_and_beyond_them_is_not():
    hm = _pillar_map()
    # 4 cells long from x = 0: contact on x = 0..1, centre at x = 2 (the hull's edge): holds.
    assert centre_supported(hm, 0, 0, 4, 4, 100)
    # 6 cells long: the centre at x = 3 is past the pillar's edge: tips.
    assert not centre_supported(hm, 0, 0, 6, 4, 100)
    # Contact on two separate ridges spans the gap between them.
    hm[6:8, :] = 100
    assert centre_supported(hm, 0, 0, 8, 4, 100)


def test_the_fallback_takes_the_cheapest_supported_placement():
    hm = _pillar_map()
    shown = (ShownItem(0, 0, (150, 100, 40), (6, 4, 20)),)
    cands = search_candidates(hm, shown, container_height_mm=400, cell_mm=25)
    at = {(int(cands.x[i]), int(cands.rotation[i])): i for i in range(len(cands))}
    tipping, standing = at[(0, 0)], at[(2, 0)]  # z = 100 on the pillar's edge vs z = 0
    scored = [(1.0, tipping), (2.0, standing)]
    assert _pick(hm, cands, scored, check_support=False) == (1.0, tipping, False)
    assert _pick(hm, cands, scored, check_support=True) == (2.0, standing, True)
    # Nothing supported: the cheapest anyway, counted as a fallback.
    assert _pick(hm, cands, [(1.0, tipping)], check_support=True) == (1.0, tipping, True)


@pytest.mark.parametrize("seed", range(2))
def test_with_the_support_check_every_committed_box_stands(seed):
    case = make_layered_case(seed, cells=(8, 6), layer_heights_mm=(100, 60), buffer_size=4)
    policy = make_policy("plan", stability="support")
    result = run_episode(case, policy, backend="geometric")
    assert policy.decisions == len(result.steps)
    assert all(step.valid for step in result.steps)


def test_an_unknown_stability_check_is_refused():
    with pytest.raises(ConfigError, match="stability"):
        make_policy("plan", stability="mujoco")
