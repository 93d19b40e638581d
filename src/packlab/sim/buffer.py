"""The visible window over the arrival sequence, its seeded visible-order shuffle, and the
shown items exact observation makes of it (perceived mode's are ``packlab.sim.perceived``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from packlab.core.choices import SideNames, named_size
from packlab.core.types import Case, Container, ShownItem


def visible_window(pending: Sequence[int], buffer_size: int) -> list[int]:
    """The first ``buffer_size`` unprocessed objects (indices into the case) in arrival order."""
    return list(pending[:buffer_size])


def shuffled_view(window: Sequence[int], rng: np.random.Generator) -> list[int]:
    """The window in the order the policy sees it this step (a fresh permutation each step)."""
    order = rng.permutation(len(window))
    return [window[i] for i in order]


def episode_rng(case_seed: int, run_seed: int) -> np.random.Generator:
    """The episode's RNG, seeded from (case seed, run seed) so runs are reproducible per case."""
    return np.random.default_rng(
        np.random.SeedSequence([int(case_seed) & 0xFFFFFFFF, int(run_seed) & 0xFFFFFFFF])
    )


def cells_covering(mm: int, cell: int) -> int:
    """Cells a length of ``mm`` covers, rounded up (a box never fits in fewer)."""
    return -(-mm // cell)


def size_cells(size_mm: tuple[int, int, int], container: Container) -> tuple[int, int, int]:
    """A size (l, w, h mm) in the container's cells, each side rounded up."""
    return (
        cells_covering(size_mm[0], container.cell_xy_mm),
        cells_covering(size_mm[1], container.cell_xy_mm),
        cells_covering(size_mm[2], container.cell_z_mm),
    )


def exact_items(case: Case, shown: Sequence[int], sides: SideNames) -> tuple[ShownItem, ...]:
    """The objects at case indices ``shown`` as exact observation shows them: the case's ids
    and types, the true sizes with sides named as ``sides`` says."""
    items = []
    for i, index in enumerate(shown):
        box = case.objects[index]
        size = named_size(box.size_mm, sides)
        items.append(
            ShownItem(
                shown_index=i,
                internal_id=box.internal_id,
                size_mm=size,
                size_cells=size_cells(size, case.container),
                type_id=box.type_id,
            )
        )
    return tuple(items)
