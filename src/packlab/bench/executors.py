"""Where bench tasks run: in this process, in a local process pool, or on Ray.

Every executor yields records as episodes finish, in completion order; the caller (the runner's
single writer) appends them. Workers receive the run's cases once (inherited by the fork /
Ray object store) and then only small ``Task`` tuples, so sending work costs microseconds, not
a pickled case per episode.

Stopping: closing the returned iterator (``.close()``, or leaving a ``for`` loop by an
exception) stops every worker at once; episodes in flight are not recorded and run again on
resume. With a ``deadline`` (``time.monotonic()``), no work is handed out after it and the
iterator raises ``DeadlineReached`` once it passes, after stopping the workers.

The local pool is this module's own (one pipe per worker) rather than ``multiprocessing.Pool``
because the parent must know which task each worker holds: a worker that dies (out of memory,
a segfault in an extension) becomes an error record for its task instead of a result that
never arrives, and a worker that stays silent past the episode time limit plus a grace period
(stuck where the alarm cannot reach, e.g. a C loop) is killed and recorded as a timeout.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import sys
import time
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from typing import Any

from packlab.bench.task import DeadlineReached, Task, error_record, run_task
from packlab.core.errors import ConfigError
from packlab.core.types import Case

#: Seconds past the episode time limit after which the pool kills a silent worker. The alarm in
#: the worker normally ends the episode at the limit itself (with a traceback of where it was
#: stuck); this is the backstop for code that signals cannot interrupt.
HARD_KILL_GRACE_S = 10.0
#: At most this many tasks sent ahead to each worker while the queue is long (_Pool.fill).
_PREFETCH = 4
#: How long a stopping worker gets to exit on SIGTERM before SIGKILL.
_STOP_WAIT_S = 2.0


def _share_cores(workers: int) -> None:
    """Give each worker its share of the cores for math libraries (torch, BLAS).

    Without it every worker's torch starts one thread per core, and model policies (``vlm``)
    run several times slower from oversubscription. A user's explicit OMP_NUM_THREADS wins.
    """
    threads = str(max(1, (os.cpu_count() or 1) // max(workers, 1)))
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, threads)
    torch = sys.modules.get("torch")  # already imported by the parent before the fork
    if torch is not None:
        torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))


@dataclass(frozen=True, slots=True)
class _Job:
    """What every worker of one run needs besides its tasks."""

    cases: Sequence[Case]
    backend: str
    physics: Any
    policy_kwargs: dict[str, dict[str, Any]]
    timeout_s: float | None

    def run(self, task: Task, deadline: float | None = None) -> dict[str, Any]:
        return run_task(self.cases[task.case_index], task.policy, task.seed, self.backend, self.physics,
                        self.policy_kwargs.get(task.policy), timeout_s=self.timeout_s, deadline=deadline)

    def failed(self, task: Task, kind: str, message: str, elapsed_s: float | None = None) -> dict[str, Any]:
        timing = {} if elapsed_s is None else {"episode_s": round(elapsed_s, 6)}
        return error_record(self.cases[task.case_index], task.policy, task.seed, self.backend, kind, message,
                            timing=timing)


def run_serial(job: _Job, tasks: Sequence[Task], deadline: float | None = None) -> Iterator[dict[str, Any]]:
    """Episodes one after another in this process (time limits by alarm only)."""
    for t in tasks:
        if deadline is not None and time.monotonic() >= deadline:
            raise DeadlineReached("the run deadline (--deadline) was reached")
        yield job.run(t, deadline)


# -- the local process pool ---------------------------------------------------------------------

def _worker_main(conn: Connection, job: _Job, workers: int) -> None:
    """A worker: receive a Task, send back its record, until told to stop (None) or orphaned."""
    _share_cores(workers)
    # Ctrl-C goes to the whole process group; only the parent should act on it (it stops the
    # workers and keeps every record written so far). Workers dying mid-task would add noise.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = os.getppid()
    while True:
        try:
            # Poll rather than block: a forked worker also holds copies of its siblings' pipe
            # ends, so a parent killed alone would not always show up as end-of-file here.
            while not conn.poll(1.0):
                if os.getppid() != parent:
                    return
            task = conn.recv()
        except (EOFError, OSError):  # the parent is gone
            return
        if task is None:
            return
        conn.send(job.run(task))


def _context() -> mp.context.BaseContext:
    # fork: workers start in milliseconds with the engine and every registered policy already
    # imported (spawn would re-import mujoco and scipy per worker, about a second each, and lose
    # policies registered at run time, e.g. by tests). The runner forks before starting threads.
    methods = mp.get_all_start_methods()
    return mp.get_context("fork" if "fork" in methods else "spawn")


@dataclass(slots=True)
class _Worker:
    proc: Any  # multiprocessing.Process
    conn: Connection
    #: Tasks sent and not yet answered, in order; the first is the one running.
    tasks: deque[Task] = field(default_factory=deque)
    started: float = 0.0  # time.monotonic() when the running task started (as far as we know)


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
    """``n`` worker processes, each with its own pipe and a short list of tasks sent to it."""

    def __init__(self, job: _Job, n: int) -> None:
        self._ctx, self._job, self._n = _context(), job, n
        self.workers = [self._spawn() for _ in range(n)]

    def _spawn(self) -> _Worker:
        parent_end, child_end = self._ctx.Pipe(duplex=True)
        proc = self._ctx.Process(target=_worker_main, args=(child_end, self._job, self._n), daemon=True)
        proc.start()
        child_end.close()  # the parent's copy; the worker's end stays open in the worker
        return _Worker(proc, parent_end)

    def fill(self, queue: deque[Task]) -> None:
        """Send tasks ahead to workers while plenty are left, so a worker starts its next
        episode without waiting for the parent to file the last record (on a busy machine the
        parent may wait milliseconds for a core); fewer near the end, so no short task waits
        behind a long one while another worker idles."""
        for i in range(len(self.workers)):
            w = self.workers[i]
            depth = max(1, min(_PREFETCH, len(queue) // len(self.workers)))
            while len(w.tasks) < depth and queue:
                task = queue.popleft()
                try:
                    w.conn.send(task)
                except OSError:  # the worker died since we last looked
                    queue.appendleft(task)
                    if not w.tasks:  # died idle: nothing to record, just replace it
                        self.replace(i, queue)
                    break  # else _finish records its running task when it sees the death
                w.tasks.append(task)
                if len(w.tasks) == 1:
                    w.started = time.monotonic()

    def collect(self, worker: _Worker) -> tuple[Task, dict[str, Any] | None]:
        """The running task and the record the worker sent for it (None if it died instead)."""
        task = worker.tasks[0]
        try:
            if worker.conn.poll():
                record = worker.conn.recv()
                worker.tasks.popleft()
                worker.started = time.monotonic()  # the next one starts now
                return task, record
        except (EOFError, OSError):
            pass
        return task, None

    def replace(self, index: int, queue: deque[Task]) -> None:
        """Kill worker ``index`` (stuck, dead, or tainted by a timeout), put the tasks it had
        not started back at the front of the queue, and start a fresh worker."""
        w = self.workers[index]
        _stop([w])
        queue.extendleft(reversed(w.tasks))
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
    """Seconds until the next thing to check: the deadline or a busy worker's kill time."""
    times = [] if deadline is None else [deadline]
    if timeout_s is not None:
        times += [w.started + timeout_s + HARD_KILL_GRACE_S for w in pool.workers if w.tasks]
    return None if not times else max(0.0, min(times) - time.monotonic())


