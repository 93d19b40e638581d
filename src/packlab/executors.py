"""Where independent work items run: in this process, in a local process pool, or on Ray.

One interface for the bench (an item is an episode) and the data engine (an item is a shard)::

    with run_items(work, items, executor="process", workers=4) as results:
        for result in results:  # in completion order
            ...

``work(item, ctx)`` runs one item and returns its result. ``ctx.report(payload)`` sends a small
progress message to the caller's ``on_report`` (as it happens on a pool, at the item's end on
Ray); ``ctx.deadline`` is the run's deadline (on the running process's ``time.monotonic()``)
where the item runs in this process or on Ray, where nothing else could stop it, and None in a
pool worker, which the executor stops itself.

Executors (``packlab.core.choices.Executor``):
  * ``process`` with ``workers=1``: in this process, one item after another; cheapest and
    debuggable, but a crash takes the run with it.
  * ``process``: this module's own pool of forked workers, one pipe each, a few items sent ahead.
    The parent knows which item each worker holds, so a worker that dies (out of memory, a
    segfault in an extension) is a ``Lost`` item instead of a result that never arrives, and a
    worker silent past ``timeout_s + HARD_KILL_GRACE_S`` (stuck where the item's own alarm
    cannot reach, e.g. a C loop) is killed and its item ``Lost`` too. Fork, so workers start in
    milliseconds with every imported module and registered policy; the pool forks eagerly in
    ``run_items``, so create threads (a progress bar's) only after it returns.
  * ``ray``: one Ray task per item, on the cluster already initialised or a local
    ``ray.init(num_cpus=workers)`` (shut down at the end).

Concurrency: with ``concurrency=N`` above 1 each pool worker runs up to N items at once, each in
a thread of its own (``workers=1`` then means one pool worker, not this process, so that stopping
stays a matter of ending processes). It pays where items mostly wait (a policy asking a model
server over HTTP): while one thread waits on its answer another runs its physics, and the server
sees up to ``workers x N`` requests at once to batch. On Ray each item stays a task of its own,
``1/N`` of a CPU each, ``workers x N`` in flight. An item's time limit in a thread is the work's
own (``packlab.bench.task`` raises in that thread); the hard kill past it ends the whole worker:
its other running items are put back in the queue and run again elsewhere, and after a result
for which ``recycle`` is true the worker gets no new items and is replaced once its running ones
end (replacing it at once would throw their work away).

An exception raised by ``work`` reaches the caller (the pool stops). A lost item becomes
``on_lost(item, lost)``'s result, or without ``on_lost`` raises ``WorkerLost``. After a result
for which ``recycle(result)`` is true, its worker is replaced by a fresh process.

Stopping: ``close()`` (or leaving the ``with`` block, or a ``for`` loop by an exception) stops
every worker at once; items in flight produce nothing. With a ``deadline`` (``time.monotonic()``)
no item starts after it, and the iterator raises ``DeadlineReached`` once it passes, after
stopping the workers (on a caller's Ray cluster, which is never cancelled into, the tasks in
flight stop at their own alarm: Ray passes the deadline to the work as ``ctx.deadline``).
"""

from __future__ import annotations

import ctypes
import itertools
import multiprocessing as mp
import os
import pickle
import signal
import sys
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from multiprocessing.connection import Connection, wait
from typing import Any, Generic, Literal, Protocol, TypeVar

from tqdm import tqdm

from packlab.core.choices import Executor, require_choice
from packlab.core.errors import ConfigError, RunAborted
from packlab.core.stop import (
    adopt_orphans,
    clock_ticks_since_boot,
    descendants,
    end_processes,
    holding_files_under,
    reap,
    started_at_ticks,
)

T = TypeVar("T")
R = TypeVar("R")
T_contra = TypeVar("T_contra", contravariant=True)
R_co = TypeVar("R_co", covariant=True)

#: Seconds past an item's time limit after which the pool kills a silent worker. The item's own
#: alarm normally ends it at the limit itself (with a traceback of where it was stuck); this is
#: the backstop for code that signals cannot interrupt.
HARD_KILL_GRACE_S = 10.0
#: At most this many items sent ahead to each worker while the queue is long (_Pool.fill).
_PREFETCH = 4
#: How long a stopping worker gets to exit on SIGTERM before SIGKILL.
_STOP_WAIT_S = 2.0
#: Most items one worker runs at once (``concurrency``): threads share the worker's one core.
MAX_CONCURRENCY = 64
#: Kinds of the messages a worker sends its parent.
_REPORT, _DONE, _RAISED = "report", "done", "raised"


