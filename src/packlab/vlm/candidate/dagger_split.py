"""Which generated cases each DAgger round plays, and which evaluate (torch-free)."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence

from packlab.core.types import Case

LEVEL_ORDER = ("easy", "medium", "hard")


def split_cases(
    cases: Sequence[Case], per_round: int, rounds: int, eval_per_level: int
) -> tuple[list[list[Case]], list[Case]]:
    """(cases of each round 0..rounds, evaluation cases): round r takes the r-th slice of each
    level's cases, interleaved by level; the last ``eval_per_level`` of each level evaluate."""
    by_level: dict[str, list[Case]] = defaultdict(list)
    for c in cases:
        by_level[c.difficulty].append(c)
    levels = [d for d in LEVEL_ORDER if d in by_level] or sorted(by_level)
    evals = [c for d in levels for c in by_level[d][len(by_level[d]) - eval_per_level :]]
    each = max(1, per_round // len(levels))
    need = each * (rounds + 1) + eval_per_level
    short = [d for d in levels if len(by_level[d]) < need]
    if short:
        raise ValueError(
            f"{rounds + 1} rounds of {per_round} cases need {need} cases per level; "
            f"{', '.join(f'{d} has {len(by_level[d])}' for d in short)}"
        )
    rounds_cases = [
        [by_level[d][r * each + i] for i in range(each) for d in levels] for r in range(rounds + 1)
    ]
    return rounds_cases, evals
