"""Errors that carry a user-facing, one-line message (the CLI prints them without a traceback)."""

from __future__ import annotations


class PacklabError(Exception):
    """Base class of errors whose message is meant for the user as it is."""


class CaseFormatError(PacklabError, ValueError):
    """A case file is malformed; the message names file, line, field and value."""

    def __init__(self, source: str, line: int | None, field: str, value: object, problem: str):
        where = f"{source}:{line}" if line is not None else source
        super().__init__(f"{where}: field '{field}' = {value!r}: {problem}")
        self.source, self.line, self.field, self.value, self.problem = (
            source,
            line,
            field,
            value,
            problem,
        )


class RecordFormatError(PacklabError, ValueError):
    """A record file (bench episodes or summary, dataset info) that this packlab cannot read as
    its typed record: an unknown format version, or a field missing or of the wrong type. The
    message names file, line (JSONL only), field and value (see ``packlab.core.records``)."""

    def __init__(
        self,
        source: str,
        line: int | None,
        field: str,
        value: object,
        problem: str,
        *,
        show_value: bool = True,
    ):
        where = f"{source}:{line}" if line is not None else source
        shown = f" = {value!r}" if show_value else ""
        super().__init__(f"{where}: field '{field}'{shown}: {problem}")
        self.source, self.line, self.field, self.value, self.problem = (
            source,
            line,
            field,
            value,
            problem,
        )


class ConfigError(PacklabError, ValueError):
    """A configuration value is invalid; the message names the field and value."""


class EndpointUnavailable(PacklabError):
    """A model server could not be used: refused, timed out, or answered 5xx after its retries.

    Raised by remote policies (``endpoint``) instead of returning an action: a transport failure
    says nothing about the policy's packing, so the bench records the episode as an error of kind
    ``transport`` and counts consecutive ones in its circuit breaker (see docs/robustness.md).
    """


class RunAborted(PacklabError):
    """A bench run stopped early (circuit breaker, run deadline); the records written are kept."""


#: Process exit codes of the ``packlab`` commands (documented in docs/robustness.md).
EXIT_OK = 0  # everything asked for ran
EXIT_EPISODE_ERRORS = (
    1  # the run finished, but some episodes ended in error (count on the last line)
)
EXIT_USAGE = 2  # bad input or configuration: nothing was run or written half-way
EXIT_ABORTED = 3  # the run stopped early (circuit breaker, run deadline); finished records are kept
EXIT_INTERRUPTED = 130  # SIGINT (Ctrl-C); rerun the same command to resume
EXIT_TERMINATED = 143  # SIGTERM (a scheduler or supervisor stopped it); rerun to resume
