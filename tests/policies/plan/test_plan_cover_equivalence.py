"""The bitmask exact cover answers exactly as the numpy one it replaced: same slots in the same
order, same node count, same ``exhausted``, on seeded random regions, pieces and rules.

Node budgets decide what the planner does (and so the bench's scores), so "same nodes" is part
of the contract, not a detail. The reference is a frozen copy (_cover_reference.py).
"""

from __future__ import annotations

import numpy as np
import pytest
from _cover_reference import exact_cover as reference_cover
from layered_cases import _split

from packlab.policies.plan.cover import JOKER, CoverResult, CoverRules, Piece, exact_cover

CASES = 400
BUDGETS = (1, 2, 7, 40, 300, 2_000)


def _region_and_pieces(rng: np.random.Generator, nx: int, ny: int) -> tuple[np.ndarray, list]:
    """A guillotine layer cut into rectangles: the region is what some of them leave free (the
    whole box, or with rectangles placed, maybe with a few extra cells blocked), the pieces are
    the free rectangles (a few dropped, turned at random, shuffled) with a few strangers and
    repeated footprints: tilings exist for some cases, for others only with jokers or none."""
    rects = _split(rng, nx, ny, int(rng.integers(2, 12)), int(rng.integers(1, 4)))
    region = np.ones((nx, ny), bool)
    sizes = []
    placed = rng.random() < 0.5
    for x, y, dx, dy in rects:
        if placed and rng.random() < 0.3:
            region[x : x + dx, y : y + dy] = False
        elif rng.random() < 0.9:
            sizes.append((dx, dy))
    if rng.random() < 0.2:
        x, y = int(rng.integers(nx)), int(rng.integers(ny))
        region[x : x + int(rng.integers(1, 4)), y : y + int(rng.integers(1, 4))] = False
    if rng.random() < 0.3:
        # strangers: small ones, and long ones that may not fit the grid turned either way
        sizes += [
            (int(rng.integers(1, 7)), int(rng.integers(1, max(nx, ny) + 4))) for _ in range(2)
        ]
    if sizes and rng.random() < 0.3:
        sizes += [sizes[0]] * int(rng.integers(1, 3))
    pieces = [
        Piece(k, dy, dx) if rng.random() < 0.5 else Piece(k, dx, dy)
        for k, (dx, dy) in enumerate(sizes)
    ]
    return region, [pieces[i] for i in rng.permutation(len(pieces))]


def _rules(rng: np.random.Generator) -> CoverRules:
    if rng.random() < 0.35:
        return CoverRules()
    return CoverRules(
        jokers=int(rng.integers(1, 4)),
        use_all=bool(rng.random() < 0.5),
        joker_side=int(rng.integers(1, 5)),
        tilings=int(rng.choice([1, 2, 5, 32])),
    )


def _case(seed: int) -> tuple[np.ndarray, list[Piece], int, CoverRules]:
    rng = np.random.default_rng(seed)
    nx, ny = int(rng.integers(3, 19)), int(rng.integers(3, 19))
    region, pieces = _region_and_pieces(rng, nx, ny)
    return region, pieces, int(rng.choice(BUDGETS)), _rules(rng)


def _compare(seed: int) -> tuple[CoverResult, CoverRules]:
    region, pieces, budget, rules = _case(seed)
    want = reference_cover(region, pieces, budget, rules)
    got = exact_cover(region, pieces, budget, rules)
    assert got == want, f"seed {seed}: {got} != {want}"
    return got, rules


@pytest.mark.parametrize("block", range(8))
def test_the_fast_search_answers_exactly_as_the_reference(block):
    results = [_compare(seed) for seed in range(block * CASES // 8, (block + 1) * CASES // 8)]
    # Each block reaches the branches that matter: budgets that run out, tilings found with
    # jokers and without, and several tilings compared.
    assert any(r.exhausted for r, _ in results)
    assert any(r.slots and not any(s.key == JOKER for s in r.slots) for r, _ in results)
    assert any(r.slots and any(s.key == JOKER for s in r.slots) for r, _ in results)
    assert any(r.slots and rules.tilings > 1 for r, rules in results)


@pytest.mark.parametrize("seed", range(40))
def test_degenerate_sizes_answer_as_the_reference(seed):
    # A side of 0 cells (a box perceived thinner than nothing) and jokers of side 0 are not
    # the planner's, but the search must not part from the reference on them either.
    region, pieces, budget, _ = _case(10_000 + seed)
    rng = np.random.default_rng(seed)
    pieces.append(Piece(len(pieces), int(rng.integers(0, 3)), 0))
    rules = CoverRules(jokers=int(rng.integers(0, 3)), use_all=bool(seed % 2), joker_side=0)
    want = reference_cover(region, pieces, budget, rules)
    assert exact_cover(region, pieces, budget, rules) == want


def test_a_piece_wider_than_the_grid_shares_no_footprint_with_a_joker():
    # In a 4 x 4 grid a row takes 5 bits: a 1 x 7 piece and a 2 x 2 joker would share the
    # footprint id fx * 5 + fy (12), and so a cached window, were ids counted in rows.
    region = np.ones((4, 4), bool)
    for pieces in ([Piece(0, 1, 7), Piece(1, 2, 3)], [Piece(0, 1, 7)]):
        for jokers in (1, 2, 3):
            rules = CoverRules(jokers=jokers, joker_side=2, tilings=32)
            want = reference_cover(region, pieces, 5_000, rules)
            assert exact_cover(region, pieces, 5_000, rules) == want
