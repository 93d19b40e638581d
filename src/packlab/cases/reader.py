"""Field access and validation for one case record, with errors that say where they are.

Every check raises ``CaseFormatError`` naming file, line, field (as the user sees it in the
file) and value; values are cut short so a message stays one line. Files speak centimetres,
the library integer millimetres: ``Reader.mm`` converts one way, ``cm`` the other.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

from packlab.cases.limits import INT64_BOUND
from packlab.core.errors import CaseFormatError


class Reader:
    """Field access for one case record that reports errors with their location.

    ``aliases`` maps a top-level key to where it sits in the file (in the reference's rows
    ``object_sequence`` is really ``extra_info.interaction_kwargs.object_sequence`` and the
    case id is ``...sample_id``), so an error names the field as the user sees it in the file.
    """

    def __init__(self, source: str, line: int | None, aliases: Mapping[str, str] | None = None):
        self.source, self.line = source, line
        self.aliases = dict(aliases or {})

    def path(self, field: str) -> str:
        top = re.split(r"[.\[]", field, maxsplit=1)[0]
        return self.aliases.get(top, top) + field[len(top) :]

    def fail(self, field: str, value: object, problem: str) -> CaseFormatError:
        return CaseFormatError(self.source, self.line, self.path(field), shorten(value), problem)

    def get(self, record: Mapping[str, Any], key: str, field: str) -> Any:
        if not isinstance(record, Mapping):
            raise self.fail(field.rsplit(".", 1)[0] or field, record, "expected an object")
        if key not in record or record[key] is None:
            raise self.fail(field, None, "missing required field")
        return record[key]

    def mm(self, value: Any, field: str, *, multiple_of: int = 1, max_mm: int | None = None) -> int:
        """A positive length in cm -> integer mm, on the grid and within ``max_mm``."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(field, value, "expected a number of centimetres")
        if isinstance(value, int):  # exact, and no float overflow for huge integers
            mm = value * 10
        else:
            if not math.isfinite(value):
                raise self.fail(field, value, "expected a finite number of centimetres")
            mm_float = value * 10.0
            if abs(mm_float) > 1e15:  # beyond every limit; round() of it would mean nothing
                raise self.fail(field, value, _too_large(max_mm))
            mm = round(mm_float)
            if abs(mm - mm_float) > 1e-6:
                raise self.fail(field, value, "not a whole number of millimetres")
        if mm <= 0:
            raise self.fail(field, value, "must be positive")
        if max_mm is not None and mm > max_mm:
            raise self.fail(field, value, _too_large(max_mm))
        if mm % multiple_of:
            raise self.fail(field, value, f"not a multiple of the {multiple_of / 10:g} cm grid")
        return mm

    def integer(
        self, value: object, field: str, *, minimum: int | None = None, bound: int = INT64_BOUND
    ) -> int:
        """An integer (or a float with no fraction) in ``[minimum or -bound, bound)``."""
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise self.fail(field, value, "expected an integer")
        if minimum is not None and value < minimum:
            raise self.fail(field, value, f"must be at least {minimum}")
        if not -bound <= value < bound:
            raise self.fail(field, value, f"out of range (|value| < 2**{bound.bit_length() - 1})")
        return value

    def text(self, value: Any, field: str, max_chars: int) -> str:
        if not isinstance(value, str):
            raise self.fail(field, value, "expected a string")
        if len(value) > max_chars:
            raise self.fail(field, value, f"longer than {max_chars} characters")
        return value

    def triple(self, record: Mapping[str, Any], key: str, field: str) -> list[Any]:
        value = self.get(record, key, field)
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            raise self.fail(field, value, "expected a list of three numbers")
        return list(value)


def shorten(value: object) -> object:
    """A value as an error shows it: long strings, numbers and containers cut, so a message
    stays one line."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**30:
        digits = str(abs(value))
        return Cut(f"{'-' if value < 0 else ''}{digits[:12]}...({len(digits)} digits)")
    if isinstance(value, str) and len(value) > 60:
        return value[:57] + "..."
    if isinstance(value, bytes) and len(value) > 60:
        return value[:57] + b"..."
    if isinstance(value, (list, tuple, dict)):
        text = repr(value)
        return value if len(text) <= 80 else Cut(text[:77] + "...")
    return value


class Cut(str):
    """A cut-down repr that prints without quotes."""

    def __repr__(self) -> str:
        return str(self)


def _too_large(max_mm: int | None) -> str:
    if max_mm is None:
        return "too large"
    return f"larger than the limit of {max_mm / 10:g} cm (packlab.cases.MAX_CONTAINER_SIDE_CM)"


def cm(mm: int) -> float | int:
    """mm -> cm, written as an int when whole so files stay tidy."""
    value = mm / 10.0
    return int(value) if value.is_integer() else value


__all__ = ["Cut", "Reader", "cm", "shorten"]
