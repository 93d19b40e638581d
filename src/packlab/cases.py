"""Read and write case files: one JSON case, a JSONL suite, or the reference benchmark parquet.

Files speak centimetres with the public PackLab reference field names (DESIGN.md section 3);
the library speaks integer millimetres. Every malformed input raises ``CaseFormatError`` naming
file, line, field and value.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from packlab.errors import CaseFormatError
from packlab.types import DEFAULT_CELL_XY_MM, DEFAULT_CELL_Z_MM, Box, Case, Container, PlanStep


class _Reader:
    """Field access for one case record that reports errors with their location."""

    def __init__(self, source: str, line: int | None):
        self.source, self.line = source, line

    def fail(self, field: str, value: object, problem: str) -> CaseFormatError:
        return CaseFormatError(self.source, self.line, field, value, problem)

    def get(self, record: Mapping[str, Any], key: str, field: str) -> Any:
        if not isinstance(record, Mapping):
            raise self.fail(field.rsplit(".", 1)[0] or field, record, "expected an object")
        if key not in record:
            raise self.fail(field, None, "missing required field")
        return record[key]

    def mm(self, value: Any, field: str, *, multiple_of: int = 1, positive: bool = True) -> int:
        """A length in cm -> integer mm, checked to be on the grid."""
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(field, value, "expected a number of centimetres")
        mm_float = float(value) * 10.0
        mm = round(mm_float)
        if abs(mm - mm_float) > 1e-6:
            raise self.fail(field, value, "not a whole number of millimetres")
        if positive and mm <= 0:
            raise self.fail(field, value, "must be positive")
        if not positive and mm < 0:
            raise self.fail(field, value, "must not be negative")
        if mm % multiple_of:
            raise self.fail(field, value, f"not a multiple of the {multiple_of / 10:g} cm grid")
        return mm

    def integer(self, value: Any, field: str, *, minimum: int | None = None) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise self.fail(field, value, "expected an integer")
        if minimum is not None and value < minimum:
            raise self.fail(field, value, f"must be at least {minimum}")
        return value

    def triple(self, record: Mapping[str, Any], key: str, field: str) -> list[Any]:
        value = self.get(record, key, field)
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            raise self.fail(field, value, "expected a list of three numbers")
        return list(value)


def case_from_dict(record: Mapping[str, Any], source: str = "<dict>", line: int | None = None) -> Case:
    """Validate one case record (reference field names, cm) and convert it to a ``Case``."""
    r = _Reader(source, line)
    if not isinstance(record, Mapping):
        raise r.fail("<case>", record, "expected a JSON object")

    cell = record.get("grid_cell_size_cm") or {}
    if not isinstance(cell, Mapping):
        raise r.fail("grid_cell_size_cm", cell, "expected {xy, z}")
    cell_xy = r.mm(cell.get("xy", DEFAULT_CELL_XY_MM / 10), "grid_cell_size_cm.xy")
    cell_z = r.mm(cell.get("z", DEFAULT_CELL_Z_MM / 10), "grid_cell_size_cm.z")

    size = r.triple(record, "container_size_cm", "container_size_cm")
    cx = r.mm(size[0], "container_size_cm[0]", multiple_of=cell_xy)
    cy = r.mm(size[1], "container_size_cm[1]", multiple_of=cell_xy)
    cz = r.mm(size[2], "container_size_cm[2]")
    container = Container((cx, cy, cz), cell_xy, cell_z)

    buffer_size = r.integer(r.get(record, "buffer_size", "buffer_size"), "buffer_size", minimum=1)

    sequence = r.get(record, "object_sequence", "object_sequence")
    if not isinstance(sequence, list) or not sequence:
        raise r.fail("object_sequence", sequence, "expected a non-empty list of objects")
    objects: list[Box] = []
    seen_ids: set[int] = set()
    for i, item in enumerate(sequence):
        f = f"object_sequence[{i}]"
        internal_id = r.integer(r.get(item, "internal_id", f"{f}.internal_id"), f"{f}.internal_id")
        if internal_id in seen_ids:
            raise r.fail(f"{f}.internal_id", internal_id, "duplicate internal_id")
        seen_ids.add(internal_id)
        dims = r.triple(item, "size_cm", f"{f}.size_cm")
        l = r.mm(dims[0], f"{f}.size_cm[0]", multiple_of=cell_xy)
        w = r.mm(dims[1], f"{f}.size_cm[1]", multiple_of=cell_xy)
        h = r.mm(dims[2], f"{f}.size_cm[2]", multiple_of=cell_z)
        fits_flat = (l <= cx and w <= cy) or (w <= cx and l <= cy)
        if not fits_flat or h > cz:
            raise r.fail(f"{f}.size_cm", dims, f"box is larger than the container {list(size)}")
        objects.append(
            Box(
                internal_id=internal_id,
                size_mm=(l, w, h),
                gt_index=r.integer(item.get("gt_index", i), f"{f}.gt_index"),
                type_id=r.integer(item.get("type_id", 0), f"{f}.type_id"),
            )
        )

    plan = record.get("gt_plan")
    gt_plan = None if plan is None else _plan_from_list(plan, r, seen_ids)

    episode_id = record.get("episode_id")
    if episode_id is None:
        episode_id = f"{Path(source).stem}-{line if line is not None else 0}"
    generator = record.get("generator") or {}
    if not isinstance(generator, Mapping):
        generator = {"name": str(generator)}
    return Case(
        episode_id=str(episode_id),
        container=container,
        buffer_size=buffer_size,
        objects=tuple(objects),
        seed=r.integer(record.get("seed", 0), "seed"),
        difficulty=str(record.get("difficulty", "") or ""),
        gt_plan=gt_plan,
        generator=dict(generator),
    )


def _plan_from_list(plan: Any, r: _Reader, ids: set[int]) -> tuple[PlanStep, ...]:
    if not isinstance(plan, list):
        raise r.fail("gt_plan", plan, "expected a list")
    steps = []
    for i, item in enumerate(plan):
        f = f"gt_plan[{i}]"
        internal_id = r.integer(r.get(item, "internal_id", f"{f}.internal_id"), f"{f}.internal_id")
        if internal_id not in ids:
            raise r.fail(f"{f}.internal_id", internal_id, "not in object_sequence")
        cells = r.get(item, "target_box_cells", f"{f}.target_box_cells")
        action = r.get(item, "action", f"{f}.action")
        c = {k: r.integer(r.get(cells, k, f"{f}.target_box_cells.{k}"), f"{f}.target_box_cells.{k}", minimum=0)
             for k in ("x", "y", "z", "dx", "dy", "dz")}
        rotation = r.integer(r.get(action, "rotation", f"{f}.action.rotation"), f"{f}.action.rotation")
        if rotation not in (0, 1):
            raise r.fail(f"{f}.action.rotation", rotation, "must be 0 or 1")
        steps.append(
            PlanStep(
                internal_id=internal_id,
                gt_index=r.integer(item.get("gt_index", i), f"{f}.gt_index"),
                layer_index=r.integer(item.get("layer_index", 0), f"{f}.layer_index"),
                cell_min=(c["x"], c["y"], c["z"]),
                cell_size=(c["dx"], c["dy"], c["dz"]),
                x=r.integer(r.get(action, "x", f"{f}.action.x"), f"{f}.action.x", minimum=0),
                y=r.integer(r.get(action, "y", f"{f}.action.y"), f"{f}.action.y", minimum=0),
                rotation=rotation,
            )
        )
    return tuple(steps)


def _cm(mm: int) -> float | int:
    """mm -> cm, written as an int when whole so files stay tidy."""
    cm = mm / 10.0
    return int(cm) if cm.is_integer() else cm


def case_to_dict(case: Case) -> dict[str, Any]:
    """The reference-format record (cm) of a case; ``case_from_dict`` inverts it."""
    c = case.container
    record: dict[str, Any] = {
        "episode_id": case.episode_id,
        "difficulty": case.difficulty,
        "seed": case.seed,
        "container_size_cm": [_cm(v) for v in c.size_mm],
        "grid_cell_size_cm": {"xy": _cm(c.cell_xy_mm), "z": _cm(c.cell_z_mm)},
        "buffer_size": case.buffer_size,
        "object_sequence": [
            {"internal_id": b.internal_id, "gt_index": b.gt_index, "type_id": b.type_id,
             "size_cm": [_cm(v) for v in b.size_mm]}
            for b in case.objects
        ],
    }
    if case.gt_plan is not None:
        record["gt_plan"] = [
            {
                "internal_id": p.internal_id,
                "gt_index": p.gt_index,
                "layer_index": p.layer_index,
                "target_box_cells": dict(zip(("x", "y", "z", "dx", "dy", "dz"), p.cell_min + p.cell_size)),
                "action": {"x": p.x, "y": p.y, "rotation": p.rotation},
            }
            for p in case.gt_plan
        ]
    if case.generator:
        record["generator"] = case.generator
    return record


def _records_from_parquet(path: Path) -> Iterable[tuple[int, Any]]:
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    if "extra_info" not in table.column_names:
        raise CaseFormatError(str(path), None, "extra_info", None, "parquet has no 'extra_info' column")
    for row, extra in enumerate(table.column("extra_info").to_pylist(), start=1):
        if isinstance(extra, str):
            extra = json.loads(extra)
        kwargs = (extra or {}).get("interaction_kwargs")
        if isinstance(kwargs, str):
            kwargs = json.loads(kwargs)
        if kwargs is None:
            raise CaseFormatError(str(path), row, "extra_info.interaction_kwargs", None, "missing")
        yield row, kwargs


def load_cases(path: str | os.PathLike[str]) -> list[Case]:
    """Load a JSON case (or list of cases), a JSONL suite or a reference parquet file."""
    path = Path(path)
    source = str(path)
    if not path.exists():
        raise FileNotFoundError(f"{source}: no such case file")
    if path.suffix == ".parquet":
        cases = [case_from_dict(rec, source, row) for row, rec in _records_from_parquet(path)]
    elif path.suffix == ".jsonl":
        cases = []
        with path.open(encoding="utf-8") as fh:
            for lineno, text in enumerate(fh, start=1):
                if not text.strip():
                    continue
                try:
                    record = json.loads(text)
                except json.JSONDecodeError as exc:
                    raise CaseFormatError(source, lineno, "<json>", text.strip()[:60], f"bad JSON line ({exc.msg})") from None
                cases.append(case_from_dict(record, source, lineno))
    else:
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise CaseFormatError(source, exc.lineno, "<json>", exc.doc[exc.pos : exc.pos + 30], f"bad JSON ({exc.msg})") from None
        records = data if isinstance(data, list) else [data]
        cases = [case_from_dict(rec, source, None if len(records) == 1 else i + 1) for i, rec in enumerate(records)]
    ids = [c.episode_id for c in cases]
    if len(set(ids)) != len(ids):
        dup = next(i for i in ids if ids.count(i) > 1)
        raise CaseFormatError(source, None, "episode_id", dup, "episode_id is not unique in the suite")
    return cases


def save_cases(cases: Iterable[Case], path: str | os.PathLike[str]) -> Path:
    """Write cases as JSONL atomically (a temp file renamed into place: no half-written suite)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            for case in cases:
                fh.write(json.dumps(case_to_dict(case), separators=(",", ":")) + "\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
