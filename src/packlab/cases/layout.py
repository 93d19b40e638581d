"""The public PackLab reference's benchmark layout: its file names, row head and level order.

A reference benchmark *directory* is ``<dir>/<difficulty>/test.parquet`` per level plus
``<dir>/metadata/manifest.json``, as the reference's ``build_dataset.py`` writes it. Reading and
writing share these names and the one level order, so a directory packlab writes loads back in
the order it was written.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path

from packlab.core.choices import Difficulty, choices

#: File order when a reference benchmark directory is loaded (other levels follow, sorted).
REFERENCE_LEVEL_ORDER = choices(Difficulty)  # easy, medium, hard
#: The per-level file inside a reference benchmark directory.
REFERENCE_FILE = "test.parquet"
#: What the reference's ``episode_to_eval_row`` puts beside ``extra_info`` in each row.
REFERENCE_ROW_HEAD = {
    "data_source": "packing_eval",
    "prompt_template_id": "packing_sft",
    "ability": "spatial_packing",
}
REFERENCE_SPLIT = "test"
REFERENCE_MANIFEST = Path("metadata") / "manifest.json"
#: A difficulty that can name a level directory: no separators, no leading dot.
LEVEL_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")


def ordered_levels(levels: Iterable[str]) -> list[str]:
    """``levels`` in load order: ``REFERENCE_LEVEL_ORDER`` first, then the others sorted."""
    present = set(levels)
    known = [lvl for lvl in REFERENCE_LEVEL_ORDER if lvl in present]
    return known + sorted(present - set(known))


def reference_level_files(directory: str | os.PathLike[str]) -> list[tuple[str, Path]]:
    """(level, file) of a reference benchmark directory, in load order: ``REFERENCE_LEVEL_ORDER``
    first, then other levels sorted by name. Empty when ``directory`` is not one."""
    directory = Path(directory)
    found = {p.parent.name: p for p in directory.glob(f"*/{REFERENCE_FILE}") if p.is_file()}
    return [(lvl, found[lvl]) for lvl in ordered_levels(found)]


__all__ = [
    "LEVEL_NAME",
    "REFERENCE_FILE",
    "REFERENCE_LEVEL_ORDER",
    "REFERENCE_MANIFEST",
    "REFERENCE_ROW_HEAD",
    "REFERENCE_SPLIT",
    "ordered_levels",
    "reference_level_files",
]
