"""What the cell service answers instead of a placement: bad input, an unknown session, a full
server. Plain exceptions (no web framework), so the planning code raises them in a worker
process too and the HTTP layer turns each into its status code and one line."""

from __future__ import annotations

from packlab.core.errors import PacklabError

#: How many characters of an offending value an error line shows (base64 data runs to MBs).
VALUE_CHARS = 80


def short_value(value: object) -> str:
    """``repr(value)``, cut to :data:`VALUE_CHARS` characters with an ellipsis."""
    text = repr(value)
    return text if len(text) <= VALUE_CHARS else text[: VALUE_CHARS - 3] + "..."


class CellInputError(PacklabError, ValueError):
    """A request the service cannot plan from: ``field = value: reason`` (HTTP 422)."""

    status = 422

    def __init__(self, field: str, value: object, reason: str):
        # args are the constructor's, so the error pickles back from a worker process as it was.
        super().__init__(field, value, reason)
        self.field, self.value, self.reason = field, value, reason

    def __str__(self) -> str:
        return f"{self.field} = {short_value(self.value)}: {self.reason}"


class UnknownSession(PacklabError, KeyError):
    """No open session has this id (HTTP 404)."""

    status = 404

    def __init__(self, session_id: str):
        super().__init__(session_id)
        self.session_id = session_id

    def __str__(self) -> str:
        return (
            f"session = {short_value(self.session_id)}: unknown (never opened, closed, or "
            "closed after idling); open a new one with POST /v1/sessions"
        )


class ServiceFull(PacklabError):
    """The server keeps as many sessions as it may, or lost a planner process (HTTP 503)."""

    status = 503


__all__ = ["VALUE_CHARS", "CellInputError", "ServiceFull", "UnknownSession", "short_value"]
