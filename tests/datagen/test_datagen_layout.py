"""Layouts are exact partitions of their cuboid and obey the object shape rules."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.datagen.config import CaseConfig, difficulty_spec
from packlab.datagen.generator import draw_blueprint
from packlab.datagen.layout import (
    Layout,
    LayoutBox,
    PieceRules,
    Rect,
    guillotine_partition,
    partition_problems,
)
from packlab.datagen.seeds import case_seed

FAMILIES = ("layered", "stepped")


def _voxels(layout: Layout) -> np.ndarray:
    """Occupancy count of every (x, y, z) cell: an independent check of the partition."""
    nx, ny = layout.cells
    grid = np.zeros((nx, ny, layout.height), dtype=np.int32)
    for b in layout.boxes:
        grid[b.x : b.x + b.dx, b.y : b.y + b.dy, b.z : b.z + b.dz] += 1
    return grid


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("difficulty", ["easy", "medium", "hard"])
def test_every_layout_is_an_exact_partition(difficulty, family):
    cfg = CaseConfig(layout=family)
    for slot in range(40):
        bp = draw_blueprint(case_seed(3, "train", difficulty, slot), difficulty, cfg)
        layout, scenario = bp.layout, bp.scenario
        assert partition_problems(layout) == []
        vox = _voxels(layout)
        assert vox.min() == 1 and vox.max() == 1  # inside, no overlaps, nothing missing
        c = scenario.container
        assert layout.cells == c.cells
        assert layout.height * c.cell_z_mm == scenario.stack_height_mm
        # Each layer's boxes fill exactly that layer's slab.
        z = 0
        for index, h_mm in enumerate(scenario.layer_heights_mm):
            dz = h_mm // c.cell_z_mm
            layer = [b for b in layout.boxes if b.layer_index == index]
            assert all(z <= b.z and b.top <= z + dz for b in layer)
            assert sum(b.volume for b in layer) == c.cells[0] * c.cells[1] * dz
            z += dz


@pytest.mark.parametrize("family", FAMILIES)
def test_objects_obey_shape_rules(family):
    cfg = CaseConfig(layout=family)
    lo, hi = cfg.objects.layer_height_mm
    for difficulty in ("easy", "medium", "hard"):
        spec = difficulty_spec(difficulty)
        for slot in range(30):
            bp = draw_blueprint(case_seed(5, "train", difficulty, slot), difficulty, cfg)
            assert spec.n_objects[0] <= len(bp.layout.boxes) <= spec.n_objects[1]
            for b in bp.layout.boxes:
                assert min(b.dx, b.dy) * cfg.cell_xy_mm >= cfg.objects.min_side_mm
                assert max(b.dx, b.dy) <= cfg.objects.max_aspect * min(b.dx, b.dy)
                h_mm = b.dz * cfg.cell_z_mm
                assert lo <= h_mm <= hi and h_mm % cfg.objects.height_step_mm == 0


def test_stepped_family_makes_uneven_intermediate_surfaces():
    """Some stepped layer has boxes that start above the layer's floor (a sub-layer)."""
    cfg = CaseConfig(layout="stepped")
    raised = 0
    for slot in range(30):
        bp = draw_blueprint(case_seed(1, "train", "hard", slot), "hard", cfg)
        floors = {}
        for b in bp.layout.boxes:
            floors.setdefault(b.layer_index, set()).add(b.z)
        raised += sum(len(zs) > 1 for zs in floors.values())
    assert raised > 10


def test_guillotine_partition_counts_and_rules():
    rng = np.random.default_rng(0)
    rules = PieceRules(min_side=3, max_aspect=3.0)
    for k in (1, 2, 5, 17, 24):
        pieces = guillotine_partition(Rect(0, 0, 20, 20), k, rules, rng)
        assert pieces is not None and len(pieces) == k
        assert sum(p.area for p in pieces) == 400
        assert all(min(p.dx, p.dy) >= 3 and max(p.dx, p.dy) <= 3 * min(p.dx, p.dy) for p in pieces)
    assert guillotine_partition(Rect(0, 0, 5, 5), 2, rules, rng) is None  # no valid cut exists


def test_partition_problems_catches_broken_layouts():
    good = Layout(
        (4, 4), 2, (LayoutBox(0, 0, 0, 4, 4, 1, 0), LayoutBox(0, 0, 1, 4, 4, 1, 1)), "layered"
    )
    assert partition_problems(good) == []
    overlap = Layout(
        (4, 4), 2, (LayoutBox(0, 0, 0, 4, 4, 2, 0), LayoutBox(0, 0, 1, 4, 4, 1, 1)), "layered"
    )
    assert any("overlap" in p for p in partition_problems(overlap))
    gap = Layout((4, 4), 2, (LayoutBox(0, 0, 0, 4, 4, 1, 0),), "layered")
    assert any("volumes" in p for p in partition_problems(gap))
    outside = Layout((4, 4), 1, (LayoutBox(1, 0, 0, 4, 4, 1, 0),), "layered")
    assert any("sticks out" in p for p in partition_problems(outside))
