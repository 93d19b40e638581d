"""Small perfect layered cases from a tiny generator written for the tests.

The data engine has its own generator; this one is deliberately simple and independent so the
core tests do not depend on it.
"""

from __future__ import annotations

import numpy as np

from packlab.core.types import Box, Case, Container, PlanStep


def _split(rng: np.random.Generator, dx: int, dy: int, pieces: int, min_side: int) -> list:
    """Guillotine-cut a dx x dy rectangle into up to ``pieces`` rectangles (largest cut first)."""
    rects = [(0, 0, dx, dy)]
    while len(rects) < pieces:
        splittable = [r for r in rects if r[2] >= 2 * min_side or r[3] >= 2 * min_side]
        if not splittable:
            break
        x, y, w, h = max(splittable, key=lambda r: r[2] * r[3])
        rects.remove((x, y, w, h))
        if w >= 2 * min_side and (h < 2 * min_side or rng.random() < w / (w + h)):
            c = int(rng.integers(min_side, w - min_side + 1))
            rects += [(x, y, c, h), (x + c, y, w - c, h)]
        else:
            c = int(rng.integers(min_side, h - min_side + 1))
            rects += [(x, y, w, c), (x, y + c, w, h - c)]
    return rects


def make_layered_case(
    seed: int,
    cells=(16, 12),
    layer_heights_mm=(200, 150),
    buffer_size=3,
    rim_mm: int | None = None,
    episode_id: str | None = None,
    pieces: int = 4,
) -> Case:
    """A perfect layout: each layer tiled exactly by rectangles, placed bottom layer first."""
    rng = np.random.default_rng(seed)
    cell = 25
    objects, plan = [], []
    z = 0
    for layer, h in enumerate(layer_heights_mm):
        rects = _split(rng, cells[0], cells[1], pieces, 3)
        for i in rng.permutation(len(rects)):
            x, y, dx, dy = rects[i]
            rotation = int(rng.random() < 0.25)
            size = (dy * cell, dx * cell, h) if rotation else (dx * cell, dy * cell, h)
            iid = len(objects)
            objects.append(Box(internal_id=iid, size_mm=size, gt_index=iid, type_id=iid % 7))
            plan.append(PlanStep(iid, iid, layer, (x, y, z // 2), (dx, dy, h // 2), x, y, rotation))
        z += h
    container = Container((cells[0] * cell, cells[1] * cell, rim_mm or z + 100))
    return Case(
        episode_id or f"layered-{seed}",
        container,
        buffer_size,
        tuple(objects),
        seed=seed,
        difficulty="test",
        gt_plan=tuple(plan),
    )
