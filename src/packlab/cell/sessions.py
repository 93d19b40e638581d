"""Open sessions in this process: the states ``plan_step`` works on, by id.

A session's steps run one at a time (its own lock: a policy's state and the history are one
sequence); different sessions run at once in the server's threads. A session idle for longer
than ``idle_s`` is closed when the next one opens, and the store keeps at most
``max_sessions``, so a cell that never closes its sessions cannot fill the server's memory.
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from packlab.cell import schema
from packlab.cell.convert import answer_model, cell_config, step_input
from packlab.cell.errors import ServiceFull, UnknownSession
from packlab.cell.limits import DEFAULT_IDLE_S, DEFAULT_MAX_SESSIONS
from packlab.cell.step import SessionState, open_session, plan_step


class SessionBackend(Protocol):
    """What the HTTP layer asks of the sessions, wherever they live (this process, workers)."""

    workers: int

    def open(self, request: schema.SessionRequest) -> schema.SessionOpened: ...

    def step(self, session_id: str, request: schema.StepRequest) -> schema.StepAnswer: ...

    def plan(self, request: schema.PlanRequest) -> schema.StepAnswer: ...

    def close(self, session_id: str) -> None: ...

    def count(self) -> int: ...

    def shutdown(self) -> None: ...


@dataclass(slots=True)
class _Entry:
    state: SessionState
    last_used: float
    lock: threading.Lock = field(default_factory=threading.Lock)


def new_session_id() -> str:
    return uuid.uuid4().hex


class LocalSessions:
    """Sessions held in this process."""

    workers = 1

    def __init__(
        self,
        default_policy: str,
        max_sessions: int = DEFAULT_MAX_SESSIONS,
        idle_s: float = DEFAULT_IDLE_S,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.default_policy = default_policy
        self.max_sessions = max_sessions
        self.idle_s = idle_s
        self._clock = clock
        self._entries: dict[str, _Entry] = {}
        self._lock = threading.Lock()

    def open(
        self, request: schema.SessionRequest, session_id: str | None = None
    ) -> schema.SessionOpened:
        config = cell_config(request, self.default_policy)
        state = open_session(config)  # makes the policy: outside the store's lock
        session_id = session_id or new_session_id()
        with self._lock:
            self._close_idle()
            if len(self._entries) >= self.max_sessions:
                raise ServiceFull(
                    f"sessions: {len(self._entries)} open, the most this server keeps; close "
                    "finished ones (DELETE /v1/sessions/{id})"
                )
            self._entries[session_id] = _Entry(state, self._clock())
        return schema.SessionOpened(
            session_id=session_id,
            policy=config.policy,
            heightmap_cells=config.container.cells,
            idle_timeout_s=self.idle_s,
        )

    def step(self, session_id: str, request: schema.StepRequest) -> schema.StepAnswer:
        entry = self._entry(session_id)
        decoded, decode_ms = step_input(request)
        with entry.lock:
            answer = plan_step(entry.state, decoded)
            entry.last_used = self._clock()
        return answer_model(answer, session_id, decode_ms)

    def plan(self, request: schema.PlanRequest) -> schema.StepAnswer:
        """A one-step session that is never stored."""
        state = open_session(cell_config(request, self.default_policy))
        decoded, decode_ms = step_input(request)
        return answer_model(plan_step(state, decoded), None, decode_ms)

    def close(self, session_id: str) -> None:
        with self._lock:
            if self._entries.pop(session_id, None) is None:
                raise UnknownSession(session_id)

    def count(self) -> int:
        with self._lock:
            return len(self._entries)

    def shutdown(self) -> None:
        with self._lock:
            self._entries.clear()

    def _entry(self, session_id: str) -> _Entry:
        with self._lock:
            entry = self._entries.get(session_id)
            if entry is None:
                raise UnknownSession(session_id)
            entry.last_used = self._clock()  # a step under way is not idle
            return entry

    def _close_idle(self) -> None:
        """Forget sessions idle for longer than ``idle_s`` (the store's lock is held)."""
        now = self._clock()
        for session_id, entry in list(self._entries.items()):
            if now - entry.last_used > self.idle_s and not entry.lock.locked():
                del self._entries[session_id]


__all__ = ["LocalSessions", "SessionBackend", "new_session_id"]
