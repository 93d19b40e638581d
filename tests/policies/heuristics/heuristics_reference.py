"""Slow, loop-by-loop reference implementations of the candidate search and every heuristic.

Written straight from the rules in the module docstrings, one candidate and one cell at a time,
so the vectorised code is checked against something obviously right (if slow).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from packlab.core.types import ShownItem


@dataclass(frozen=True)
class RefCandidate:
    obj: int
    rotation: int
    x: int
    y: int
    fx: int
    fy: int
    z: int
    top: int
    fits_in_rim: bool
    size_mm: tuple[int, int, int]  # the object's (l, w, h), for the tie-break rule
    internal_id: int | str  # the object's id, the tie-break rule's last key


def shown_item(index: int, fx: int, fy: int, h_mm: int, cell: int = 25) -> ShownItem:
    """A shown item whose rotation-0 footprint is (fx, fy) cells."""
    return ShownItem(index, 100 + index, (fx * cell, fy * cell, h_mm), (fx, fy, -(-h_mm // 2)))


def candidates(hm: np.ndarray, shown: list[ShownItem], rim: int) -> list[RefCandidate]:
    nx, ny = hm.shape
    out = []
    for k, item in enumerate(shown):
        for rot in (0, 1):
            l, w, _ = item.size_cells
            fx, fy = (w, l) if rot else (l, w)
            h = item.size_mm[2]
            for x in range(nx):
                for y in range(ny):
                    if x + fx > nx or y + fy > ny:
                        continue
                    z = max(int(hm[i, j]) for i in range(x, x + fx) for j in range(y, y + fy))
                    out.append(
                        RefCandidate(
                            k,
                            rot,
                            x,
                            y,
                            fx,
                            fy,
                            z,
                            z + h,
                            z + h <= rim,
                            item.size_mm,
                            item.internal_id,
                        )
                    )
    return out


def pool(cands: list[RefCandidate]) -> list[int]:
    """Indices of the in-rim candidates, else those of the lowest top."""
    inside = [i for i, c in enumerate(cands) if c.fits_in_rim]
    if inside or not cands:
        return inside
    low = min(c.top for c in cands)
    return [i for i, c in enumerate(cands) if c.top == low]


def larger_first(c: RefCandidate) -> tuple:
    """The ``larger_volume`` order of c's object: volume, area, l, w (larger first), then id."""
    l, w, h = c.size_mm
    return (-l * w * h, -l * w, -l, -w, isinstance(c.internal_id, str), c.internal_id)


def choose(cands: list[RefCandidate], key, tie_break: str = "larger_volume") -> int | None:
    """min over the pool by (key(c), tie order): the tie order is the scan index for
    ``shown_order``; for ``larger_volume`` the object's size order, then rotation, x, y."""
    p = pool(cands)
    if not p:
        return None
    if tie_break == "shown_order":
        return min(p, key=lambda i: (key(cands[i]), i))
    return min(
        p,
        key=lambda i: (
            key(cands[i]),
            larger_first(cands[i]),
            cands[i].rotation,
            cands[i].x,
            cands[i].y,
        ),
    )


def hm_increase_mm3(hm: np.ndarray, c: RefCandidate, cell: int = 25) -> int:
    total = 0
    for i in range(c.x, c.x + c.fx):
        for j in range(c.y, c.y + c.fy):
            total += max(int(hm[i, j]), c.top) - int(hm[i, j])
    return total * cell * cell


def contact_mm2(hm: np.ndarray, rim: int, c: RefCandidate, cell: int = 25) -> int:
    nx, ny = hm.shape

    def column(i: int, j: int) -> int:
        return int(hm[i, j]) if 0 <= i < nx and 0 <= j < ny else rim  # outside: a wall

    area = 0
    for i in range(c.x, c.x + c.fx):
        for j in range(c.y, c.y + c.fy):
            if int(hm[i, j]) == c.z:
                area += cell * cell
            for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                ni, nj = i + di, j + dj
                if c.x <= ni < c.x + c.fx and c.y <= nj < c.y + c.fy:
                    continue  # an inner edge of the box, not a face
                area += max(0, min(c.top, column(ni, nj)) - c.z) * cell
    return area


def solid_voxels(hm: np.ndarray, rim: int, v: int) -> np.ndarray:
    """(m, 3) padded coordinates of every solid voxel: floor, walls up to the rim, columns."""
    nx, ny = hm.shape
    layers = math.ceil(max(int(hm.max()), rim) / v) + 1
    pts = []
    for i in range(nx + 2):
        for j in range(ny + 2):
            pts.append((i, j, 0))  # the floor
            wall = i in (0, nx + 1) or j in (0, ny + 1)
            height = rim if wall else int(hm[i - 1, j - 1])
            for k in range(layers):
                if (k + 0.5) * v < height:
                    pts.append((i, j, k + 1))
    return np.array(pts, dtype=np.float64)


def brute_gap_field(hm: np.ndarray, rim: int, v: int, layers: int, trunc: float) -> np.ndarray:
    """Truncated gap (mm) of every padded voxel [i, j, k] (k = 0 the floor) by brute force."""
    nx, ny = hm.shape
    solids = solid_voxels(hm, rim, v)
    grid = np.stack(np.indices((nx + 2, ny + 2, layers + 1)), axis=-1).reshape(-1, 3)
    d2 = ((grid[:, None, :] - solids[None, :, :]) ** 2).sum(axis=-1).min(axis=1)
    gap = np.clip((np.sqrt(d2) - 1.0) * v, 0.0, trunc)
    return gap.reshape(nx + 2, ny + 2, layers + 1)


def box_layers(c: RefCandidate, v: int) -> list[int]:
    """Layers whose centre lies in [z, top); at least the first one at or above z."""
    ks = [k for k in range(c.top // v + 2) if c.z <= (k + 0.5) * v < c.top]
    return ks or [math.ceil(c.z / v - 0.5)]


def mean_surface_gap_mm(field: np.ndarray, c: RefCandidate, v: int) -> float:
    """Mean over the box's bottom-layer and side-face voxels of the field (top face left out)."""
    ks = box_layers(c, v)
    gaps = []
    for i in range(c.x, c.x + c.fx):
        for j in range(c.y, c.y + c.fy):
            side = i in (c.x, c.x + c.fx - 1) or j in (c.y, c.y + c.fy - 1)
            for k in ks:
                if side or k == ks[0]:
                    gaps.append(field[i + 1, j + 1, k + 1])
    return float(np.mean(gaps))
