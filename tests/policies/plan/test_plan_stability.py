"""The planner's support test and its fallback down the ranking."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core.errors import ConfigError
from packlab.core.feasibility import search_candidates
from packlab.core.types import Action, Box, Case, Container, ShownItem
from packlab.policies import make_policy
from packlab.policies.plan.search import _pick
from packlab.policies.plan.stability import centre_supported
from packlab.sim.episode import Episode


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


#: A hand-made scene (y sizes 90 mm in a 100 mm container, so nothing jams against the walls):
#: an 8 x 4 cell floor with a 40 mm pillar on x = 0 and an 80 mm one on x = 5..6, then a 5-cell
#: long box to place. Heightmap along x: 40 0 0 0 0 80 80 0. The box cannot reach the floor; of
#: its placements only x = 3 has its centre (cell 2.5 of 5) over its contact cells (x = 5..6).
TIPPING_SCENE = ((25, 90, 40), (50, 90, 80), (125, 90, 40))
PILLARS_AT = (0, 5)


def _scene_case() -> Case:
    boxes = tuple(Box(internal_id=i, size_mm=s, gt_index=i) for i, s in enumerate(TIPPING_SCENE))
    return Case("tipping", Container((200, 100, 300)), 1, boxes, seed=0)


def _place_last(backend: str, stability: str):
    """Script the pillars, let ``plan`` place the last box: (policy, action, heightmap before,
    the drop, the episode)."""
    episode = Episode(backend, sides="catalogue")  # the scripted rotations are the catalogue's
    episode.reset(_scene_case(), 0)
    for x in PILLARS_AT:
        episode.step(Action(0, 0, x, 0))
    before = episode.heightmap.copy()
    policy = make_policy("plan", stability=stability)
    action = policy.act(episode.observe())
    step = episode.step(action)
    return policy, action, before, step.drop_mm, episode


def _centre_over_contact(before: np.ndarray, action: Action, drop_mm) -> bool:
    """Independent of the module under test: boxes span the container's width, so the box holds
    when its centre lies within the x extent of the cells touching its underside."""
    length = TIPPING_SCENE[-1][0] // 25
    under = before[action.x : action.x + length, 0]
    touching = np.flatnonzero(under >= drop_mm[2])
    return bool(touching.size) and touching.min() <= length / 2 <= touching.max() + 1


def _tilt_deg(quaternions: np.ndarray) -> np.ndarray:
    """Per box, the angle (degrees) between its up axis and the world's (wxyz quaternions)."""
    up_z = 1.0 - 2.0 * (quaternions[:, 1] ** 2 + quaternions[:, 2] ** 2)
    return np.degrees(np.arccos(np.clip(up_z, -1.0, 1.0)))


def test_the_support_check_turns_a_tipping_choice_into_a_standing_one():
    # Without the check the planner's cheapest placement overhangs the 40 mm pillar: the scene
    # really asks the check to act ...
    off, tipping, before, drop, _ = _place_last("geometric", "off")
    assert before[:, 0].tolist() == [40, 0, 0, 0, 0, 80, 80, 0]
    assert not _centre_over_contact(before, tipping, drop)
    assert (off.decisions, off.fallbacks) == (1, 0)
    # ... and with it the planner takes the one placement whose centre is supported.
    checked, standing, before, drop, _ = _place_last("geometric", "support")
    assert standing == Action(0, 0, 3, 0) and drop == (75, 0, 80)
    assert _centre_over_contact(before, standing, drop)
    assert (checked.decisions, checked.fallbacks) == (1, 1)


@pytest.mark.physics
def test_in_mujoco_the_checked_placement_stands_and_the_unchecked_one_tips():
    _, _, _, _, tipped = _place_last("mujoco", "off")
    _, _, _, drop, stood = _place_last("mujoco", "support")
    assert _tilt_deg(tipped.backend.poses()[1])[-1] > 10  # it fell into the gap
    positions, quaternions = stood.backend.poses()
    assert _tilt_deg(quaternions).max() < 2  # every box upright, the last one too ...
    assert positions[-1][2] == pytest.approx(drop[2] + TIPPING_SCENE[-1][2] / 2, abs=2)  # on top


def test_an_unknown_stability_check_is_refused():
    with pytest.raises(ConfigError, match="stability"):
        make_policy("plan", stability="mujoco")
