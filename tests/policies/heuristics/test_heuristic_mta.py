"""MTA on hand-made states, and its contact area against hand-computed values."""

from __future__ import annotations

import heuristics_reference as ref
import numpy as np

from packlab.core.feasibility import search_candidates
from packlab.core.types import Action
from packlab.policies.heuristics import dblf, mta
from packlab.policies.heuristics.select import choose, to_action


def cands(heights, shown, rim=100):
    return search_candidates(np.asarray(heights, dtype=np.int32), shown, rim)


POCKET = [[50, 50, 50], [0, 0, 50], [0, 0, 50]]


def test_contact_area_of_a_square_box_in_each_position() -> None:
    # 2 x 2 cells, 40 mm tall, rim 100. Areas in cm^2 (cell 2.5 cm, so a cell is 6.25 cm^2 and
    # a 1 mm overlap along one cell edge is 0.25 cm^2).
    c = cands(POCKET, [ref.shown_item(0, 2, 2, 40)])
    got = dict(
        zip(
            zip(c.x[c.rotation == 0].tolist(), c.y[c.rotation == 0].tolist()),
            mta.contact_area_cm2(c)[c.rotation == 0].tolist(),
        )
    )
    # (0, 0): rests at 50 on two cells (12.5); -x and -y walls 40 mm over 2 cells each
    # (4 * 40 * 0.25 = 40); the +x columns (0 mm) and +y columns (50 mm) lie below it.
    # (0, 1): rests at 50 on three cells (18.75); -x and +y walls (40).
    # (1, 0): the pocket: floor under all four cells (25); the 50 mm columns at -x and +y and
    # the walls at +x and -y each cover 40 mm over two cells (8 * 40 * 0.25 = 80).
    # (1, 1): rests at 50 on two cells (12.5); +x and +y walls (40).
    assert got == {(0, 0): 52.5, (0, 1): 58.75, (1, 0): 105.0, (1, 1): 52.5}
    assert to_action(c, choose(c, mta.score(c))) == Action(0, 0, 1, 0)


def test_side_overlap_is_clipped_to_the_box_and_to_the_wall_height() -> None:
    # 1 x 1 box, 80 mm tall, on a 30 mm cell beside a 50 mm and a 200 mm column; rim 100.
    heights = [[30, 50], [200, 0]]
    c = cands(heights, [ref.shown_item(0, 1, 1, 80)], rim=100)
    i = int(np.flatnonzero((c.x == 0) & (c.y == 0) & (c.rotation == 0))[0])
    # z = 30, top = 110. Support 625 mm^2. Walls (-x, -y): min(110, 100) - 30 = 70 mm each.
    # +x column 200: min(110, 200) - 30 = 80. +y column 50: 50 - 30 = 20.
    assert mta.contact_area_mm2(c)[i] == 625 + (70 + 70 + 80 + 20) * 25


def test_prefers_a_deep_pocket_over_a_lower_open_spot() -> None:
    # 6 x 1 cells, rim 200, 1 x 1 box 50 mm tall. The pit at x = 4 (30 mm, between 150 mm
    # columns) touches on four sides: 625 + 4 * 50 * 25 = 5625 mm^2; the floor at x = 0 touches
    # the -x wall and both y walls only: 625 + 3 * 50 * 25 = 4375 mm^2.
    c = cands([[0], [0], [0], [150], [30], [150]], [ref.shown_item(0, 1, 1, 50)], rim=200)
    assert to_action(c, choose(c, mta.score(c))) == Action(0, 0, 4, 0)
    assert to_action(c, choose(c, dblf.score(c))) == Action(0, 0, 0, 0)


def test_chooses_the_taller_object_for_its_larger_faces() -> None:
    shown = [ref.shown_item(0, 1, 1, 20), ref.shown_item(1, 1, 1, 60)]
    c = cands(np.zeros((2, 2)), shown)
    assert to_action(c, choose(c, mta.score(c))) == Action(1, 0, 0, 0)


def test_equal_contact_ties_go_bottom_then_deepest() -> None:
    # 1 x 1 box, 50 mm, rim 100. The floor corner (0, 0) and the pit (1, 1) at 20 mm both touch
    # 625 + 3 * 50 * 25 = 4375 mm^2 ((0, 0): -x and -y walls and the 100 mm column at +x;
    # (1, 1): three 100 mm columns). Lower z wins; (0, 2) also ties at z = 0 but lies further left.
    heights = [[0, 0, 0], [100, 20, 100], [100, 100, 100]]
    c = cands(heights, [ref.shown_item(0, 1, 1, 50)])
    area = dict(zip(zip(c.x.tolist(), c.y.tolist()), mta.contact_area_mm2(c).tolist()))
    assert area[(0, 0)] == area[(1, 1)] == area[(0, 2)] == 4375
    assert max(area.values()) == 4375
    assert to_action(c, choose(c, mta.score(c))) == Action(0, 0, 0, 0)