class DeadlineReached(RunAborted):
    """The run's overall deadline passed; items in flight were dropped."""


class WorkerLost(RunAborted):
    """A worker died (or was killed, silent past its time limit) while running an item."""


@dataclass(frozen=True, slots=True)
class Context:
    """What a work function gets besides its item."""

    #: The run's deadline (``time.monotonic()``) when the item runs in this process, else None.
    deadline: float | None
    #: Send a progress payload (small, picklable) to the caller's ``on_report``.
    report: Callable[[Any], None]


class Work(Protocol[T_contra, R_co]):
    """A function of one item (picklable for Ray; inherited by fork for the pool)."""

    def __call__(self, item: T_contra, ctx: Context, /) -> R_co: ...


@dataclass(frozen=True, slots=True)
class Lost:
    """Why an item has no result: its worker ``died``, or stayed silent past the item's time
    limit and the grace period (``overdue``) and was killed."""

    kind: Literal["died", "overdue"]
    #: "killed by SIGKILL (out of memory?)", "exit code 1", a Ray error's one-line text, or
    #: "no result 12 s after the start".
    detail: str
    elapsed_s: float | None  # from the item's start to the loss, as far as the parent knows
    executor: Executor


def _ignore(payload: Any) -> None:
    pass


class Results(Generic[R]):
    """The results of ``run_items`` as they finish; ``close()`` stops the workers (even when
    iteration never started)."""

    def __init__(self, results: Iterator[R], stop: Callable[[], None] = lambda: None) -> None:
        self._results, self._stop = results, stop

    def __iter__(self) -> Iterator[R]:
        return self

    def __next__(self) -> R:
        return next(self._results)

    def close(self) -> None:
        close = getattr(self._results, "close", None)
        if close is not None:
            close()
        self._stop()

    def __enter__(self) -> Results[R]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def run_items(
    work: Work[T, R],
    items: Sequence[T],
    *,
    executor: Executor = "process",
    workers: int = 1,
    timeout_s: float | None = None,
    deadline: float | None = None,
    on_report: Callable[[Any], None] | None = None,
    on_lost: Callable[[T, Lost], R] | None = None,
    recycle: Callable[[R], bool] | None = None,
    concurrency: int = 1,
) -> Results[R]:
    """The results of ``work`` on every item, in completion order (see the module docstring).

    Items are handed out in the given order (put long ones first for a balanced end).
    ``timeout_s`` is each item's own time limit, enforced by ``work`` (an alarm); the pool adds
    the hard kill past it. ``workers`` counts processes, or Ray CPUs when it starts Ray;
    ``concurrency`` is how many items each runs at once.
    """
    require_choice(executor, Executor, "executor")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers = {workers!r}: must be a whole number >= 1")
    check_concurrency(concurrency)
    report = on_report or _ignore
    lose = on_lost or _raise_lost
    if executor == "ray":
        _import_ray()  # a missing extra is an error now, not at the first result
        return Results(_run_ray(work, items, workers, deadline, report, lose, concurrency))
    if (workers == 1 and concurrency == 1) or not items:
        return Results(_run_here(work, items, deadline, report))
    pool = _Pool(work, min(workers, len(items)), concurrency)
    running = _drive(pool, deque(items), timeout_s, deadline, report, lose, recycle)
    return Results(running, pool.shutdown)


def check_concurrency(concurrency: int) -> None:
    """ConfigError unless ``concurrency`` is a whole number from 1 to MAX_CONCURRENCY."""
    if (
        isinstance(concurrency, bool)
        or not isinstance(concurrency, int)
        or not 1 <= concurrency <= MAX_CONCURRENCY
    ):
        raise ConfigError(
            f"concurrency = {concurrency!r}: must be a whole number from 1 to {MAX_CONCURRENCY}"
        )


