"""Write cases to disk: packlab's JSONL suite, or the reference's layout (a parquet file,
JSON lines, or a whole benchmark directory with its manifest).

Every file is written atomically with the user's umask (``packlab.core.fileio``), and a benchmark
directory appears whole or not at all; an existing reference output is refused, never
overwritten.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import IO, Any

import pyarrow as pa
import pyarrow.parquet as pq

from packlab.cases.layout import (
    LEVEL_NAME,
    REFERENCE_FILE,
    REFERENCE_MANIFEST,
    REFERENCE_SPLIT,
    ordered_levels,
)
from packlab.cases.serialize import case_lines, case_to_reference_row
from packlab.core.errors import ConfigError
from packlab.core.fileio import create_directory_atomically, write_atomically
from packlab.core.types import Case


def save_cases(cases: Iterable[Case], path: str | os.PathLike[str]) -> Path:
    """Write cases as packlab JSONL atomically (no half-written suite), with the user's umask."""

    def write(fh: IO[bytes]) -> None:
        for line in case_lines(cases):
            fh.write(line)

    return write_atomically(Path(path), write)


def write_reference(cases: Iterable[Case], out: str | os.PathLike[str]) -> list[Path]:
    """Write cases in the reference's layout; returns the files written.

    ``out`` ending in ``.parquet``: one parquet file, rows in the given order. ``.jsonl``: the
    same rows as JSON lines. Anything else: a reference benchmark directory
    (``out/<difficulty>/test.parquet`` per level, in ``REFERENCE_LEVEL_ORDER`` then sorted, plus
    ``out/metadata/manifest.json``), exactly what the reference's ``build_dataset.py`` makes.
    Reading any of them back with ``load_cases`` gives the same cases (a directory: grouped by
    level). An existing ``out`` is refused, never overwritten.
    """
    out = Path(out)
    cases = list(cases)
    if out.exists() or out.is_symlink():
        raise ConfigError(f"--out {out}: already exists; remove it or choose another path")
    if not cases:
        raise ConfigError("no cases to export")
    if out.suffix == ".parquet":
        return [write_atomically(out, _parquet_writer(_reference_rows(cases)))]
    if out.suffix == ".jsonl":
        return [write_atomically(out, _reference_jsonl_writer(_reference_rows(cases)))]
    return _write_reference_dir(cases, out)


def _reference_rows(cases: Sequence[Case]) -> list[dict[str, Any]]:
    """The reference rows of one file, indexed by their position in it."""
    return [case_to_reference_row(c, i) for i, c in enumerate(cases)]


# -- row writers ---------------------------------------------------------------------------------


def _reference_table(rows: list[dict[str, Any]]) -> pa.Table:
    try:
        # Types inferred from the rows, as the reference's pandas ``to_parquet`` does.
        return pa.Table.from_pylist(rows)
    except (pa.ArrowInvalid, pa.ArrowTypeError) as exc:
        raise ConfigError(
            f"cannot write these cases as one parquet table ({exc}); integer and "
            f"string internal_ids cannot share a column: export as jsonl"
        ) from None


def _parquet_writer(rows: list[dict[str, Any]]) -> Callable[[IO[bytes]], None]:
    """Builds the table now (so a bad one fails before any file exists); writes it later."""
    table = _reference_table(rows)
    return lambda fh: pq.write_table(table, fh)


def _reference_jsonl_writer(rows: list[dict[str, Any]]) -> Callable[[IO[bytes]], None]:
    def write(fh: IO[bytes]) -> None:
        for row in rows:
            fh.write((json.dumps(row, separators=(",", ":")) + "\n").encode("utf-8"))

    return write


# -- a reference benchmark directory ----------------------------------------------------------


def _level_groups(cases: Sequence[Case]) -> list[tuple[str, list[Case]]]:
    """Cases by difficulty, in load order; each difficulty must be able to name a directory."""
    groups: dict[str, list[Case]] = {}
    for case in cases:
        level = case.difficulty
        if not LEVEL_NAME.fullmatch(level or ""):
            raise ConfigError(
                f"case {case.episode_id!r}: difficulty {level!r} cannot name a "
                f"directory of a reference benchmark; export to a single .parquet "
                f"file instead"
            )
        groups.setdefault(level, []).append(case)
    return [(lvl, groups[lvl]) for lvl in ordered_levels(groups)]


def _manifest_entry(cases: Sequence[Case], parquet_path: str) -> dict[str, Any]:
    """One entry of the reference's metadata/manifest.json (its ``_dataset_manifest`` fields)."""
    levels: dict[str, int] = {}
    buffers: dict[str, int] = {}
    for c in cases:
        levels[c.difficulty] = levels.get(c.difficulty, 0) + 1
        buffers[str(c.buffer_size)] = buffers.get(str(c.buffer_size), 0) + 1
    return {
        "mode": "eval",
        "split": REFERENCE_SPLIT,
        "num_episodes": len(cases),
        "parquet_path": parquet_path,
        "difficulty_counts": levels,
        "buffer_size_counts": buffers,
        "seed_min": min((c.seed for c in cases), default=None),
        "seed_max": max((c.seed for c in cases), default=None),
    }


def _manifest(
    groups: list[tuple[str, list[Case]]], cases: Sequence[Case], out: Path
) -> dict[str, Any]:
    """The reference's metadata/manifest.json: one entry per level and a summary."""
    manifest: dict[str, Any] = {"mode": "eval", "split": REFERENCE_SPLIT, "difficulties": {}}
    for lvl, group in groups:
        manifest["difficulties"][lvl] = _manifest_entry(group, str(out / lvl / REFERENCE_FILE))
    manifest["summary"] = _manifest_entry(list(cases), str(out))
    return manifest


def _write_reference_dir(cases: Sequence[Case], out: Path) -> list[Path]:
    groups = _level_groups(cases)
    # Every table is built before anything is written: a case that cannot be written fails
    # the export with no directory left behind.
    tables = {lvl: _parquet_writer(_reference_rows(group)) for lvl, group in groups}
    text = json.dumps(_manifest(groups, cases, out), ensure_ascii=False, indent=2).encode("utf-8")

    def fill(tmp: Path) -> None:
        for lvl, write in tables.items():
            (tmp / lvl).mkdir()
            write_atomically(tmp / lvl / REFERENCE_FILE, write)
        write_atomically(tmp / REFERENCE_MANIFEST, lambda fh: fh.write(text))

    create_directory_atomically(out, fill)
    return [out / lvl / REFERENCE_FILE for lvl in tables] + [out / REFERENCE_MANIFEST]


__all__ = ["save_cases", "write_reference"]
