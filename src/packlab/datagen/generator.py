"""Case seed -> Case: scenario, layout, presentation and placement order put together.

``build_case`` is pure: the same (seed, difficulty, config) always gives the same case.
Cases of the ``random`` and ``rs`` families (``packlab.datagen.random_family``, ``rs_family``)
have no layout and no plan: ``build_case`` makes them with ``random_case`` / ``rs_case``;
``draw_blueprint`` is for the layout families (``layered``, ``stepped``, ``cut``).
``generate_cases`` is the public entry point for frozen suites (the bench) and shares every line
of case making with the dataset engine, so suites and datasets come from one generator.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from packlab.core.choices import DEFAULT_SIDES, SideNames
from packlab.core.errors import ConfigError, PacklabError
from packlab.core.types import Box, Case, PlanStep
from packlab.datagen.config import (
    GENERATOR_NAME,
    GENERATOR_VERSION,
    NO_LAYOUT_FAMILIES,
    CaseConfig,
    ValidationConfig,
    difficulty_spec,
)
from packlab.datagen.cut_family import CutDraw, build_cut_layout
from packlab.datagen.cut_order import base_height_order, support_order
from packlab.datagen.layout import Layout, build_layout
from packlab.datagen.random_family import draw_random_boxes
from packlab.datagen.removal import PlacementOrder, layer_order, reverse_removal
from packlab.datagen.rs_family import TYPES, draw_rs_boxes
from packlab.datagen.scenario import Scenario, sample_scenario
from packlab.datagen.seeds import case_seed, case_streams, domain_tag
from packlab.datagen.seeds import id_prefix as seed_id_prefix
from packlab.datagen.validate import Trajectory, check_case


@dataclass(frozen=True, slots=True)
class Blueprint:
    """Everything drawn for one case, kept for checks and statistics."""

    scenario: Scenario
    layout: Layout
    order: PlacementOrder
    rotated: tuple[bool, ...]  # per layout box: presented at rotation 1
    type_ids: tuple[int, ...]  # per layout box
    cut: CutDraw | None = None  # the cut family's draw (side range), None for other families
    #: Off-grid sizes: per layout box (off x extent, off y extent, off height) mm of its slot,
    #: in the layout's frame; None: every box fills its slot (grid sizes).
    clearance: tuple[tuple[int, int, int], ...] | None = None


def draw_blueprint(seed: int, difficulty: str, cfg: CaseConfig) -> Blueprint:
    """The random draws of one case, each stage from its own stream of the case seed."""
    spec = difficulty_spec(difficulty)
    if cfg.layout in NO_LAYOUT_FAMILIES:
        raise ConfigError(f"layout = {cfg.layout!r} has no blueprint (no layout); use build_case")
    scenario_rng, layout_rng, present_rng, order_rng = case_streams(seed, 4)
    scenario = sample_scenario(spec, cfg, scenario_rng)
    cut = build_cut_layout(scenario, spec, cfg, layout_rng) if cfg.layout == "cut" else None
    layout = cut.layout if cut is not None else build_layout(scenario, cfg, layout_rng)
    n = len(layout.boxes)
    rotated = tuple(bool(r) for r in present_rng.random(n) < cfg.objects.rotated_fraction)
    type_ids = tuple(int(t) for t in present_rng.integers(cfg.n_types, size=n))
    order = _draw_order(layout, cfg, order_rng)
    clearance = _draw_clearance(seed, n, cfg) if cfg.sizes == "off-grid" else None
    return Blueprint(scenario, layout, order, rotated, type_ids, cut, clearance)


def _draw_clearance(seed: int, n: int, cfg: CaseConfig) -> tuple[tuple[int, int, int], ...]:
    """Per layout box, how much smaller than its slot an off-grid box is: (x, y, z) mm, each
    uniform in ``cfg.clearance``'s inclusive range, from the case seed's fifth stream (the four
    stages' streams and draws stay those of the grid case: same layout, order and colours)."""
    rng = case_streams(seed, 5)[4]
    (xy_lo, xy_hi), (z_lo, z_hi) = cfg.clearance.xy_mm, cfg.clearance.z_mm
    xy = rng.integers(xy_lo, xy_hi + 1, size=(n, 2))
    z = rng.integers(z_lo, z_hi + 1, size=n)
    return tuple((int(a), int(b), int(c)) for (a, b), c in zip(xy, z))


def _draw_order(layout: Layout, cfg: CaseConfig, rng: np.random.Generator) -> PlacementOrder:
    """The arrival order ``cfg.order`` of a layout (the config refuses unsuited pairs)."""
    if cfg.order == "layers":
        return layer_order(layout, cfg.anchor, rng)
    if cfg.order == "base-height":
        return base_height_order(layout, rng)
    if cfg.order == "support":
        return support_order(layout, rng)
    return reverse_removal(layout, cfg.anchor, rng)


def _family_fields(bp: Blueprint) -> dict[str, Any]:
    """``Case.generator`` fields of the layout's shape: the scenario's layers for the layered
    families (their bytes unchanged), the base heights and side range of a cut."""
    if bp.cut is None:
        return {
            "n_layers": len(bp.scenario.layer_heights_mm),
            "stack_height_cm": _cm(bp.scenario.stack_height_mm),
            "layer_heights_cm": [_cm(h) for h in bp.scenario.layer_heights_mm],
        }
    c = bp.scenario.container
    units = (c.cell_xy_mm, c.cell_xy_mm, c.cell_z_mm)
    return {
        "n_bases": len({b.z for b in bp.layout.boxes}),
        "stack_height_cm": _cm(bp.scenario.stack_height_mm),
        "side_min_cm": [_cm(v * u) for v, u in zip(bp.cut.sides.lo, units)],
        "side_max_cm": [_cm(v * u) for v, u in zip(bp.cut.sides.hi, units)],
        "target_objects": bp.scenario.n_objects,
    }


def _clearance_fields(bp: Blueprint) -> dict[str, Any]:
    """``Case.generator`` fields of an off-grid case: ``sizes`` and ``fill``, the boxes' volume
    over their slots' (the layout's), the Compactness of the plan packed at its slots' heights.
    Each box's own clearance is its plan step's cells minus its size."""
    assert bp.clearance is not None
    c = bp.scenario.container
    slots = boxes = 0
    for b, off in zip(bp.layout.boxes, bp.clearance):
        fx, fy, h = b.dx * c.cell_xy_mm, b.dy * c.cell_xy_mm, b.dz * c.cell_z_mm
        slots += fx * fy * h
        boxes += (fx - off[0]) * (fy - off[1]) * (h - off[2])
    return {"sizes": "off-grid", "fill": round(boxes / slots, 6)}


def _cm(mm: int) -> float | int:
    cm = mm / 10
    return int(cm) if cm.is_integer() else cm


def case_from_blueprint(
    bp: Blueprint,
    seed: int,
    difficulty: str,
    episode_id: str,
    provenance: dict[str, Any] | None = None,
) -> Case:
    """The case of a blueprint: arrival order = placement order, and the plan that replays it.

    ``internal_id`` is the object's index in the layout and ``gt_index`` its position in the
    plan. A rotated object's own size is (w, l, h) of its footprint, so rotation 1 puts it back
    where the layout has it (``Box.footprint_mm(1)`` swaps l and w).
    """
    spec = difficulty_spec(difficulty)
    c = bp.scenario.container
    objects, plan = [], []
    for gt_index, i in enumerate(bp.order.order):
        b = bp.layout.boxes[i]
        rotation = int(bp.rotated[i])
        fx, fy, h = b.dx * c.cell_xy_mm, b.dy * c.cell_xy_mm, b.dz * c.cell_z_mm
        if bp.clearance is not None:  # off-grid: smaller than its slot, which the plan names
            off = bp.clearance[i]
            fx, fy, h = fx - off[0], fy - off[1], h - off[2]
        size = (fy, fx, h) if rotation else (fx, fy, h)
        objects.append(Box(internal_id=i, size_mm=size, gt_index=gt_index, type_id=bp.type_ids[i]))
        plan.append(
            PlanStep(
                internal_id=i,
                gt_index=gt_index,
                layer_index=b.layer_index,
                cell_min=(b.x, b.y, b.z),
                cell_size=(b.dx, b.dy, b.dz),
                x=b.x,
                y=b.y,
                rotation=rotation,
            )
        )
    first = bp.layout.boxes[bp.order.order[0]]
    generator = {
        "name": GENERATOR_NAME,
        "version": GENERATOR_VERSION,
        "layout": bp.layout.family,
        # Recorded when not the default, so removal cases keep the bytes they always had.
        **({"order": bp.order.rule} if bp.order.rule != "removal" else {}),
        "anchor": bp.order.anchor,
        "first_cell": [first.x, first.y],
        **_family_fields(bp),
        "base_size_cm": [_cm(v) for v in bp.scenario.base_size_mm],
        **(_clearance_fields(bp) if bp.clearance is not None else {}),
        **(provenance or {}),
    }
    return Case(
        episode_id=episode_id,
        container=c,
        buffer_size=spec.buffer_size,
        objects=tuple(objects),
        seed=seed,
        difficulty=difficulty,
        gt_plan=tuple(plan),
        generator=generator,
    )


def random_case(
    seed: int,
    difficulty: str,
    cfg: CaseConfig,
    episode_id: str,
    provenance: dict[str, Any] | None = None,
) -> Case:
    """A case of the ``random`` family: drawn boxes in draw order, no ``gt_plan``.

    The streams are those of a blueprint (scenario, boxes in place of the layout, presentation;
    the order stream is unused: arrival is the draw order). ``internal_id`` and ``gt_index`` are
    the draw index.
    """
    spec = difficulty_spec(difficulty)
    scenario_rng, boxes_rng, present_rng, _ = case_streams(seed, 4)
    scenario = sample_scenario(spec, cfg, scenario_rng)
    draw = draw_random_boxes(scenario, spec, cfg, boxes_rng)
    objects = _drawn_objects(draw.sizes_mm, cfg, present_rng)
    generator = {
        "name": GENERATOR_NAME,
        "version": GENERATOR_VERSION,
        "layout": "random",
        "order": "draw",
        "target_height_cm": _cm(scenario.stack_height_mm),
        "target_fill": round(draw.target_mm3 / scenario.container.volume_mm3, 6),
        "base_size_cm": [_cm(v) for v in scenario.base_size_mm],
        **(provenance or {}),
    }
    return Case(
        episode_id=episode_id,
        container=scenario.container,
        buffer_size=spec.buffer_size,
        objects=objects,
        seed=seed,
        difficulty=difficulty,
        gt_plan=None,
        generator=generator,
    )


def rs_case(
    seed: int,
    difficulty: str,
    cfg: CaseConfig,
    episode_id: str,
    provenance: dict[str, Any] | None = None,
) -> Case:
    """A case of the ``rs`` family: i.i.d. boxes of the 64 types in draw order, no ``gt_plan``.

    The streams are those of ``random_case`` (scenario for the container, boxes, presentation;
    the order stream is unused). ``internal_id`` and ``gt_index`` are the draw index.
    """
    spec = difficulty_spec(difficulty)
    scenario_rng, boxes_rng, present_rng, _ = case_streams(seed, 4)
    scenario = sample_scenario(spec, cfg, scenario_rng)
    c = scenario.container
    draw = draw_rs_boxes(c, cfg.objects.height_step_mm, boxes_rng)
    objects = _drawn_objects(draw.sizes_mm, cfg, present_rng)
    drawn = sum(l * w * h for l, w, h in draw.sizes_mm)
    generator = {
        "name": GENERATOR_NAME,
        "version": GENERATOR_VERSION,
        "layout": "rs",
        "order": "draw",
        "unit_cm": _cm(draw.unit_mm),
        "types": [list(TYPES[k]) for k in draw.type_index],
        "drawn_fill": round(drawn / c.volume_mm3, 6),
        "base_size_cm": [_cm(v) for v in scenario.base_size_mm],
        **(provenance or {}),
    }
    return Case(
        episode_id=episode_id,
        container=c,
        buffer_size=spec.buffer_size,
        objects=objects,
        seed=seed,
        difficulty=difficulty,
        gt_plan=None,
        generator=generator,
    )


def _drawn_objects(
    sizes_mm: Sequence[tuple[int, int, int]], cfg: CaseConfig, present_rng: np.random.Generator
) -> tuple[Box, ...]:
    """Boxes in draw order (``internal_id`` and ``gt_index``: the draw index), coloured from the
    case's presentation stream: the families with no layout (random, rs)."""
    type_ids = present_rng.integers(cfg.n_types, size=len(sizes_mm))
    return tuple(
        Box(internal_id=i, size_mm=size, gt_index=i, type_id=int(t))
        for i, (size, t) in enumerate(zip(sizes_mm, type_ids))
    )


def build_case(
    seed: int,
    difficulty: str,
    cfg: CaseConfig | None = None,
    episode_id: str | None = None,
    provenance: dict[str, Any] | None = None,
) -> Case:
    """The case of a case seed (pure and deterministic)."""
    cfg = cfg or CaseConfig()
    episode_id = episode_id or f"{difficulty}-{seed}"
    if cfg.layout == "random":
        return random_case(seed, difficulty, cfg, episode_id, provenance)
    if cfg.layout == "rs":
        return rs_case(seed, difficulty, cfg, episode_id, provenance)
    bp = draw_blueprint(seed, difficulty, cfg)
    return case_from_blueprint(bp, seed, difficulty, episode_id, provenance)


def slot_case(
    user_seed: int,
    domain: str,
    difficulty: str,
    slot: int,
    attempt: int,
    cfg: CaseConfig,
    id_prefix: str,
) -> Case:
    """The case tried for one slot of a suite or dataset at one attempt."""
    seed = case_seed(user_seed, domain, difficulty, slot, attempt)
    provenance = {
        "domain": domain,
        "user_seed": int(user_seed),
        "slot": int(slot),
        "attempt": int(attempt),
    }
    return build_case(seed, difficulty, cfg, f"{id_prefix}{difficulty}-{slot:05d}", provenance)


@dataclass(frozen=True, slots=True)
class SlotOutcome:
    """The first accepted attempt of a slot (``case`` None when all failed) and the rejections."""

    case: Case | None
    trajectory: Trajectory | None  # the accepted replay; None without replay
    rejected: tuple[str, ...]  # reasons of the rejected attempts, in order


def fill_slot(
    user_seed: int,
    domain: str,
    difficulty: str,
    slot: int,
    cfg: CaseConfig,
    validation: ValidationConfig,
    id_prefix: str,
    replay_plan: bool = True,
    sides: SideNames = DEFAULT_SIDES,
) -> SlotOutcome:
    """Try attempts 0, 1, ... of a slot until a case passes validation (or attempts run out).

    A ``random`` or ``rs`` case has no plan to check or replay: attempt 0 is taken as it is. The
    accepted replay's observations name sides as ``sides`` says.
    """
    if cfg.layout in NO_LAYOUT_FAMILIES:
        case = slot_case(user_seed, domain, difficulty, slot, 0, cfg, id_prefix)
        return SlotOutcome(case, None, ())
    rejected: list[str] = []
    for attempt in range(validation.max_attempts):
        case = slot_case(user_seed, domain, difficulty, slot, attempt, cfg, id_prefix)
        verdict = check_case(case, validation, replay_plan=replay_plan, sides=sides)
        if verdict.accepted:
            return SlotOutcome(case, verdict.trajectory, tuple(rejected))
        rejected.append(verdict.reason)
    return SlotOutcome(None, None, tuple(rejected))


def generate_cases(
    difficulty: str,
    n: int,
    seed: int,
    validate: bool = True,
    *,
    config: CaseConfig | None = None,
    validation: ValidationConfig | None = None,
    domain: str = "bench",
    start: int = 0,
    id_prefix: str | None = None,
) -> list[Case]:
    """``n`` cases of one difficulty, deterministic for ``seed``; the bench's suite maker.

    Slot ``i`` (``start <= i < start + n``) takes the first attempt whose case passes the plan
    checks and, with ``validate``, the replay validation (mujoco by default, see
    ``ValidationConfig``). ``domain`` picks the seed space (see ``packlab.datagen.seeds``): the
    bench's default keeps suites disjoint from training data. Episode ids are
    ``{id_prefix}{difficulty}-{slot:05d}`` with ``id_prefix`` defaulting to
    ``seeds.id_prefix(domain, seed)`` (``train-s4402-``; ``bench-`` for the frozen suites).
    """
    difficulty_spec(difficulty)
    domain_tag(domain)
    if n < 0 or start < 0:
        raise ConfigError(f"n = {n}, start = {start}: must not be negative")
    cfg = config or CaseConfig()
    val = validation or ValidationConfig()
    prefix = seed_id_prefix(domain, seed) if id_prefix is None else id_prefix
    cases = []
    for slot in range(start, start + n):
        outcome = fill_slot(seed, domain, difficulty, slot, cfg, val, prefix, replay_plan=validate)
        if outcome.case is None:
            raise PacklabError(
                f"{difficulty} slot {slot}: no valid case in {val.max_attempts} attempts "
                f"({', '.join(outcome.rejected)})"
            )
        cases.append(outcome.case)
    return cases


__all__ = [
    "Blueprint",
    "SlotOutcome",
    "build_case",
    "case_from_blueprint",
    "draw_blueprint",
    "fill_slot",
    "generate_cases",
    "random_case",
    "rs_case",
    "slot_case",
]
