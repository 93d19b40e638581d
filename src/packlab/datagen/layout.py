"""Layout partition: the perfect packing a case is made from, as boxes on the grid.

A layout tiles the cuboid ``x_cells x y_cells x height`` (floor cells by z cells) exactly: the
boxes are pairwise disjoint, lie inside it and their volumes add up to its volume. That makes
every layout a perfect packing by construction, which is what the oracle's score of 1.0 rests
on:

* Compactness 1: the boxes fill X * Y * H with H the stack height.
* Full support: take a point just under a box's bottom face (z > 0). It lies in some box,
  which cannot reach into the box above, so its top is exactly that bottom face. Every part of
  every bottom face therefore rests on a top face or the floor, whatever the family.

Two families (``CaseConfig.layout``):

* ``layered`` (the paper's): the stack height is cut into layers; each layer's floor is cut into
  rectangles by guillotine cuts on the grid; every object of a layer has the layer's height.
* ``stepped`` (opt-in, richer): a layer's floor is first cut into 2-3 regions, and each region
  may be cut at its own height into two sub-layers, each then tiled like a layer. Neighbouring
  regions thus grow at different heights (the surface is a set of steps while the layer is being
  built), sub-layer objects rest on several smaller objects, and the next layer rests on a
  support assembled from objects of different heights. The layer's top stays flat, so the
  layout is still an exact 3-D guillotine partition of the cuboid and everything above holds.
  Partial layers (a layer not covering the floor) are not offered: nothing could rest on the gap
  and the terminal packing would not be compact.

Every object has sides of at least ``min_side_mm``, a footprint aspect ratio of at most
``max_aspect`` and a height in the layer-height range.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from packlab.datagen.config import CaseConfig
from packlab.datagen.scenario import Scenario, split_height


@dataclass(frozen=True, slots=True)
class Rect:
    """A floor rectangle in xy cells."""

    x: int
    y: int
    dx: int
    dy: int

    @property
    def area(self) -> int:
        return self.dx * self.dy


@dataclass(frozen=True, slots=True)
class LayoutBox:
    """One box of a layout: min corner and size in (xy cells, xy cells, z cells)."""

    x: int
    y: int
    z: int
    dx: int
    dy: int
    dz: int
    layer_index: int

    @property
    def volume(self) -> int:
        return self.dx * self.dy * self.dz

    @property
    def top(self) -> int:
        return self.z + self.dz


@dataclass(frozen=True, slots=True)
class Layout:
    """A perfect packing of the cuboid ``cells x height`` (z cells), bottom layer first."""

    cells: tuple[int, int]
    height: int  # stack height in z cells
    boxes: tuple[LayoutBox, ...]
    family: str


@dataclass(frozen=True, slots=True)
class PieceRules:
    """Shape rules of a floor piece, in cells."""

    min_side: int
    max_aspect: float


def _aspect_ok(a: np.ndarray | int, b: np.ndarray | int, rules: PieceRules) -> np.ndarray | bool:
    return np.maximum(a, b) <= rules.max_aspect * np.minimum(a, b)


def valid_cuts(dx: int, dy: int, rules: PieceRules) -> list[tuple[int, int]]:
    """Guillotine cuts (axis, offset) of a dx x dy piece whose two children obey ``rules``."""
    m = rules.min_side
    cuts: list[tuple[int, int]] = []
    for axis, (length, other) in enumerate(((dx, dy), (dy, dx))):
        pos = np.arange(m, length - m + 1)
        if pos.size == 0:
            continue
        ok = _aspect_ok(pos, other, rules) & _aspect_ok(length - pos, other, rules)
        cuts.extend((axis, int(p)) for p in pos[ok])
    return cuts


def _cut(r: Rect, axis: int, offset: int) -> tuple[Rect, Rect]:
    if axis == 0:
        return Rect(r.x, r.y, offset, r.dy), Rect(r.x + offset, r.y, r.dx - offset, r.dy)
    return Rect(r.x, r.y, r.dx, offset), Rect(r.x, r.y + offset, r.dx, r.dy - offset)


def guillotine_partition(
    rect: Rect, k: int, rules: PieceRules, rng: np.random.Generator, tries: int = 40
) -> list[Rect] | None:
    """``rect`` cut into exactly ``k`` pieces obeying ``rules``, or None if the tries run out.

    Each cut splits a piece chosen with probability proportional to its area (keeps sizes
    comparable) at a position drawn uniformly from its valid cuts (long sides have more valid
    positions, so pieces drift towards squarish without forbidding slabs).
    """
    if k < 1 or not _aspect_ok(rect.dx, rect.dy, rules) or min(rect.dx, rect.dy) < rules.min_side:
        return None
    for _ in range(tries):
        pieces = [rect]
        cuts = [valid_cuts(rect.dx, rect.dy, rules)]
        while len(pieces) < k:
            splittable = [i for i, c in enumerate(cuts) if c]
            if not splittable:
                break
            areas = np.array([pieces[i].area for i in splittable], dtype=np.float64)
            i = splittable[int(rng.choice(len(splittable), p=areas / areas.sum()))]
            axis, offset = cuts[i][int(rng.integers(len(cuts[i])))]
            a, b = _cut(pieces[i], axis, offset)
            pieces[i : i + 1] = [a, b]
            cuts[i : i + 1] = [valid_cuts(a.dx, a.dy, rules), valid_cuts(b.dx, b.dy, rules)]
        if len(pieces) == k:
            return pieces
    return None


def _spread(total: int, weights: np.ndarray, rng: np.random.Generator) -> list[int]:
    """``total`` items over len(weights) bins, at least one each, the rest multinomial."""
    n = len(weights)
    extra = rng.multinomial(total - n, weights / weights.sum())
    return [1 + int(e) for e in extra]


@dataclass(frozen=True, slots=True)
class _Block:
    """A region of one layer with its own z range, to be tiled into ``count`` objects."""

    rect: Rect
    z: int
    dz: int


def _stepped_blocks(
    floor: Rect,
    z: int,
    dz: int,
    count: int,
    cfg: CaseConfig,
    rules: PieceRules,
    rng: np.random.Generator,
) -> list[_Block] | None:
    """Regions of a layer, each kept whole or split at its own height into two sub-layers."""
    zc = cfg.cell_z_mm
    lo, hi = (v // zc for v in cfg.objects.layer_height_mm)
    step = cfg.objects.height_step_mm // zc
    if count < 2:
        return None
    n_regions = int(rng.integers(2, min(3, count) + 1))
    regions = guillotine_partition(floor, n_regions, rules, rng)
    if regions is None:
        return None
    blocks: list[_Block] = []
    budget = count - n_regions  # every extra block needs one more object
    for region in regions:
        can_split = dz >= 2 * lo and budget > 0
        if can_split and rng.random() < cfg.step_prob:
            low = split_height(dz * zc, 2, lo * zc, hi * zc, step * zc, rng)[0] // zc
            blocks += [_Block(region, z, low), _Block(region, z + low, dz - low)]
            budget -= 1
        else:
            blocks.append(_Block(region, z, dz))
    return blocks


def _tile_blocks(
    blocks: list[_Block], count: int, layer: int, rules: PieceRules, rng: np.random.Generator
) -> list[LayoutBox] | None:
    """Each block's floor cut into its share of ``count`` objects (share grows with area)."""
    shares = _spread(count, np.array([b.rect.area for b in blocks], dtype=np.float64), rng)
    out: list[LayoutBox] = []
    for block, k in zip(blocks, shares):
        pieces = guillotine_partition(block.rect, k, rules, rng)
        if pieces is None:
            return None
        out += [LayoutBox(p.x, p.y, block.z, p.dx, p.dy, block.dz, layer) for p in pieces]
    return out


