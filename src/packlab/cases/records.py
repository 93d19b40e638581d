"""One record -> ``Case``: packlab's own record, or a reference benchmark row flattened to one.

A reference row keeps the case in ``extra_info`` (a mapping, or its JSON text in parquet) and
``extra_info.interaction_kwargs``; it is flattened to packlab's record with a note of where each
field sat, so errors name the field as it is written in the file.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from packlab.cases.contents import objects_from_record, plan_from_list
from packlab.cases.limits import (
    MAX_BUFFER_SIZE,
    MAX_CASE_ID_CHARS,
    MAX_CONTAINER_SIDE_CM,
    MAX_HEIGHTMAP_CELLS,
    MAX_ID_CHARS,
)
from packlab.cases.reader import Reader, shorten
from packlab.core.errors import CaseFormatError
from packlab.core.types import DEFAULT_CELL_XY_MM, DEFAULT_CELL_Z_MM, Case, CaseOrigin, Container

#: Fields of a reference row that sit in ``extra_info`` beside ``interaction_kwargs``.
_EXTRA_CASE_FIELDS = ("difficulty", "generator", "gt_plan")


def case_from_dict(
    record: Mapping[str, Any],
    source: str = "<dict>",
    line: int | None = None,
    *,
    default_id: str | None = None,
    default_difficulty: str = "",
) -> Case:
    """Validate one case record and convert it to a ``Case``.

    ``record`` is packlab's own record or a reference benchmark row (recognised by its
    ``extra_info``). Without an id in the record the case is called ``default_id`` (by default
    ``<file stem>-<line>``).
    """
    if not isinstance(record, Mapping):
        raise CaseFormatError(source, line, "<case>", shorten(record), "expected a JSON object")
    if default_id is None:
        default_id = f"{Path(source).stem}-{line if line is not None else 0}"
    flat: Mapping[str, Any]
    if "extra_info" in record:
        flat, aliases, origin = _flatten_reference_row(record, source, line)
        r = Reader(source, line, aliases)
    else:
        flat, origin, r = record, None, Reader(source, line)
    return _case_from_record(flat, r, default_id, default_difficulty, origin)


# -- the reference's row -> packlab's record ---------------------------------------------------


def _json_object(value: Any, field: str, r: Reader) -> Mapping[str, Any]:
    """A mapping, or the JSON text of one (parquet files may hold either)."""
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except (ValueError, RecursionError) as exc:
            problem = exc.msg if isinstance(exc, json.JSONDecodeError) else type(exc).__name__
            raise r.fail(field, value, f"a string that is not JSON ({problem})") from None
    if not isinstance(value, Mapping):
        raise r.fail(field, value, "expected an object (or the JSON text of one)")
    return value


def _flatten_reference_row(
    row: Mapping[str, Any], source: str, line: int | None
) -> tuple[dict[str, Any], dict[str, str], CaseOrigin | None]:
    """A reference row -> (packlab record, where each field sits in the row, its origin)."""
    r = Reader(source, line)
    extra = _json_object(row["extra_info"], "extra_info", r)
    kwargs = _json_object(
        r.get(extra, "interaction_kwargs", "extra_info.interaction_kwargs"),
        "extra_info.interaction_kwargs",
        r,
    )
    record = dict(kwargs)
    aliases = {key: f"extra_info.interaction_kwargs.{key}" for key in kwargs}
    if kwargs.get("sample_id") is not None:
        sample_id = kwargs["sample_id"]
        if kwargs.get("episode_id") is not None and kwargs["episode_id"] != sample_id:
            raise r.fail(
                "extra_info.interaction_kwargs.episode_id",
                kwargs["episode_id"],
                f"differs from sample_id {sample_id!r}",
            )
        record["episode_id"] = sample_id
        aliases["episode_id"] = "extra_info.interaction_kwargs.sample_id"
    for key in _EXTRA_CASE_FIELDS:
        if extra.get(key) is None:
            continue
        if kwargs.get(key) is not None and kwargs[key] != extra[key]:
            raise r.fail(
                f"extra_info.{key}", extra[key], f"differs from extra_info.interaction_kwargs.{key}"
            )
        record[key] = extra[key]
        aliases[key] = f"extra_info.{key}"
    return record, aliases, _origin(extra, r)


def _origin(extra: Mapping[str, Any], r: Reader) -> CaseOrigin | None:
    """Where a reference row sat: its ``split`` and ``index``, if it names either."""
    split = extra.get("split")
    if split is not None and not isinstance(split, str):
        raise r.fail("extra_info.split", split, "expected a string")
    index = extra.get("index")
    if index is not None:
        index = r.integer(index, "extra_info.index")
    return None if split is None and index is None else CaseOrigin(split, index)


# -- packlab's record -> Case ------------------------------------------------------------------


def _case_from_record(
    record: Mapping[str, Any],
    r: Reader,
    default_id: str,
    default_difficulty: str,
    origin: CaseOrigin | None,
) -> Case:
    container = _container(record, r)
    buffer_size = r.integer(r.get(record, "buffer_size", "buffer_size"), "buffer_size", minimum=1)
    if buffer_size > MAX_BUFFER_SIZE:
        raise r.fail(
            "buffer_size",
            buffer_size,
            f"larger than the limit of {MAX_BUFFER_SIZE} (packlab.cases.MAX_BUFFER_SIZE)",
        )
    objects = objects_from_record(record, r, container)
    ids = {b.internal_id for b in objects}
    plan = record.get("gt_plan")
    gt_plan = None if plan is None else plan_from_list(plan, r, ids, container)
    return Case(
        episode_id=_case_id(record.get("episode_id"), r, default_id),
        container=container,
        buffer_size=buffer_size,
        objects=objects,
        seed=r.integer(record.get("seed", 0), "seed"),
        difficulty=_difficulty(record.get("difficulty"), r, default_difficulty),
        gt_plan=gt_plan,
        generator=_generator(record.get("generator"), r),
        origin=origin,
    )


def _container(record: Mapping[str, Any], r: Reader) -> Container:
    cell = record.get("grid_cell_size_cm") or {}
    if not isinstance(cell, Mapping):
        raise r.fail("grid_cell_size_cm", cell, "expected {xy, z}")
    side_mm = MAX_CONTAINER_SIDE_CM * 10
    cell_xy = r.mm(cell.get("xy", DEFAULT_CELL_XY_MM / 10), "grid_cell_size_cm.xy", max_mm=side_mm)
    cell_z = r.mm(cell.get("z", DEFAULT_CELL_Z_MM / 10), "grid_cell_size_cm.z", max_mm=side_mm)
    size = r.triple(record, "container_size_cm", "container_size_cm")
    cx = r.mm(size[0], "container_size_cm[0]", multiple_of=cell_xy, max_mm=side_mm)
    cy = r.mm(size[1], "container_size_cm[1]", multiple_of=cell_xy, max_mm=side_mm)
    cz = r.mm(size[2], "container_size_cm[2]", max_mm=side_mm)
    if (cx // cell_xy) * (cy // cell_xy) > MAX_HEIGHTMAP_CELLS:
        raise r.fail(
            "container_size_cm",
            size,
            f"{cx // cell_xy} x {cy // cell_xy} cells of {cell_xy / 10:g} cm is more "
            f"than the limit of {MAX_HEIGHTMAP_CELLS} heightmap cells "
            "(packlab.cases.MAX_HEIGHTMAP_CELLS)",
        )
    return Container((cx, cy, cz), cell_xy, cell_z)


def _case_id(value: Any, r: Reader, default_id: str) -> str:
    if value is None:
        return default_id
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise r.fail("episode_id", value, "expected a string")
    text = r.text(str(value), "episode_id", MAX_CASE_ID_CHARS)
    if not text or not text.isprintable():
        raise r.fail("episode_id", value, "expected a non-empty printable string")
    return text


def _difficulty(value: Any, r: Reader, default: str) -> str:
    if value is None or value == "":
        return default
    text = r.text(value, "difficulty", MAX_ID_CHARS)
    if not text.isprintable():
        raise r.fail("difficulty", value, "expected a printable string")
    return text


def _generator(value: Any, r: Reader) -> dict[str, Any]:
    """Provenance: a mapping, or a name (the reference writes ``"layer_cuboid_v1_..."``).

    A name is kept as ``{"name": NAME}``; a string holding a JSON object is that mapping (the
    reference-layout exporter writes packlab's generator mappings so, see
    ``packlab.cases.serialize.generator_text``).
    """
    if value is None or value == "":
        return {}
    if isinstance(value, str):
        if value.startswith("{"):
            try:
                decoded = json.loads(value)
            except (ValueError, RecursionError):
                decoded = None
            if isinstance(decoded, dict):
                return decoded
        return {"name": value}
    if isinstance(value, Mapping):
        return dict(value)
    raise r.fail("generator", value, "expected a string or an object")


__all__ = ["case_from_dict"]
