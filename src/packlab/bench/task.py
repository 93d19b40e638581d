"""One unit of bench work: a (case, policy, run seed) episode turned into a record.

This is what workers execute. It never raises for a policy or engine failure: the failure is
the record (``status: "error"`` with ``error_kind``, a one-line ``error`` and the traceback),
so one crashing policy on one case cannot stop a run of thousands of episodes.

Error kinds (``error_kind``):
  * ``"exception"``: the policy or the engine raised (or the worker process died);
  * ``"timeout"``: the episode ran past ``--episode-timeout``;
  * ``"transport"``: a remote policy could not reach its server (``EndpointUnavailable``);
    says nothing about the policy, and the runner's circuit breaker counts these.

Time limits use ``SIGALRM`` (``signal.setitimer``) in the thread that runs the episode, when
that is the process's main thread: the handler raises inside whatever the policy is doing,
including a blocking ``time.sleep`` or socket read. An episode in another thread (a worker
running several at once, ``--concurrency``) gets the exception from a timer thread instead,
delivered at its next Python instruction: not inside a blocking call, which ends first (an
HTTP request at its own deadline). Code that never returns to the interpreter (a C loop)
cannot be interrupted either way; the process pool backs the limit up by killing a worker that
stays silent past it (see ``packlab.executors``).
"""

from __future__ import annotations

import ctypes
import importlib
import os
import signal
import threading
import time
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import msgspec

from packlab.core.choices import ErrorKind, choices
from packlab.core.errors import EndpointUnavailable
from packlab.core.records import RUN_FORMAT, EpisodeError, EpisodeOk, EpisodeRecord, Timing, convert
from packlab.core.types import Case
from packlab.executors import DeadlineReached
from packlab.policies import make_policy
from packlab.sim.episode import run_episode
from packlab.sim.modes import EXACT_MODES, EpisodeModes

#: The driver of ``--via-cell`` (``served_policy``, ``preflight_service``): it needs the cell
#: extra (httpx, pydantic), so it is imported only by a run that asks for it.
VIA_CELL_MODULE = "packlab.cell.via_cell"

#: Values of a failed record's ``error_kind``.
ERROR_KINDS = choices(ErrorKind)


@dataclass(frozen=True, slots=True)
class Task:
    """An episode to run: the case by index into the run's case list (cheap to send to workers)."""

    case_index: int
    policy: str
    seed: int


class EpisodeTimeout(BaseException):
    """Raised by the alarm inside a running episode.

    A BaseException so that a policy's own ``except Exception: retry`` cannot swallow it and
    carry on past the limit.
    """


class _DeadlineAlarm(BaseException):
    """The alarm fired for the run deadline (internal; becomes DeadlineReached)."""


def _alarm_usable() -> bool:
    return hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()


def _timeout_message(seconds: float | None) -> str:
    return f"episode ran past the {seconds:g} s limit (--episode-timeout)"


def _raise_in(thread_id: int, exc: type[BaseException] | None) -> None:
    """Have ``exc`` raised in thread ``thread_id`` at its next instruction (None: cancel one
    not yet raised)."""
    ctypes.pythonapi.PyThreadState_SetAsyncExc(
        ctypes.c_ulong(thread_id), None if exc is None else ctypes.py_object(exc)
    )


@contextmanager
def thread_time_limit(seconds: float) -> Iterator[None]:
    """Raise EpisodeTimeout in this thread after ``seconds`` (any thread; see the module
    docstring for what it cannot interrupt)."""
    target, lock = threading.get_ident(), threading.Lock()
    state = {"inside": True, "fired": False}

    def fire() -> None:
        with lock:  # never into the thread once it has left the block
            if state["inside"]:
                state["fired"] = True
                _raise_in(target, EpisodeTimeout)

    timer = threading.Timer(seconds, fire)
    timer.daemon = True
    timer.start()
    try:
        yield
    except EpisodeTimeout as exc:
        exc.args = exc.args or (_timeout_message(seconds),)  # keeps where it was stuck
        _disarm(timer, lock, state, target)
        raise
    except BaseException:
        _disarm(timer, lock, state, target)
        raise
    if _disarm(timer, lock, state, target):  # fired as the block ended: not delivered yet
        raise EpisodeTimeout(_timeout_message(seconds))


def _disarm(
    timer: threading.Timer, lock: threading.Lock, state: dict[str, bool], target: int
) -> bool:
    """Stop the timer; whether it had fired (an exception not yet raised is cancelled)."""
    timer.cancel()
    with lock:
        state["inside"] = False
        if state["fired"]:
            _raise_in(target, None)
    return state["fired"]


