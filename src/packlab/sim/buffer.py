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


#: A measured side (perceived mode, ``packlab cell serve``) this many mm or less over a whole
#: number of cells takes that number of cells: the size estimate errs by a few mm (structured
#: light: mean 2 mm, p95 4 mm), and a carton a few mm short of a cell multiple measured a mm or
#: two long would otherwise take one cell more than it covers, and no exact tiling of its level
#: would hold it. On sizes snapped to the cell grid it changes nothing. Chosen on generated
#: off-grid training cases (plan-fast, structured light, ``--size-prior none``): 2, 3, 4 and 5
#: mm against none, +0.020, +0.025 [+0.002, +0.051], +0.010 and +0.010.
MEASURED_SIDE_SLACK_MM = 3


def size_cells(
    size_mm: tuple[int, int, int], container: Container, slack_mm: int = 0
) -> tuple[int, int, int]:
    """A size (l, w, h mm) in the container's cells, each side rounded up; a length (l, w) at
    most ``slack_mm`` over a whole number of cells takes that number (measured sizes:
    :data:`MEASURED_SIDE_SLACK_MM`). True sizes take no slack: a footprint covers every cell it
    touches."""
    cell = container.cell_xy_mm
    return (
        cells_covering(max(size_mm[0] - slack_mm, 1), cell),
        cells_covering(max(size_mm[1] - slack_mm, 1), cell),
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
