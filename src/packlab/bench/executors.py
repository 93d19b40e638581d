"""Where bench tasks run: in this process, in a local process pool, or on Ray.

Every executor yields records as episodes finish, in completion order; the caller (the runner's
single writer) appends them. Workers receive the run's cases once (pool initializer / Ray object
store) and then only small ``Task`` tuples, so sending work costs microseconds, not a pickled
case per episode.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import sys
from collections.abc import Iterator, Sequence
from typing import Any

from packlab.bench.task import Task, run_task
from packlab.errors import ConfigError
from packlab.types import Case

# Per-worker state, set once by the pool initializer.
_CASES: Sequence[Case] = ()
_BACKEND = "mujoco"
_PHYSICS: Any = None
_POLICY_KWARGS: dict[str, dict[str, Any]] = {}


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


def _init_worker(cases: Sequence[Case], backend: str, physics: Any, policy_kwargs: dict[str, dict[str, Any]],
                 workers: int = 1) -> None:
    global _CASES, _BACKEND, _PHYSICS, _POLICY_KWARGS
    _CASES, _BACKEND, _PHYSICS, _POLICY_KWARGS = cases, backend, physics, policy_kwargs
    _share_cores(workers)
    # Ctrl-C goes to the whole process group; only the parent should act on it (it stops the
    # pool and keeps every record written so far). Workers dying mid-task would just add noise.
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _pool_run(task: Task) -> dict[str, Any]:
    return run_task(_CASES[task.case_index], task.policy, task.seed, _BACKEND, _PHYSICS,
                    _POLICY_KWARGS.get(task.policy))


def run_serial(cases: Sequence[Case], tasks: Sequence[Task], backend: str, physics: Any,
               policy_kwargs: dict[str, dict[str, Any]]) -> Iterator[dict[str, Any]]:
    for t in tasks:
        yield run_task(cases[t.case_index], t.policy, t.seed, backend, physics, policy_kwargs.get(t.policy))


def _context() -> mp.context.BaseContext:
    # fork: workers start in milliseconds with the engine and every registered policy already
    # imported (spawn would re-import mujoco and scipy per worker, about a second each, and lose
    # policies registered at run time, e.g. by tests). The runner forks before starting threads.
    methods = mp.get_all_start_methods()
    return mp.get_context("fork" if "fork" in methods else "spawn")


def run_pool(cases: Sequence[Case], tasks: Sequence[Task], backend: str, physics: Any,
             policy_kwargs: dict[str, dict[str, Any]], workers: int) -> Iterator[dict[str, Any]]:
    """Episodes on ``workers`` processes, one task at a time per worker.

    ``chunksize=1``: episodes take 10 ms to seconds, so dispatch overhead is noise and handing
    out one at a time keeps every core busy to the end (the tasks come longest first). The pool
    is forked here, eagerly, before the caller starts any thread (e.g. a progress bar's).
    """
    pool = _context().Pool(workers, initializer=_init_worker, initargs=(tuple(cases), backend, physics, policy_kwargs, workers))
    return _drain(pool, pool.imap_unordered(_pool_run, tasks, chunksize=1))


def _drain(pool: Any, results: Iterator[dict[str, Any]]) -> Iterator[dict[str, Any]]:
    try:
        yield from results
        pool.close()
        pool.join()
    finally:
        # Reached early on an interrupt or an error in the consumer: stop the workers now.
        pool.terminate()
        pool.join()


def run_ray(cases: Sequence[Case], tasks: Sequence[Task], backend: str, physics: Any,
            policy_kwargs: dict[str, dict[str, Any]], workers: int) -> Iterator[dict[str, Any]]:
    """Episodes as Ray tasks on a local ``ray.init`` (or the cluster already initialised)."""
    try:
        import ray
    except ModuleNotFoundError:
        raise ConfigError("backend-exec = 'ray' needs the ray extra: pip install 'packlab[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    try:
        cases_ref = ray.put(tuple(cases))

        @ray.remote(num_cpus=1)
        def remote_task(all_cases: Sequence[Case], task: Task) -> dict[str, Any]:
            return run_task(all_cases[task.case_index], task.policy, task.seed, backend, physics,
                            policy_kwargs.get(task.policy))

        pending = [remote_task.remote(cases_ref, t) for t in tasks]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                yield ray.get(ref)
    finally:
        if started_here:
            ray.shutdown()


def execute(cases: Sequence[Case], tasks: Sequence[Task], backend: str, physics: Any, workers: int,
            exec_backend: str = "process",
            policy_kwargs: dict[str, dict[str, Any]] | None = None) -> Iterator[dict[str, Any]]:
    """Records of ``tasks`` as they finish, on the chosen executor."""
    kwargs = policy_kwargs or {}
    if exec_backend == "ray":
        return run_ray(cases, tasks, backend, physics, kwargs, workers)
    if workers <= 1 or len(tasks) <= 1:
        return run_serial(cases, tasks, backend, physics, kwargs)
    return run_pool(cases, tasks, backend, physics, kwargs, min(workers, len(tasks)))


__all__ = ["execute", "run_pool", "run_ray", "run_serial"]