def progress_bar(
    total: int, initial: int, desc: str, enabled: bool = True, unit: str = "ep"
) -> Any:
    """tqdm on stderr; create it after ``run_items`` returned (the pool forks first)."""
    return tqdm(
        total=total,
        initial=initial,
        desc=desc,
        unit=unit,
        file=sys.stderr,
        disable=not enabled,
        dynamic_ncols=True,
        smoothing=0.05,
    )


def _raise_lost(item: Any, lost: Lost) -> Any:
    raise WorkerLost(
        f"a worker ({lost.executor}) was lost running {item!r}: {lost.kind}, {lost.detail}"
    )


def _deadline_passed(deadline: float | None) -> None:
    if deadline is not None and time.monotonic() >= deadline:
        raise DeadlineReached("the run deadline was reached")


def _run_here(
    work: Work[T, R], items: Sequence[T], deadline: float | None, report: Callable[[Any], None]
) -> Iterator[R]:
    ctx = Context(deadline, report)
    for item in items:
        _deadline_passed(deadline)
        yield work(item, ctx)


# -- the local process pool ---------------------------------------------------------------------


def share_cores(workers: int) -> None:
    """Give each of ``workers`` processes its share of the cores for math libraries (torch, BLAS).

    Without it every worker's torch starts one thread per core, and model policies run several
    times slower from oversubscription. A user's explicit OMP_NUM_THREADS wins.
    """
    threads = str(max(1, (os.cpu_count() or 1) // max(workers, 1)))
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, threads)
    torch = sys.modules.get("torch")  # already imported by the parent before the fork
    if torch is not None:
        torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))


def _portable(exc: Exception) -> Exception:
    """``exc`` with the worker's traceback as a note (a RuntimeError if it cannot be pickled)."""
    note = f"raised in worker process {os.getpid()}:\n{traceback.format_exc()}"
    try:
        exc.add_note(note)
        pickle.dumps(exc)
        return exc
    except Exception:  # noqa: BLE001 - anything that does not survive the pipe
        plain = RuntimeError(f"{type(exc).__name__}: {exc}")
        plain.add_note(note)
        return plain


def _worker_main(
    conn: Connection, work: Work[Any, Any], workers: int, concurrency: int = 1
) -> None:
    """A worker: receive an item, send back its reports and result, until orphaned or stopped.
    Messages carry the item's sequence number: with ``concurrency`` above 1 results come back
    in the order the items end, not the order they were sent."""
    share_cores(workers)
    # Ctrl-C goes to the whole process group; only the parent should act on it (it stops the
    # workers and keeps every result so far). Workers dying mid-item would add noise.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # The default action for terminate(): the worker holds nothing that needs a clean exit.
    # The parent blocked SIGTERM across the fork (_Pool._spawn); one sent meanwhile lands now.
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGTERM})
    parent = os.getppid()
    die_with_parent(parent)
    if concurrency > 1:
        _serve_threads(conn, work, parent, concurrency)
        return
    while (received := _receive(conn, parent)) is not None:
        seq, item = received
        ctx = Context(None, partial(_send_report, conn, seq))
        try:
            message = (_DONE, seq, work(item, ctx))
        except Exception as exc:  # noqa: BLE001 - the caller decides what an exception means
            message = (_RAISED, seq, _portable(exc))
        try:
            conn.send(message)
        except OSError:  # the parent is gone
            return
        except Exception as exc:  # noqa: BLE001 - the result cannot be pickled
            conn.send((_RAISED, seq, _portable(exc)))


def _receive(conn: Connection, parent: int) -> tuple[int, Any] | None:
    """The next (sequence number, item) from the parent; None once the parent is gone."""
    try:
        # Poll rather than block: a forked worker also holds copies of its siblings' pipe
        # ends, so a parent killed alone would not always show up as end-of-file here.
        while not conn.poll(1.0):
            if os.getppid() != parent:
                return None
        received: tuple[int, Any] = conn.recv()
        return received
    except (EOFError, OSError):  # the parent is gone
        return None


def _send_report(conn: Any, seq: int, payload: Any) -> None:
    """A progress report of item ``seq`` to the parent (each item's own sender)."""
    conn.send((_REPORT, seq, payload))


