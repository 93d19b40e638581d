"""Read case files: one JSON case (or list), a JSONL suite, a reference parquet file or directory.

Each reader turns bytes into records and hands every record to ``case_from_dict`` with its
location: ``FILE:LINE`` for JSON/JSONL, ``FILE (row N)`` (1-based) for parquet, whose files have
rows, not lines. Text must be UTF-8 (a leading byte-order mark is skipped).
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from packlab.cases.layout import REFERENCE_FILE, reference_level_files
from packlab.cases.reader import shorten
from packlab.cases.records import case_from_dict
from packlab.core.errors import CaseFormatError, ConfigError
from packlab.core.types import Case

_BOM = b"\xef\xbb\xbf"  # a UTF-8 byte-order mark


def load_cases(path: str | os.PathLike[str]) -> list[Case]:
    """Load a JSON case (or list of cases), a JSONL suite, a parquet file in the reference
    layout, or a reference benchmark directory; see ``packlab.cases``."""
    path = Path(path)
    source = str(path)
    if not path.exists():  # errno form: the CLI prints "'PATH': no such case file", exit code 2
        raise FileNotFoundError(errno.ENOENT, "no such case file", source)
    if path.is_dir():
        cases = _read_reference_dir(path)
    elif path.suffix == ".parquet":
        cases = _read_parquet(path, source, path.stem)
    elif path.suffix == ".jsonl":
        cases = _read_jsonl(path, source, path.stem)
    else:
        cases = _read_json(path, source, path.stem)
    _check_unique_ids(cases, source)
    return cases


def _check_unique_ids(cases: list[Case], source: str) -> None:
    seen: set[str] = set()
    for case in cases:
        if case.episode_id in seen:
            raise CaseFormatError(
                source, None, "episode_id", case.episode_id, "episode_id is not unique in the suite"
            )
        seen.add(case.episode_id)


# -- JSON and JSONL -----------------------------------------------------------------------------


def _decode(raw: bytes, source: str, line: int, offset: int) -> str:
    """UTF-8 text of one line; a clear error with the byte offset (in the file) otherwise."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        bad = raw[exc.start : exc.start + 4]
        raise CaseFormatError(
            source,
            line,
            "<encoding>",
            bad,
            f"not UTF-8 (byte offset {offset + exc.start} in the file); save the file as UTF-8",
        ) from None


def _parse_json(text: str, source: str, line: int | None) -> Any:
    """One JSON document; ``line`` given: it is one line of a JSONL file."""
    what = "bad JSON line" if line is not None else "bad JSON"
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        where = line if line is not None else exc.lineno
        raise CaseFormatError(
            source, where, "<json>", shorten(text.strip()[:60]), f"{what} ({exc.msg})"
        ) from None
    except (ValueError, RecursionError) as exc:  # an int past Python's digit limit; deep nesting
        problem = "nested too deeply" if isinstance(exc, RecursionError) else str(exc).split(";")[0]
        raise CaseFormatError(
            source, line, "<json>", shorten(text.strip()[:60]), f"{what} ({problem})"
        ) from None


def _read_jsonl(path: Path, source: str, id_prefix: str) -> list[Case]:
    cases = []
    offset = 0
    with path.open("rb") as fh:
        for lineno, raw in enumerate(fh, start=1):
            start = offset
            offset += len(raw)
            if lineno == 1 and raw.startswith(_BOM):
                raw, start = raw[3:], 3
            text = _decode(raw, source, lineno, start)
            if not text.strip():
                continue
            record = _parse_json(text, source, lineno)
            cases.append(case_from_dict(record, source, lineno, default_id=f"{id_prefix}-{lineno}"))
    return cases


def _read_json(path: Path, source: str, id_prefix: str) -> list[Case]:
    data = path.read_bytes()
    if data.startswith(_BOM):
        data = data[3:]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise CaseFormatError(
            source,
            line,
            "<encoding>",
            data[exc.start : exc.start + 4],
            f"not UTF-8 (byte offset {exc.start} in the file); save the file as UTF-8",
        ) from None
    records = _parse_json(text, source, None)
    records = records if isinstance(records, list) else [records]
    many = len(records) > 1
    return [
        case_from_dict(
            rec, source, i + 1 if many else None, default_id=f"{id_prefix}-{i + 1 if many else 0}"
        )
        for i, rec in enumerate(records)
    ]


# -- the reference's parquet files --------------------------------------------------------------


def _read_parquet(
    path: Path, source: str, id_prefix: str, default_difficulty: str = ""
) -> list[Case]:
    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as exc:
        reason = " ".join(str(exc).split())[:240]
        raise CaseFormatError(
            source,
            None,
            "<parquet>",
            None,
            f"not a readable parquet file ({type(exc).__name__}: {reason}); "
            f"is it truncated, or not parquet at all?",
        ) from None
    if "extra_info" not in table.column_names:
        raise CaseFormatError(
            source,
            None,
            "extra_info",
            None,
            f"parquet has no 'extra_info' column "
            f"(columns: {', '.join(table.column_names)}); "
            f"expected the reference benchmark layout",
        )
    cases = []
    for row, extra in enumerate(table.column("extra_info").to_pylist(), start=1):
        # Errors say "FILE (row N)": a parquet file has rows, not lines.
        where = f"{source} (row {row})"
        if extra is None:
            raise CaseFormatError(where, None, "extra_info", None, "missing required field")
        cases.append(
            case_from_dict(
                {"extra_info": extra},
                where,
                None,
                default_id=f"{id_prefix}-{row}",
                default_difficulty=default_difficulty,
            )
        )
    return cases


def _read_reference_dir(path: Path) -> list[Case]:
    files = reference_level_files(path)
    if not files:
        raise ConfigError(
            f"{path}: is a directory; pass a case file (.jsonl, .json or .parquet) "
            f"or a reference benchmark directory (<dir>/<difficulty>/"
            f"{REFERENCE_FILE}, e.g. easy/{REFERENCE_FILE})"
        )
    cases: list[Case] = []
    for level, file in files:
        # Rows without a sample_id are called <level>-<row>: every level's file is test.parquet.
        cases += _read_parquet(file, str(file), id_prefix=level, default_difficulty=level)
    return cases


__all__ = ["load_cases"]
