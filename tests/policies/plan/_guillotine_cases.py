"""Random guillotine packings of mixed heights (the cut family's structure, small), shared by the
skyline and guillotine-assembly tests."""

from __future__ import annotations

import random

import numpy as np

from packlab.policies.plan.skyline import Block

CELL_MM = 25


def guillotine_boxes(seed: int, cells=(12, 10), height_mm=400, lo=(3, 3, 80), hi=(7, 7, 250)):
    """A random 3-D guillotine cut of a cuboid (cells x cells x mm) into boxes whose sides lie
    in [lo, hi] (z in 10 mm steps): a perfect packing of mixed heights."""
    rng = random.Random(seed)
    todo, done = [(0, 0, 0, cells[0], cells[1], height_mm)], []
    while todo:
        x, y, z, dx, dy, dz = todo.pop()
        dims = [dx, dy, dz]
        axes = [a for a in range(3) if dims[a] > hi[a]]
        if not axes:
            done.append((x, y, z, dx, dy, dz))
            continue
        a = rng.choice(axes)
        step = 10 if a == 2 else 1  # heights in whole cm, footprints in whole cells
        cut = rng.randrange(lo[a], dims[a] - lo[a] + 1, step)
        first, second = list(dims), list(dims)
        first[a], second[a] = cut, dims[a] - cut
        origin = [x, y, z]
        origin[a] += cut
        todo.append((x, y, z, *first))
        todo.append((*origin, *second))
    return done


def shuffled_blocks(seed: int) -> list[Block]:
    """The boxes of ``guillotine_boxes(seed)``, each turned at random, in a random order."""
    rng = random.Random(seed)
    out = []
    for i, (_, _, _, dx, dy, dz) in enumerate(guillotine_boxes(seed)):
        if rng.random() < 0.5:
            dx, dy = dy, dx
        out.append(Block(i, dx, dy, dz))
    rng.shuffle(out)
    return out


def replay(heightmap, placements):
    """Apply a filling; every box must rest flat on what was placed before it."""
    hm = np.array(heightmap, dtype=np.int64)
    for p in placements:
        under = hm[p.x : p.x + p.fx, p.y : p.y + p.fy]
        assert under.shape == (p.fx, p.fy), "footprint leaves the container"
        assert (under == p.z_mm).all(), "a box rests on a step"
        hm[p.x : p.x + p.fx, p.y : p.y + p.fy] = p.top_mm
    return hm