def run_pool(job: _Job, tasks: Sequence[Task], workers: int,
             deadline: float | None = None) -> Iterator[dict[str, Any]]:
    """Episodes on ``workers`` processes, in the given order (the runner sorts longest first).

    The workers are forked here, eagerly, before the caller starts any thread (e.g. a progress
    bar's); the generator below only runs once the caller iterates.
    """
    pool = _Pool(job, workers)
    return _drive(pool, job, deque(tasks), deadline)


def _drive(pool: _Pool, job: _Job, queue: deque[Task], deadline: float | None) -> Iterator[dict[str, Any]]:
    try:
        while True:
            if deadline is not None and time.monotonic() >= deadline:
                raise DeadlineReached("the run deadline (--deadline) was reached")
            pool.fill(queue)
            handles = {}
            for i, w in enumerate(pool.workers):
                if w.tasks:
                    handles[w.conn] = handles[w.proc.sentinel] = i
            if not handles:
                return
            ready = {handles[h] for h in wait(list(handles), timeout=_wake_time(pool, job.timeout_s, deadline))}
            for i in sorted(ready):
                yield from _finish(pool, job, i, queue)
            yield from _kill_overdue(pool, job, queue)
    finally:
        # Reached at the end, on an interrupt, or when the consumer stops early: stop workers now.
        pool.shutdown()