def _serve_threads(conn: Connection, work: Work[Any, Any], parent: int, concurrency: int) -> None:
    """Run up to ``concurrency`` items at once, one thread each, in the order received; the
    main thread only receives. One lock keeps the threads' messages whole on the pipe."""
    lock = threading.Lock()

    def send(message: tuple[str, int, Any]) -> None:
        with lock:
            try:
                conn.send(message)
            except OSError:  # the parent is gone: nobody wants the other items either
                os._exit(0)
            except Exception as exc:  # noqa: BLE001 - the result cannot be pickled
                conn.send((_RAISED, message[1], _portable(exc)))

    def run(seq: int, item: Any) -> None:
        ctx = Context(None, lambda payload: send((_REPORT, seq, payload)))
        try:
            message = (_DONE, seq, work(item, ctx))
        except BaseException as exc:  # noqa: BLE001 - a thread's exception would vanish
            plain = exc if isinstance(exc, Exception) else RuntimeError(repr(exc))
            message = (_RAISED, seq, _portable(plain))
        send(message)

    threads = ThreadPoolExecutor(concurrency, thread_name_prefix="packlab-item")
    while (received := _receive(conn, parent)) is not None:
        threads.submit(run, *received)
    # The parent is gone: end now rather than wait for the running items (their results have
    # nowhere to go), which a normal return would, joining the threads.
    os._exit(0)


#: Linux's prctl option that delivers a signal to a process when its parent dies.
_PR_SET_PDEATHSIG = 1
#: How often a worker without prctl checks that its parent is alive.
_ORPHAN_CHECK_S = 1.0


def die_with_parent(parent: int) -> None:
    """End this worker when ``parent`` dies, whatever the worker is doing at the time.

    The parent stops its workers itself on any exit it can see (an exception, SIGINT, SIGTERM:
    ``packlab.core.stop``), but not on SIGKILL or a crash; a worker busy in an item (a long
    episode, a C loop) would not notice until the item ends. On Linux the kernel sends SIGKILL
    the moment the parent dies (prctl PR_SET_PDEATHSIG); elsewhere a daemon thread checks the
    parent's pid every second and exits the process.
    """
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0:
                if os.getppid() != parent:  # died before the prctl took effect
                    os._exit(1)
                return
        except (OSError, AttributeError):
            pass  # no prctl in this libc: fall back to the watchdog

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(_ORPHAN_CHECK_S)
        os._exit(1)

    threading.Thread(target=watch, name="packlab-orphan-watch", daemon=True).start()


def _context() -> mp.context.ForkContext | mp.context.SpawnContext:
    # fork: workers start in milliseconds with the engine and every registered policy already
    # imported (spawn would re-import mujoco and scipy per worker, about a second each, and lose
    # policies registered at run time, e.g. by tests). run_items forks before threads start.
    if "fork" in mp.get_all_start_methods():
        return mp.get_context("fork")
    return mp.get_context("spawn")


@dataclass(slots=True)
class _Worker:
    proc: Any  # multiprocessing.Process
    conn: Connection
    #: Items sent and not yet answered, by sequence number in the order sent; the worker runs
    #: the first ``concurrency`` of them and starts the next one as one ends.
    items: dict[int, Any] = field(default_factory=dict)
    #: time.monotonic() when each running item started (as far as the parent knows).
    started: dict[int, float] = field(default_factory=dict)
    #: Gets no new items and is replaced once its items are done (``recycle``, concurrency > 1).
    retiring: bool = False


def _describe_exit(code: int | None) -> str:
    if code is not None and code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        hint = " (out of memory?)" if -code == signal.SIGKILL else ""
        return f"killed by {name}{hint}"
    return f"exit code {code}"


