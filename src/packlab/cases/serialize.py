"""``Case`` -> records: packlab's own record, the reference's benchmark row, and the checksum.

``case_from_dict`` reads every record written here back to the same case. Nothing here
touches a file: the writers in ``packlab.cases.write`` put these records on disk.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Iterator, Mapping
from typing import Any

from packlab.cases.layout import REFERENCE_ROW_HEAD, REFERENCE_SPLIT
from packlab.cases.reader import cm
from packlab.core.errors import ConfigError
from packlab.core.types import DEFAULT_CELL_XY_MM, DEFAULT_CELL_Z_MM, Case, PlanStep

#: The keys of a plan step's ``target_box_cells``: its lowest cell, then its size in cells.
_CELL_KEYS = ("x", "y", "z", "dx", "dy", "dz")


def case_to_dict(case: Case) -> dict[str, Any]:
    """packlab's own record (cm) of a case; ``case_from_dict`` inverts it.

    ``case.origin`` is provenance and is not written: the record, and so a case file's
    checksum, depends on the case's content only.
    """
    c = case.container
    record: dict[str, Any] = {
        "episode_id": case.episode_id,
        "difficulty": case.difficulty,
        "seed": case.seed,
        "container_size_cm": [cm(v) for v in c.size_mm],
        "grid_cell_size_cm": {"xy": cm(c.cell_xy_mm), "z": cm(c.cell_z_mm)},
        "buffer_size": case.buffer_size,
        "object_sequence": [
            {
                "internal_id": b.internal_id,
                "gt_index": b.gt_index,
                "type_id": b.type_id,
                "size_cm": [cm(v) for v in b.size_mm],
            }
            for b in case.objects
        ],
    }
    if case.gt_plan is not None:
        record["gt_plan"] = [_plan_step_dict(p) for p in case.gt_plan]
    if case.generator:
        record["generator"] = case.generator
    return record


def _plan_step_dict(p: PlanStep, action_object_id: bool = False) -> dict[str, Any]:
    action: dict[str, Any] = {"x": p.x, "y": p.y, "rotation": p.rotation}
    if action_object_id:  # the reference writes the key, always null (the shown index is per step)
        action = {"object_id": None, **action}
    return {
        "internal_id": p.internal_id,
        "gt_index": p.gt_index,
        "layer_index": p.layer_index,
        "target_box_cells": dict(zip(_CELL_KEYS, p.cell_min + p.cell_size, strict=False)),
        "action": action,
    }


def generator_text(generator: Mapping[str, Any]) -> str:
    """The reference's ``generator`` is a string: a bare name stays a name, anything richer is
    written as JSON text (``case_from_dict`` reads both back to the same mapping)."""
    if not generator:
        return ""
    name = generator.get("name")
    if set(generator) == {"name"} and isinstance(name, str) and not name.startswith("{"):
        return name
    return json.dumps(generator, separators=(",", ":"))


def case_to_reference_row(case: Case, index: int) -> dict[str, Any]:
    """The row the reference's ``episode_to_eval_row`` writes for this case.

    ``index`` is the row's position in its file, used unless the case came from a reference
    row (``case.origin``), whose ``split`` and ``index`` are written back unchanged. The
    reference layout has no grid field (its cells are always 2.5 cm and 0.2 cm), so a case on
    another grid cannot be written in it.
    """
    c = case.container
    if (c.cell_xy_mm, c.cell_z_mm) != (DEFAULT_CELL_XY_MM, DEFAULT_CELL_Z_MM):
        raise ConfigError(
            f"case {case.episode_id!r}: grid {cm(c.cell_xy_mm)} cm / "
            f"{cm(c.cell_z_mm)} cm; the reference layout has no grid field "
            f"(always 2.5 cm / 0.2 cm): export it as jsonl"
        )
    origin = case.origin
    split = origin.split if origin is not None and origin.split is not None else REFERENCE_SPLIT
    row_index = origin.index if origin is not None and origin.index is not None else index
    plan = case.gt_plan
    return {
        **REFERENCE_ROW_HEAD,
        "extra_info": {
            "split": split,
            "index": row_index,
            "difficulty": case.difficulty,
            "generator": generator_text(case.generator),
            "gt_plan": None if plan is None else [_plan_step_dict(p, True) for p in plan],
            "interaction_kwargs": _interaction_kwargs(case),
        },
    }


def _interaction_kwargs(case: Case) -> dict[str, Any]:
    """The reference row's ``extra_info.interaction_kwargs``: the case the environment gets."""
    return {
        "name": "packing",
        "sample_id": case.episode_id,
        # The reference writes every size as a float (``round(cells * 2.5, 4)``).
        "container_size_cm": [v / 10.0 for v in case.container.size_mm],
        "buffer_size": case.buffer_size,
        "object_sequence": [
            {
                "internal_id": b.internal_id,
                "gt_index": b.gt_index,
                "type_id": b.type_id,
                "size_cm": [v / 10.0 for v in b.size_mm],
            }
            for b in case.objects
        ],
        "seed": case.seed,
    }


def case_lines(cases: Iterable[Case]) -> Iterator[bytes]:
    """packlab's JSONL, line by line: what ``save_cases`` writes and ``cases_sha256`` digests."""
    for case in cases:
        yield (json.dumps(case_to_dict(case), separators=(",", ":")) + "\n").encode("utf-8")


def cases_sha256(cases: Iterable[Case]) -> str:
    """The cases' checksum: sha256 of their canonical JSONL (``save_cases``'s bytes).

    It depends on the cases only, not on the file they came from: a suite, its export to the
    reference layout and that export read back all give the same digest. For a bundled suite
    it equals the recorded file digest, as the suite file is written by ``save_cases``.
    """
    digest = hashlib.sha256()
    for line in case_lines(cases):
        digest.update(line)
    return digest.hexdigest()


__all__ = ["case_lines", "case_to_dict", "case_to_reference_row", "cases_sha256", "generator_text"]