def _finish(pool: _Pool, job: _Job, index: int, queue: deque[Task]) -> Iterator[dict[str, Any]]:
    """The record of worker ``index`` (ready to read, or dead)."""
    w = pool.workers[index]
    elapsed = time.monotonic() - w.started
    task, record = pool.collect(w)
    if record is None:
        if w.proc.is_alive():  # a spurious wake-up: nothing to read yet
            return
        w.proc.join()
        w.tasks.popleft()
        record = job.failed(task, "exception", f"WorkerDied: the worker process running this episode died "
                                               f"({_describe_exit(w.proc.exitcode)})", elapsed)
        pool.replace(index, queue)
    elif record.get("error_kind") == "timeout":
        # The alarm interrupted the policy at an arbitrary point; a fresh process leaves no
        # half-updated state (a cached model, a socket mid-message) to the next episode.
        pool.replace(index, queue)
    yield record


def _kill_overdue(pool: _Pool, job: _Job, queue: deque[Task]) -> Iterator[dict[str, Any]]:
    if job.timeout_s is None:
        return
    now = time.monotonic()
    for i, w in enumerate(pool.workers):
        if w.tasks and now - w.started > job.timeout_s + HARD_KILL_GRACE_S:
            task, elapsed = w.tasks.popleft(), now - w.started
            pool.replace(i, queue)
            yield job.failed(task, "timeout",
                             f"EpisodeTimeout: no result {elapsed:.0f} s after the start, past the {job.timeout_s:g} s "
                             f"limit (--episode-timeout) and the alarm; worker process killed", elapsed)


# -- Ray ----------------------------------------------------------------------------------------

def run_ray(job: _Job, tasks: Sequence[Task], workers: int, deadline: float | None = None) -> Iterator[dict[str, Any]]:
    """Episodes as Ray tasks on a local ``ray.init`` (or the cluster already initialised).

    The episode time limit is the same alarm inside each Ray task (Ray runs a task in its
    worker's main thread). The deadline is the driver's: once it passes, every pending task is
    cancelled (``force=True`` kills the worker processes running them).
    """
    try:
        import ray
    except ModuleNotFoundError:
        raise ConfigError("backend-exec = 'ray' needs the ray extra: pip install 'packlab[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    pending: dict[Any, Task] = {}
    try:
        job_ref = ray.put(job)

        @ray.remote(num_cpus=1)
        def remote_task(shared: _Job, task: Task) -> dict[str, Any]:
            return shared.run(task)

        pending = {remote_task.remote(job_ref, t): t for t in tasks}
        while pending:
            wait_s = None if deadline is None else max(0.0, deadline - time.monotonic())
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=wait_s)
            if not ready:
                raise DeadlineReached("the run deadline (--deadline) was reached")
            for ref in ready:
                task = pending.pop(ref)
                try:
                    yield ray.get(ref)
                except ray.exceptions.RayError as exc:  # the worker died; the task is the error
                    message = " ".join(f"{type(exc).__name__}: {exc}".split())
                    yield job.failed(task, "exception", message)
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        if started_here:
            ray.shutdown()


def execute(cases: Sequence[Case], tasks: Sequence[Task], backend: str, physics: Any, workers: int,
            exec_backend: str = "process", policy_kwargs: dict[str, dict[str, Any]] | None = None, *,
            timeout_s: float | None = None, deadline: float | None = None) -> Iterator[dict[str, Any]]:
    """Records of ``tasks`` as they finish, on the chosen executor (see the module docstring)."""
    job = _Job(tuple(cases), backend, physics, policy_kwargs or {}, timeout_s)
    if exec_backend == "ray":
        return run_ray(job, tasks, workers, deadline)
    if workers <= 1 or not tasks:
        # In this process: cheapest, and debuggable, but a worker that dies takes the run with it.
        return run_serial(job, tasks, deadline)
    return run_pool(job, tasks, min(workers, len(tasks)), deadline)


__all__ = ["HARD_KILL_GRACE_S", "execute", "run_pool", "run_ray", "run_serial"]