class _Pool:
    """``n`` worker processes, each with its own pipe and a short list of items sent to it,
    each running up to ``concurrency`` of them at once."""

    def __init__(self, work: Work[Any, Any], n: int, concurrency: int = 1) -> None:
        self._ctx, self._work, self._n = _context(), work, n
        self.concurrency = concurrency
        self._seq = itertools.count()
        self.workers = [self._spawn() for _ in range(n)]

    def _spawn(self) -> _Worker:
        parent_end, child_end = self._ctx.Pipe(duplex=True)
        proc = self._ctx.Process(
            target=_worker_main,
            args=(child_end, self._work, self._n, self.concurrency),
            daemon=True,
        )
        # SIGTERM stays blocked across the fork until the child has reset its handler: a
        # handler inherited from this process (Ray installs one) would otherwise swallow a
        # terminate() sent while the child is still starting, leaving it for the SIGKILL wait.
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})
        try:
            proc.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        child_end.close()  # the parent's copy; the worker's end stays open in the worker
        return _Worker(proc, parent_end)

    def fill(self, queue: deque[Any]) -> None:
        """Send items ahead to workers while plenty are left, so a worker starts its next item
        without waiting for the parent to take the last result (on a busy machine the parent
        may wait milliseconds for a core); fewer near the end, so no short item waits behind a
        long one while another worker idles."""
        n = self.concurrency
        for i in range(len(self.workers)):
            w = self.workers[i]
            if w.retiring:
                continue
            depth = max(n, min(n + _PREFETCH - 1, len(queue) // len(self.workers)))
            while len(w.items) < depth and queue:
                item = queue.popleft()
                seq = next(self._seq)
                try:
                    w.conn.send((seq, item))
                except OSError:  # the worker died since we last looked
                    queue.appendleft(item)
                    if not w.items:  # died idle: nothing lost, just replace it
                        self.replace(i, queue)
                    break  # else _finish reports its running items when it sees the death
                w.items[seq] = item
                self.start_next(w)

    def start_next(self, worker: _Worker) -> None:
        """Mark the items the worker runs now as started: the first ``concurrency`` sent."""
        now = time.monotonic()
        for seq in worker.items:
            if len(worker.started) >= self.concurrency:
                return
            worker.started.setdefault(seq, now)

    def messages(self, worker: _Worker) -> Iterator[tuple[str, int, Any]]:
        """The messages waiting on the worker's pipe (none once it is closed by a death)."""
        try:
            while worker.conn.poll():
                yield worker.conn.recv()
        except (EOFError, OSError):
            return

    def replace(self, index: int, queue: deque[Any]) -> None:
        """Kill worker ``index`` (stuck, dead, or to be recycled), put the items it still had
        back at the front of the queue, and start a fresh worker."""
        w = self.workers[index]
        _stop([w])
        queue.extendleft(reversed(list(w.items.values())))
        self.workers[index] = self._spawn()

    def shutdown(self) -> None:
        _stop(self.workers)


def _stop(workers: list[_Worker]) -> None:
    for w in workers:
        if w.proc.is_alive():
            w.proc.terminate()
    until = time.monotonic() + _STOP_WAIT_S
    for w in workers:
        w.proc.join(max(0.0, until - time.monotonic()))
        if w.proc.is_alive():
            w.proc.kill()
            w.proc.join()
        w.conn.close()


def _wake_time(pool: _Pool, timeout_s: float | None, deadline: float | None) -> float | None:
    """Seconds until the next thing to check: the deadline or a running item's kill time."""
    times = [] if deadline is None else [deadline]
    if timeout_s is not None:
        limit = timeout_s + HARD_KILL_GRACE_S
        times += [t + limit for w in pool.workers for t in w.started.values()]
    return None if not times else max(0.0, min(times) - time.monotonic())


def _drive(
    pool: _Pool,
    queue: deque[T],
    timeout_s: float | None,
    deadline: float | None,
    report: Callable[[Any], None],
    lose: Callable[[T, Lost], R],
    recycle: Callable[[R], bool] | None,
) -> Iterator[R]:
    try:
        while True:
            _deadline_passed(deadline)
            pool.fill(queue)
            handles = {}
            for i, w in enumerate(pool.workers):
                if w.items:
                    handles[w.conn] = handles[w.proc.sentinel] = i
            if not handles:
                return
            wake = _wake_time(pool, timeout_s, deadline)
            ready = {handles[h] for h in wait(list(handles), timeout=wake)}
            for i in sorted(ready):
                yield from _finish(pool, i, queue, report, lose, recycle)
            yield from _kill_overdue(pool, queue, timeout_s, lose)
    finally:
        # Reached at the end, on an interrupt, or when the consumer stops early: stop workers now.
        pool.shutdown()


def _finish(
    pool: _Pool,
    index: int,
    queue: deque[T],
    report: Callable[[Any], None],
    lose: Callable[[T, Lost], R],
    recycle: Callable[[R], bool] | None,
) -> Iterator[R]:
    """The results of worker ``index`` (ready to read, or dead)."""
    w = pool.workers[index]
    for kind, seq, payload in pool.messages(w):
        if kind == _REPORT:
            report(payload)
            continue
        if kind == _RAISED:
            raise payload
        del w.items[seq]
        w.started.pop(seq, None)
        pool.start_next(w)  # the next one starts now
        if recycle is not None and recycle(payload):
            # E.g. an alarm interrupted the item at an arbitrary point; a fresh process leaves
            # no half-updated state (a cached model, a socket mid-message) to the next item.
            if pool.concurrency == 1:
                pool.replace(index, queue)
                yield payload
                return
            w.retiring = True  # its other running items end first (module docstring)
        yield payload
    if w.retiring and not w.items:
        pool.replace(index, queue)
    elif w.items and not w.proc.is_alive():
        yield from _lose_dead(pool, index, queue, lose)


def _lose_dead(
    pool: _Pool, index: int, queue: deque[T], lose: Callable[[T, Lost], R]
) -> Iterator[R]:
    """The items a dead worker was running, each lost; the ones it had not started go back to
    the queue. Which of several running items killed it cannot be told, so all are lost."""
    w = pool.workers[index]
    w.proc.join()
    now = time.monotonic()
    running = [(w.items.pop(seq), now - started) for seq, started in w.started.items()]
    detail = _describe_exit(w.proc.exitcode)
    pool.replace(index, queue)
    for item, elapsed in running:
        yield lose(item, Lost("died", detail, elapsed, "process"))


def _kill_overdue(
    pool: _Pool, queue: deque[T], timeout_s: float | None, lose: Callable[[T, Lost], R]
) -> Iterator[R]:
    if timeout_s is None:
        return
    now = time.monotonic()
    for i, w in enumerate(pool.workers):
        limit = timeout_s + HARD_KILL_GRACE_S
        overdue = [(seq, now - t) for seq, t in w.started.items() if now - t > limit]
        if not overdue:
            continue
        # The whole worker goes; its other items (running or not) are put back in the queue.
        lost = [(w.items.pop(seq), elapsed) for seq, elapsed in overdue]
        pool.replace(i, queue)
        for item, elapsed in lost:
            detail = f"no result {elapsed:.0f} s after the start"
            yield lose(item, Lost("overdue", detail, elapsed, "process"))


# -- Ray ----------------------------------------------------------------------------------------


def _import_ray() -> Any:
    try:
        import ray
    except ModuleNotFoundError:
        raise ConfigError(
            "executor = 'ray' needs the ray extra: pip install 'packlab[ray]'"
        ) from None
    return ray


def _on_ray(work: Work[T, R], item: T, deadline_wall: float | None) -> tuple[R, list[Any]]:
    """One item in a Ray worker: its result and its reports (delivered when it ends).

    The run's deadline travels as wall-clock time (a worker on another node has its own
    monotonic clock) and reaches the work as ``ctx.deadline`` on this worker's clock: the
    item's own alarm is what ends it there, since the driver never cancels a Ray task."""
    reports: list[Any] = []
    deadline = None if deadline_wall is None else time.monotonic() + deadline_wall - time.time()
    return work(item, Context(deadline, reports.append)), reports


def _run_ray(
    work: Work[T, R],
    items: Sequence[T],
    workers: int,
    deadline: float | None,
    report: Callable[[Any], None],
    lose: Callable[[T, Lost], R],
    concurrency: int = 1,
) -> Iterator[R]:
    """Items as Ray tasks, at most ``workers x concurrency`` submitted at a time. Time limits
    inside an item work as in a pool (Ray runs a task in its worker's main thread), and so does
    the deadline, which each task gets as ``ctx.deadline``.

    No task is ever cancelled: in Ray 2.60 ``ray.cancel`` racing a task's completion aborts
    the driver ("Tried to complete task that was not pending", exit 1), forced or not
    (benchmarks/maintainers/ray_cancel_race.py reproduces it). When the run stops early, a
    cluster started here is shut down whole; on a caller's cluster the few tasks in flight run on
    until they end or reach their own time limit or the deadline, and the items never submitted
    never start."""
    ray = _import_ray()
    started_here = not ray.is_initialized()
    before_ray: set[int] = set()
    ray_started_ticks: int | None = None
    if started_here:
        # ray.init replaces the SIGINT and SIGTERM handlers with its own (log, shut down, exit
        # with the signal's number); keep the caller's (packlab.core.stop), so a stop request
        # runs this function's cleanup and the command exits with its documented code.
        handlers = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
        before_ray = set(descendants(os.getpid()))  # the caller's own children are not Ray's
        ray_started_ticks = clock_ticks_since_boot()
        # Orphans become ours, not init's: an agent whose raylet ends first stays findable.
        adopt_orphans(True)
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        if threading.current_thread() is threading.main_thread():
            for signum, handler in handlers.items():
                if handler is not None:
                    signal.signal(signum, handler)
    pending: dict[Any, T] = {}
    try:
        work_ref = ray.put(work)  # once, not once per item (the bench's cases, a dataset config)
        remote = ray.remote(num_cpus=1 / concurrency)(_on_ray)
        deadline_wall = None if deadline is None else time.time() + deadline - time.monotonic()
        waiting = iter(items)

        def submit(n: int) -> None:
            if deadline is not None and time.monotonic() >= deadline:
                return  # no item starts after the deadline
            for item in itertools.islice(waiting, n):
                pending[remote.remote(work_ref, item, deadline_wall)] = item

        # A window of `workers x concurrency` tasks: what is still in flight when the run
        # stops is bounded by them, never the whole run (nothing is cancelled, see above).
        submit(workers * concurrency)
        while pending:
            wait_s = None if deadline is None else max(0.0, deadline - time.monotonic())
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=wait_s)
            if not ready:
                raise DeadlineReached("the run deadline was reached")
            for ref in ready:
                item = pending.pop(ref)
                submit(1)
                try:
                    result, reports = ray.get(ref)
                except ray.exceptions.RayTaskError:
                    raise  # the work function raised: also an instance of its exception's class
                except ray.exceptions.RayError as exc:  # the worker died
                    detail = " ".join(f"{type(exc).__name__}: {exc}".split())
                    yield lose(item, Lost("died", detail, None, "ray"))
                    continue
                for payload in reports:
                    report(payload)
                yield result
    finally:
        _end_ray(ray, started_here, before_ray, ray_started_ticks)


def _end_ray(
    ray: Any, started_here: bool, before_ray: set[int], ray_started_ticks: int | None
) -> None:
    """When this run started Ray, shut it down and end what it started. A caller's cluster is
    left as it is (its tasks in flight end by themselves, see _run_ray). The last step runs
    whatever the one before raised (a shutdown interrupted by the stop itself): ending what
    Ray started here is what keeps a stopped run from leaving processes behind."""
    if not started_here:
        return
    # Ray's per-node agents (dashboard, runtime env) outlive ray.shutdown() by seconds once
    # their raylet is gone, no longer our descendants by then: end what Ray started here by
    # pid after its own shutdown.
    started = set(descendants(os.getpid(), skip=before_ray))
    session = _ray_session_dir(ray)
    try:
        ray.shutdown()
    finally:
        # An agent whose raylet ended before the snapshot was no longer our descendant: it is
        # still found by the session's logs it keeps open. Only processes younger than this
        # ray.init: never this process's ancestors, nor another program that happens to read
        # Ray's logs.
        if session is not None and ray_started_ticks is not None:
            started |= {
                p
                for p in holding_files_under(session)
                if (started_at_ticks(p) or 0) >= ray_started_ticks
            } - before_ray
        # What Ray left, adopted by this process once its parent ended (adopt_orphans).
        started |= set(descendants(os.getpid(), skip=before_ray))
        ended = sorted(started - {os.getpid()})
        end_processes(ended)
        reap(ended)
        adopt_orphans(False)


def _ray_session_dir(ray: Any) -> str | None:
    """This process's Ray session directory (None when Ray does not say: a private API that a
    Ray release may move; the cleanup then relies on the descendants snapshot alone)."""
    try:
        return str(ray._private.worker._global_node.get_session_dir_path())
    except Exception:  # noqa: BLE001 - any failure means "unknown", never an error
        return None


__all__ = [
    "HARD_KILL_GRACE_S",
    "MAX_CONCURRENCY",
    "Context",
    "DeadlineReached",
    "Lost",
    "Results",
    "Work",
    "WorkerLost",
    "check_concurrency",
    "die_with_parent",
    "progress_bar",
    "run_items",
    "share_cores",
]
