"""Errors that carry a user-facing, one-line message (the CLI prints them without a traceback)."""

from __future__ import annotations


class PacklabError(Exception):
    """Base class of errors whose message is meant for the user as it is."""


class CaseFormatError(PacklabError, ValueError):
    """A case file is malformed; the message names file, line, field and value."""

    def __init__(self, source: str, line: int | None, field: str, value: object, problem: str):
        where = f"{source}:{line}" if line is not None else source
        super().__init__(f"{where}: field '{field}' = {value!r}: {problem}")
        self.source, self.line, self.field, self.value, self.problem = source, line, field, value, problem


class ConfigError(PacklabError, ValueError):
    """A configuration value is invalid; the message names the field and value."""
