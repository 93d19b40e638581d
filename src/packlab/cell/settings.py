"""``packlab cell serve``'s settings (no web framework imported: the command line reads them
before the ``cell`` extra is needed)."""

from __future__ import annotations

from dataclasses import dataclass

from packlab.cell.limits import DEFAULT_IDLE_S, DEFAULT_MAX_SESSIONS
from packlab.core.errors import ConfigError

#: What sessions that name no policy are served by: the best planner that fits a robot's cycle.
DEFAULT_POLICY = "plan-fast"
DEFAULT_PORT = 8100


@dataclass(frozen=True, slots=True)
class ServeSettings:
    """Where the service listens, what it plans with, and how much it keeps."""

    policy: str = DEFAULT_POLICY
    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    #: Planner processes: 1 plans in the server's own process; N > 1 starts N processes and
    #: spreads the sessions over them (a session's state lives where it was opened).
    workers: int = 1
    max_sessions: int = DEFAULT_MAX_SESSIONS
    idle_s: float = DEFAULT_IDLE_S

    def __post_init__(self) -> None:
        checks = (
            ("port", 0 <= self.port <= 65535, "0 to 65535"),
            ("workers", self.workers >= 1, "at least 1"),
            ("max_sessions", self.max_sessions >= 1, "at least 1"),
            ("idle_s", self.idle_s > 0, "more than 0"),
        )
        for name, ok, need in checks:
            if not ok:
                raise ConfigError(f"{name} = {getattr(self, name)!r}: need {need}")


__all__ = ["DEFAULT_POLICY", "DEFAULT_PORT", "ServeSettings"]