@contextmanager
def time_limit(seconds: float | None, deadline: float | None = None) -> Iterator[None]:
    """Raise EpisodeTimeout after ``seconds``, or _DeadlineAlarm at ``deadline`` (a
    ``time.monotonic()`` value), whichever comes first; no limit where neither is set. Outside
    the main thread (no alarm there) only ``seconds`` is enforced, by :func:`thread_time_limit`:
    a run's deadline stops such a thread's process instead (``packlab.executors``)."""
    until_deadline = None if deadline is None else deadline - time.monotonic()
    limits = [x for x in (seconds, until_deadline) if x is not None]
    if seconds is not None and threading.current_thread() is not threading.main_thread():
        with thread_time_limit(seconds):
            yield
        return
    if not limits or not _alarm_usable():
        yield
        return
    fire_in = max(min(limits), 1e-3)
    deadline_first = until_deadline is not None and (seconds is None or until_deadline < seconds)

    def on_alarm(signum: int, frame: Any) -> None:
        if deadline_first:
            raise _DeadlineAlarm()
        raise EpisodeTimeout(_timeout_message(seconds))

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, fire_in)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def is_transport_error(exc: BaseException) -> bool:
    """EndpointUnavailable itself, or raised from one (``raise X from EndpointUnavailable``)."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, EndpointUnavailable):
            return True
        seen = seen.__cause__
    return False


def _header(case: Case, policy: str, seed: int, backend: str) -> dict[str, Any]:
    # Key fields first so a record reads well in a text editor.
    return {
        "format": RUN_FORMAT,
        "case_id": case.episode_id,
        "seed": seed,
        "policy": policy,
        "backend": backend,
        "difficulty": case.difficulty,
        "n_objects": len(case.objects),
    }


def one_line(exc: BaseException) -> str:
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    return text[:500]


def error_record(
    case: Case,
    policy: str,
    seed: int,
    backend: str,
    kind: ErrorKind,
    message: str,
    trace: str = "",
    timing: Timing | None = None,
) -> EpisodeError:
    """A failed episode's record (also built by the runner, e.g. for a worker that died)."""
    assert kind in ERROR_KINDS, kind
    return EpisodeError(
        **_header(case, policy, seed, backend),
        error_kind=kind,
        error=message[:500],
        traceback=trace,
        timing=timing or Timing(),
    )


@contextmanager
def _player(
    policy: str, kwargs: dict[str, Any], modes: EpisodeModes, via_cell: str | None
) -> Iterator[tuple[Any, EpisodeModes]]:
    """The episode's policy and modes: the policy made here, or the cell service's at
    ``via_cell`` (with the modes that hand it the rendered images)."""
    if via_cell is None:
        yield make_policy(policy, **kwargs), modes
        return
    driver = importlib.import_module(VIA_CELL_MODULE)  # the cell extra, only when asked
    with driver.served_policy(via_cell, policy, kwargs, modes) as pair:
        yield pair


def run_task(
    case: Case,
    policy: str,
    seed: int,
    backend: str,
    physics: Any = None,
    policy_kwargs: dict[str, Any] | None = None,
    *,
    timeout_s: float | None = None,
    deadline: float | None = None,
    modes: EpisodeModes = EXACT_MODES,
    via_cell: str | None = None,
) -> EpisodeRecord:
    """The record of one episode (``EpisodeOk``), or of its failure (``EpisodeError``).

    A fresh policy per episode (``make_policy(policy, **policy_kwargs)``), so no state leaks
    between episodes; policies that hold heavy models cache them per process themselves.
    ``timeout_s`` limits this episode; ``deadline`` (``time.monotonic()``) is the run's end:
    reaching it raises DeadlineReached instead of producing a record. ``modes`` are the
    observation and execution modes (exact by default); ``via_cell``: a cell service's URL.
    """
    started, started_cpu = time.perf_counter(), time.process_time()
    head = _header(case, policy, seed, backend)
    timing: dict[str, Any] = {}
    record: EpisodeRecord
    try:
        with (
            time_limit(timeout_s, deadline),
            _player(policy, policy_kwargs or {}, modes, via_cell) as (player, played),
        ):
            result = run_episode(
                case,
                player,
                seed,
                backend=backend,
                physics=physics,
                perceiver=played.perceiver,
                execution=played.execution,
                sides=played.sides,
                show_remaining=played.show_remaining,
                protocol=played.protocol,
            )
        body = result.to_record()
        # The registry name is the key (a policy object's own ``name`` could differ).
        body["policy"] = policy
        # Typed (and checked) here, from the one dict layout the engine writes.
        record = convert(
            {**head, **body, "timing": {}},
            EpisodeOk,
            f"record of {case.episode_id}/{policy}/seed {seed}",
        )
        step_s = sum(s.wall_time_s for s in result.steps)
        timing = {
            "policy_s": round(result.policy_time_s, 6),
            "env_s": round(step_s, 6),
            "decisions": len(result.steps),
        }
    except _DeadlineAlarm:
        raise DeadlineReached("the run deadline (--deadline) was reached") from None
    except EpisodeTimeout as exc:
        record = error_record(
            case, policy, seed, backend, "timeout", one_line(exc), traceback.format_exc()
        )
        timing = {"timeout_s": timeout_s}
    except Exception as exc:  # noqa: BLE001 - any failure of a policy or engine is data here
        kind: ErrorKind = "transport" if is_transport_error(exc) else "exception"
        record = error_record(
            case, policy, seed, backend, kind, one_line(exc), traceback.format_exc()
        )
    # cpu_s beside the wall time: on a shared machine the wall time also counts time spent
    # waiting for a core, the CPU time only the episode's own work.
    return msgspec.structs.replace(
        record,
        timing=Timing(
            episode_s=round(time.perf_counter() - started, 6),
            cpu_s=round(time.process_time() - started_cpu, 6),
            **timing,
            pid=os.getpid(),
        ),
    )


__all__ = [
    "ERROR_KINDS",
    "DeadlineReached",
    "EpisodeTimeout",
    "Task",
    "error_record",
    "is_transport_error",
    "one_line",
    "run_task",
    "time_limit",
]
