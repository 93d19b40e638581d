"""What a case holds: ``object_sequence`` -> ``Box``es, ``gt_plan`` -> ``PlanStep``s.

Object ids (``internal_id``) are kept exactly as given, integers or strings, and must all be of
one type within a case; every box must fit the container lying flat, and every plan step must
name a listed object once and stay inside the container's cells.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from packlab.cases.limits import INT32_BOUND, MAX_CONTAINER_SIDE_CM, MAX_ID_CHARS, MAX_OBJECTS
from packlab.cases.reader import Cut, Reader, cm
from packlab.core.types import Box, Container, InternalId, PlanStep

_CELL_KEYS = ("x", "y", "z", "dx", "dy", "dz")


def internal_id(value: Any, field: str, r: Reader) -> InternalId:
    """An object id as given: an integer (a float with no fraction counts) or a short string."""
    if isinstance(value, str):
        if not value or not value.isprintable():
            raise r.fail(field, value, "expected a non-empty printable string or an integer")
        return r.text(value, field, MAX_ID_CHARS)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise r.fail(field, value, "expected an integer or a string")
    return r.integer(value, field)


def objects_from_record(
    record: Mapping[str, Any], r: Reader, container: Container
) -> tuple[Box, ...]:
    """The record's ``object_sequence``: ids unique and of one type, every box fits."""
    sequence = r.get(record, "object_sequence", "object_sequence")
    if not isinstance(sequence, list) or not sequence:
        raise r.fail("object_sequence", sequence, "expected a non-empty list of objects")
    if len(sequence) > MAX_OBJECTS:
        raise r.fail(
            "object_sequence",
            Cut(f"<{len(sequence)} objects>"),
            f"more than the limit of {MAX_OBJECTS} objects (packlab.cases.MAX_OBJECTS)",
        )
    objects: list[Box] = []
    seen: set[InternalId] = set()
    for i, item in enumerate(sequence):
        f = f"object_sequence[{i}]"
        box_id = internal_id(r.get(item, "internal_id", f"{f}.internal_id"), f"{f}.internal_id", r)
        if objects and type(box_id) is not type(objects[0].internal_id):
            first = objects[0].internal_id
            raise r.fail(
                f"{f}.internal_id",
                box_id,
                f"ids of one case must all be integers or all strings (the first is {first!r})",
            )
        if box_id in seen:
            raise r.fail(f"{f}.internal_id", box_id, "duplicate internal_id")
        seen.add(box_id)
        objects.append(
            Box(
                internal_id=box_id,
                size_mm=_box_size(item, f, r, container),
                gt_index=r.integer(item.get("gt_index", i), f"{f}.gt_index", bound=INT32_BOUND),
                type_id=r.integer(
                    item.get("type_id", 0), f"{f}.type_id", minimum=0, bound=INT32_BOUND
                ),
            )
        )
    return tuple(objects)


def _box_size(
    item: Mapping[str, Any], f: str, r: Reader, container: Container
) -> tuple[int, int, int]:
    """One object's ``size_cm`` in mm: whole millimetres (on the grid or off it: a box off the
    grid covers every cell it touches), fitting the container lying flat."""
    dims = r.triple(item, "size_cm", f"{f}.size_cm")
    side_mm = MAX_CONTAINER_SIDE_CM * 10
    length = r.mm(dims[0], f"{f}.size_cm[0]", max_mm=side_mm)
    width = r.mm(dims[1], f"{f}.size_cm[1]", max_mm=side_mm)
    height = r.mm(dims[2], f"{f}.size_cm[2]", max_mm=side_mm)
    cx, cy, cz = container.size_mm
    fits_flat = (length <= cx and width <= cy) or (width <= cx and length <= cy)
    if not fits_flat or height > cz:
        sides = [cm(v) for v in container.size_mm]
        raise r.fail(f"{f}.size_cm", dims, f"box is larger than the container {sides}")
    return (length, width, height)


def plan_from_list(
    plan: Any, r: Reader, ids: set[InternalId], container: Container
) -> tuple[PlanStep, ...]:
    """The record's ``gt_plan``: each listed object at most once, every step inside."""
    if not isinstance(plan, list):
        raise r.fail("gt_plan", plan, "expected a list")
    if len(plan) > len(ids):
        raise r.fail(
            "gt_plan", Cut(f"<{len(plan)} steps>"), f"more steps than the {len(ids)} objects"
        )
    steps: list[PlanStep] = []
    planned: set[InternalId] = set()
    for i, item in enumerate(plan):
        f = f"gt_plan[{i}]"
        step_id = internal_id(r.get(item, "internal_id", f"{f}.internal_id"), f"{f}.internal_id", r)
        if step_id not in ids:
            raise r.fail(f"{f}.internal_id", step_id, "not in object_sequence")
        if step_id in planned:
            raise r.fail(f"{f}.internal_id", step_id, "planned twice")
        planned.add(step_id)
        steps.append(_plan_step(item, i, step_id, r, container))
    return tuple(steps)


def _plan_step(
    item: Mapping[str, Any], i: int, step_id: InternalId, r: Reader, container: Container
) -> PlanStep:
    """Step ``i`` of a plan: its target cells and its action, both inside the container."""
    f = f"gt_plan[{i}]"
    x_cells, y_cells = container.cells
    z_cells = container.height_mm // container.cell_z_mm
    cells = r.get(item, "target_box_cells", f"{f}.target_box_cells")
    action = r.get(item, "action", f"{f}.action")
    c = {
        k: r.integer(
            r.get(cells, k, f"{f}.target_box_cells.{k}"), f"{f}.target_box_cells.{k}", minimum=0
        )
        for k in _CELL_KEYS
    }
    if c["x"] + c["dx"] > x_cells or c["y"] + c["dy"] > y_cells or c["z"] + c["dz"] > z_cells:
        raise r.fail(
            f"{f}.target_box_cells",
            dict(cells),
            f"outside the container's {x_cells} x {y_cells} x {z_cells} cells",
        )
    rotation = r.integer(r.get(action, "rotation", f"{f}.action.rotation"), f"{f}.action.rotation")
    if rotation not in (0, 1):
        raise r.fail(f"{f}.action.rotation", rotation, "must be 0 or 1")
    x = r.integer(r.get(action, "x", f"{f}.action.x"), f"{f}.action.x", minimum=0)
    y = r.integer(r.get(action, "y", f"{f}.action.y"), f"{f}.action.y", minimum=0)
    if x >= x_cells or y >= y_cells:
        raise r.fail(
            f"{f}.action", dict(action), f"outside the container's {x_cells} x {y_cells} cells"
        )
    return PlanStep(
        internal_id=step_id,
        gt_index=r.integer(item.get("gt_index", i), f"{f}.gt_index", bound=INT32_BOUND),
        layer_index=r.integer(item.get("layer_index", 0), f"{f}.layer_index", bound=INT32_BOUND),
        cell_min=(c["x"], c["y"], c["z"]),
        cell_size=(c["dx"], c["dy"], c["dz"]),
        x=x,
        y=y,
        rotation=rotation,
    )


__all__ = ["internal_id", "objects_from_record", "plan_from_list"]
