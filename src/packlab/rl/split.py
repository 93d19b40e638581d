"""Which generated cases train an agent and which are kept out to evaluate it (pure)."""

from __future__ import annotations

from collections.abc import Sequence

from packlab.core.errors import ConfigError
from packlab.core.types import Case


def hold_out(cases: Sequence[Case], per_level: int) -> tuple[list[Case], list[Case]]:
    """(training, held-out): the first ``per_level`` cases of each level are held out.

    Every level keeps at least one training case, so a small case file is refused rather than
    silently trained on nothing.
    """
    train: list[Case] = []
    held: list[Case] = []
    seen: dict[str, int] = {}
    for case in cases:
        n = seen.get(case.difficulty, 0)
        (held if n < per_level else train).append(case)
        seen[case.difficulty] = n + 1
    short = {level: n for level, n in seen.items() if n <= per_level}
    if short:
        level, n = next(iter(short.items()))
        raise ConfigError(
            f"cases: level {level!r} has {n} case(s); holding out {per_level} per level for "
            "evaluation leaves none to train on (generate more, or lower --eval-cases)"
        )
    return train, held
