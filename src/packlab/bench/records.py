"""The run directory's ``episodes.jsonl``: a typed record per (case, seed, policy, backend) done.

Records are ``packlab.core.records.EpisodeRecord``s (``EpisodeOk`` or ``EpisodeError``), each
with its ``format`` version; reading checks it and migrates records written before records
carried one (run-1 and early run-2; ``packlab.core.records.migrate_episode``). A newer or
unknown version, or a field of the wrong type, is an error naming the file, line and field.

Records are appended by a single writer (the runner's main process) and flushed per line, so a
killed run leaves at most one torn last line. Readers skip a torn last line; the writer cuts it
off before appending, so a resumed run never glues a new record onto half an old one. A torn or
unreadable line anywhere *but* the end is real damage and an error naming the line.

Record kinds (``status``):
  * ``"ok"``: ``EpisodeResult.to_record()`` plus ``difficulty``, ``n_objects`` and ``timing``.
  * ``"error"``: the episode failed; ``error_kind`` says how (``"exception"``: the policy or
    engine raised, or the worker died; ``"timeout"``: past ``--episode-timeout``;
    ``"transport"``: a remote policy's server was unreachable), ``error`` (one line) and
    ``traceback`` say why. Records written before ``error_kind`` existed read as "exception".
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Self, TextIO

from packlab.core.errors import PacklabError
from packlab.core.records import (
    EpisodeError,
    EpisodeOk,
    EpisodeRecord,
    NotJSON,
    decode_episode,
    dumps_line,
)

EPISODES_FILE = "episodes.jsonl"
CONFIG_FILE = "config.json"
CASES_FILE = "cases.jsonl"

#: A record's identity: rerunning the same key is redoing work.
RecordKey = tuple[str, int, str, str]


def record_key(record: EpisodeRecord) -> RecordKey:
    return record.key


class RecordsError(PacklabError):
    """An episodes.jsonl line is damaged somewhere other than at the end."""


@dataclass(frozen=True, slots=True)
class RecordFile:
    """What a records file holds: the parsed records and where the intact part ends."""

    records: tuple[EpisodeRecord, ...]
    good_bytes: int  # length of the intact prefix (everything up to the last complete record)
    torn_tail: bool  # True when bytes after good_bytes are an unfinished record


def _parse_lines(data: bytes, path: Path) -> RecordFile:
    records: list[EpisodeRecord] = []
    offset = 0
    lines = data.split(b"\n")
    # The part after the last newline is either empty (a clean file) or an unfinished write.
    *complete, tail = lines
    for lineno, raw in enumerate(complete, start=1):
        end = offset + len(raw) + 1
        if raw.strip():
            try:
                rec = decode_episode(raw, str(path), lineno)
            except NotJSON as exc:
                if lineno == len(complete) and not tail.strip():
                    # A last line that ends in a newline yet does not parse: a write cut short
                    # exactly after a buffer boundary. Treat as torn, like a missing newline.
                    return RecordFile(tuple(records), offset, True)
                raise RecordsError(f"{exc}; the file is damaged") from None
            records.append(rec)
        offset = end
    return RecordFile(tuple(records), offset, bool(tail.strip()))


def read_record_file(path: str | os.PathLike[str]) -> RecordFile:
    """Parse a records file, tolerating a torn last line (a missing file holds nothing)."""
    path = Path(path)
    if not path.exists():
        return RecordFile((), 0, False)
    return _parse_lines(path.read_bytes(), path)


def read_records(path: str | os.PathLike[str]) -> list[EpisodeRecord]:
    """The records of a file, one per key: a later record of a key replaces an earlier one."""
    latest: dict[RecordKey, EpisodeRecord] = {}
    for rec in read_record_file(path).records:
        latest[rec.key] = rec
    return list(latest.values())


def dumps(record: EpisodeRecord) -> str:
    """One compact line (no spaces: records are many and read by machines)."""
    return dumps_line(record)


class RecordWriter:
    """Appends records to episodes.jsonl, one flushed line each (use as a context manager)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._fh: TextIO | None = None

    def __enter__(self) -> Self:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        state = read_record_file(self.path)
        if state.torn_tail or (self.path.exists() and self.path.stat().st_size != state.good_bytes):
            # Cut the unfinished line of a killed run so the next record starts on a fresh line.
            with open(self.path, "r+b") as fh:
                fh.truncate(state.good_bytes)
        self._fh = open(self.path, "a", encoding="utf-8")
        return self

    def write(self, record: EpisodeRecord) -> None:
        assert self._fh is not None, "use RecordWriter as a context manager"
        self._fh.write(dumps(record) + "\n")
        # Flush per record: a kill then loses at most the record being written.
        self._fh.flush()

    def write_all(self, records: Iterable[EpisodeRecord]) -> None:
        for rec in records:
            self.write(rec)

    def __exit__(self, *exc: object) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


def iter_ok(records: Iterable[EpisodeRecord]) -> Iterator[EpisodeOk]:
    return (r for r in records if isinstance(r, EpisodeOk))


def error_kind(record: EpisodeRecord) -> str | None:
    """A failed record's kind ("exception", "timeout", "transport"); None for a result."""
    return record.error_kind if isinstance(record, EpisodeError) else None


__all__ = [
    "CASES_FILE",
    "CONFIG_FILE",
    "EPISODES_FILE",
    "RecordFile",
    "RecordKey",
    "RecordWriter",
    "RecordsError",
    "dumps",
    "error_kind",
    "iter_ok",
    "read_record_file",
    "read_records",
    "record_key",
]
