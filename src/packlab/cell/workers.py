"""Sessions spread over planner processes, for a server with more than one core to plan on.

The planning step is Python and numpy, so threads of one process share one core's worth of
the interpreter. Each of ``workers`` processes holds the sessions opened on it (a session's
policy and history live where it was opened, so every step of it goes there) and plans one
step at a time; the server process only parses requests and waits. A session opens on the
worker holding the fewest.

A worker that dies takes its sessions with it: the step that met it, and any later step of
its sessions, is answered 503 or 404; the worker is started again for new sessions.
"""

from __future__ import annotations

import multiprocessing
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import TypeVar

from packlab.cell import schema
from packlab.cell.errors import ServiceFull, UnknownSession
from packlab.cell.limits import DEFAULT_IDLE_S, DEFAULT_MAX_SESSIONS
from packlab.cell.sessions import LocalSessions, new_session_id

_T = TypeVar("_T")

#: The sessions of the worker process this module runs in (set by ``_start_worker``).
_LOCAL: LocalSessions | None = None


def _start_worker(default_policy: str, max_sessions: int, idle_s: float) -> None:
    global _LOCAL
    _LOCAL = LocalSessions(default_policy, max_sessions, idle_s)


def _local() -> LocalSessions:
    if _LOCAL is None:  # the pool's initializer always ran first
        raise RuntimeError("cell worker used before it started")
    return _LOCAL


def _open(request: schema.SessionRequest, session_id: str) -> schema.SessionOpened:
    return _local().open(request, session_id)


def _step(session_id: str, request: schema.StepRequest) -> schema.StepAnswer:
    return _local().step(session_id, request)


def _plan(request: schema.PlanRequest) -> schema.StepAnswer:
    return _local().plan(request)


def _close(session_id: str) -> None:
    _local().close(session_id)


class ProcessSessions:
    """Sessions in ``workers`` planner processes, a session pinned to the one it opened on."""

    def __init__(
        self,
        workers: int,
        default_policy: str,
        max_sessions: int = DEFAULT_MAX_SESSIONS,
        idle_s: float = DEFAULT_IDLE_S,
    ):
        if workers < 1:
            raise ValueError(f"workers = {workers}: need at least 1")
        self.workers = workers
        self.default_policy = default_policy
        self.max_sessions = max_sessions
        self.idle_s = idle_s
        # spawn, not fork: the server process runs threads, which a forked child would inherit
        # mid-flight (held locks included).
        self._context = multiprocessing.get_context("spawn")
        self._pools = [self._new_pool() for _ in range(workers)]
        self._where: dict[str, int] = {}  # session id -> worker
        self._used: dict[str, float] = {}  # session id -> last use (monotonic)
        self._lock = threading.Lock()

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=1,
            mp_context=self._context,
            initializer=_start_worker,
            # Each worker may hold them all: the server's count is the one enforced.
            initargs=(self.default_policy, self.max_sessions, self.idle_s),
        )

    def open(self, request: schema.SessionRequest) -> schema.SessionOpened:
        with self._lock:
            self._forget_idle()
            if len(self._where) >= self.max_sessions:
                raise ServiceFull(
                    f"sessions: {len(self._where)} open, the most this server keeps; close "
                    "finished ones (DELETE /v1/sessions/{id})"
                )
            load = [0] * self.workers
            for worker in self._where.values():
                load[worker] += 1
            worker = load.index(min(load))
            session_id = new_session_id()
            self._where[session_id] = worker  # reserved now, so parallel opens spread out
            self._used[session_id] = time.monotonic()
        try:
            return self._call(worker, _open, request, session_id)
        except BaseException:
            self._forget(session_id)
            raise

    def step(self, session_id: str, request: schema.StepRequest) -> schema.StepAnswer:
        worker = self._worker(session_id)
        try:
            return self._call(worker, _step, session_id, request)
        except UnknownSession:
            self._forget(session_id)  # the worker closed it after idling
            raise

    def plan(self, request: schema.PlanRequest) -> schema.StepAnswer:
        with self._lock:
            load = [0] * self.workers
            for worker in self._where.values():
                load[worker] += 1
        return self._call(load.index(min(load)), _plan, request)

    def close(self, session_id: str) -> None:
        worker = self._worker(session_id)
        self._forget(session_id)
        self._call(worker, _close, session_id)

    def count(self) -> int:
        with self._lock:
            return len(self._where)

    def shutdown(self) -> None:
        for pool in self._pools:
            pool.shutdown(wait=True, cancel_futures=True)

    def _worker(self, session_id: str) -> int:
        with self._lock:
            worker = self._where.get(session_id)
            if worker is None:
                raise UnknownSession(session_id)
            self._used[session_id] = time.monotonic()
            return worker

    def _forget(self, session_id: str) -> None:
        with self._lock:
            self._where.pop(session_id, None)
            self._used.pop(session_id, None)

    def _forget_idle(self) -> None:
        """Drop sessions idle past ``idle_s`` from the count (their worker drops them too)."""
        now = time.monotonic()
        for session_id, used in list(self._used.items()):
            if now - used > self.idle_s:
                self._where.pop(session_id, None)
                del self._used[session_id]

    def _call(self, worker: int, function: Callable[..., _T], *args: object) -> _T:
        """``function(*args)`` in ``worker``; a dead worker is restarted, its sessions lost."""
        try:
            return self._pools[worker].submit(function, *args).result()
        except BrokenProcessPool:
            with self._lock:
                self._pools[worker] = self._new_pool()
                lost = [s for s, w in self._where.items() if w == worker]
                for session_id in lost:
                    self._where.pop(session_id, None)
                    self._used.pop(session_id, None)
            raise ServiceFull(
                f"planner worker {worker} stopped; its {len(lost)} session(s) are lost, open "
                "new ones"
            ) from None


__all__ = ["ProcessSessions"]