def build_layout(
    scenario: Scenario, cfg: CaseConfig, rng: np.random.Generator, tries: int = 20
) -> Layout:
    """The layout of a scenario in the configured family (pure; draws only from ``rng``)."""
    c = scenario.container
    nx, ny = c.cells
    zc = c.cell_z_mm
    rules = PieceRules(-(-cfg.objects.min_side_mm // c.cell_xy_mm), cfg.objects.max_aspect)
    floor = Rect(0, 0, nx, ny)
    n_layers = len(scenario.layer_heights_mm)
    for _ in range(tries):
        counts = _spread(scenario.n_objects, np.ones(n_layers), rng)
        boxes: list[LayoutBox] = []
        z = 0
        for layer, (h_mm, count) in enumerate(zip(scenario.layer_heights_mm, counts)):
            dz = h_mm // zc
            tiled = None
            if cfg.layout == "stepped":
                blocks = _stepped_blocks(floor, z, dz, count, cfg, rules, rng)
                tiled = None if blocks is None else _tile_blocks(blocks, count, layer, rules, rng)
            if tiled is None:  # layered family, or a stepped draw that did not fit
                tiled = _tile_blocks([_Block(floor, z, dz)], count, layer, rules, rng)
            if tiled is None:
                break
            boxes += tiled
            z += dz
        else:
            return Layout((nx, ny), scenario.stack_height_mm // zc, tuple(boxes), cfg.layout)
    raise ValueError(
        f"could not tile {scenario.n_objects} objects in {n_layers} layers "
        f"on a {nx}x{ny}-cell floor"
    )


def partition_problems(layout: Layout) -> list[str]:
    """Why ``layout`` is not an exact partition of its cuboid (empty when it is).

    Pairwise-disjoint boxes inside the cuboid whose volumes add up to its volume cover it
    exactly (on the integer grid there is nowhere else for the volume to go).
    """
    nx, ny = layout.cells
    problems = []
    boxes = layout.boxes
    for i, b in enumerate(boxes):
        if min(b.dx, b.dy, b.dz) <= 0:
            problems.append(f"box {i} has a non-positive size {b}")
        if (
            b.x < 0
            or b.y < 0
            or b.z < 0
            or b.x + b.dx > nx
            or b.y + b.dy > ny
            or b.top > layout.height
        ):
            problems.append(f"box {i} sticks out of the {nx}x{ny}x{layout.height} cuboid: {b}")
    if boxes:
        lo = np.array([(b.x, b.y, b.z) for b in boxes])
        hi = lo + np.array([(b.dx, b.dy, b.dz) for b in boxes])
        overlap = np.all(
            (lo[:, None, :] < hi[None, :, :]) & (lo[None, :, :] < hi[:, None, :]), axis=2
        )
        np.fill_diagonal(overlap, False)
        for i, j in zip(*np.nonzero(np.triu(overlap))):
            problems.append(f"boxes {i} and {j} overlap")
    total = sum(b.volume for b in boxes)
    if total != nx * ny * layout.height:
        problems.append(f"volumes add up to {total}, the cuboid holds {nx * ny * layout.height}")
    return problems
