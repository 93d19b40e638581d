"""packlab.executors: the same results on every executor, failures of work and workers, stopping.

The bench's and the data engine's own checks (identical records and datasets on every
executor, the bench's fault records) are in tests/bench and tests/datagen.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import time

import pytest

from packlab import executors
from packlab.core.errors import ConfigError
from packlab.executors import Context, DeadlineReached, Lost, WorkerLost, run_items

ITEMS = list(range(8))


def square(item: int, ctx: Context) -> int:
    ctx.report(("seen", item))
    return item * item


def fail_on_3(item: int, ctx: Context) -> int:
    if item == 3:
        raise ValueError("three is not allowed")
    return item


def unpicklable(item: int, ctx: Context) -> object:
    return lambda: item


def die_on_2(item: int, ctx: Context) -> int:
    if item == 2:
        os.kill(os.getpid(), signal.SIGKILL)
    return item


def hang_on_0(item: int, ctx: Context) -> int:
    if item == 0:
        time.sleep(10**6)  # no alarm of its own: only the pool's hard kill ends it
    return item


def pid(item: int, ctx: Context) -> int:
    return os.getpid()


def slow(item: int, ctx: Context) -> int:
    time.sleep(0.2)
    return item


def started_then_fail_on_1(item: tuple[int, str], ctx: Context) -> int:
    """Leaves a file per started item, so a test can count what ran."""
    number, folder = item
    open(os.path.join(folder, str(number)), "w").close()
    if number == 1:
        raise ValueError("one is not allowed")
    time.sleep(0.3)
    return number


def deadline_seen(item: int, ctx: Context) -> float | None:
    return ctx.deadline


def lost_marker(item: int, lost: Lost) -> tuple:
    return ("lost", item, lost.kind, lost.detail, lost.executor)


@pytest.fixture(autouse=True)
def no_leftover_workers():
    yield
    assert not mp.active_children(), "a worker process outlived its run"


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_every_item_once_with_its_reports(workers):
    reports = []
    with run_items(square, ITEMS, workers=workers, on_report=reports.append) as results:
        out = list(results)
    assert sorted(out) == [i * i for i in ITEMS]
    assert sorted(reports) == [("seen", i) for i in ITEMS]


def test_no_items_is_no_results():
    assert list(run_items(square, [], workers=4)) == []


@pytest.mark.parametrize("workers", [1, 2])
def test_an_exception_of_the_work_reaches_the_caller(workers):
    with (
        pytest.raises(ValueError, match="three is not allowed") as err,
        run_items(fail_on_3, ITEMS, workers=workers) as results,
    ):
        list(results)
    if workers > 1:
        assert any("raised in worker process" in note for note in err.value.__notes__)


def test_a_result_that_cannot_be_pickled_is_an_error_not_a_hang():
    with pytest.raises(Exception, match="pickle"):  # the pickler's own error, from the worker
        list(run_items(unpicklable, ITEMS, workers=2))


def test_a_dead_worker_is_a_lost_item_and_the_rest_still_run():
    out = list(run_items(die_on_2, ITEMS, workers=2, on_lost=lost_marker))
    lost = [r for r in out if isinstance(r, tuple)]
    assert lost == [("lost", 2, "died", "killed by SIGKILL (out of memory?)", "process")]
    assert sorted(r for r in out if not isinstance(r, tuple)) == [i for i in ITEMS if i != 2]


def test_a_dead_worker_without_on_lost_stops_the_run():
    with pytest.raises(WorkerLost, match="killed by SIGKILL"):
        list(run_items(die_on_2, ITEMS, workers=2))


def test_a_silent_worker_is_killed_past_the_time_limit_and_grace(monkeypatch):
    monkeypatch.setattr(executors, "HARD_KILL_GRACE_S", 0.3)
    started = time.monotonic()
    out = list(run_items(hang_on_0, ITEMS, workers=2, timeout_s=0.2, on_lost=lost_marker))
    assert time.monotonic() - started < 10
    assert [r[:3] for r in out if isinstance(r, tuple)] == [("lost", 0, "overdue")]
    assert sorted(r for r in out if not isinstance(r, tuple)) == ITEMS[1:]


def test_recycle_replaces_the_worker_after_a_result():
    kept = set(run_items(pid, ITEMS, workers=2))
    fresh = list(run_items(pid, ITEMS, workers=2, recycle=lambda result: True))
    assert len(kept) <= 2 and len(set(fresh)) == len(ITEMS) and os.getpid() not in fresh


@pytest.mark.parametrize("workers", [1, 2])
def test_the_deadline_stops_the_run(workers):
    done = []
    results = run_items(slow, list(range(40)), workers=workers, deadline=time.monotonic() + 0.5)
    with pytest.raises(DeadlineReached):
        done.extend(results)
    assert 0 < len(done) < 40


def test_close_before_iterating_stops_the_workers():
    results = run_items(slow, ITEMS, workers=2)
    assert len(mp.active_children()) == 2  # forked eagerly, before any thread of the caller
    results.close()
    assert not mp.active_children()


def test_one_worker_runs_in_this_process():
    assert set(run_items(pid, ITEMS, workers=1)) == {os.getpid()}


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"executor": "dask"}, "executor = 'dask'"),
        ({"workers": 0}, "workers = 0"),
    ],
)
def test_bad_options_are_one_line_errors(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        run_items(square, ITEMS, **kwargs)


@pytest.mark.slow
def test_ray_gives_the_same_results_and_reports(ray_cluster):
    reports = []
    out = list(run_items(square, ITEMS, executor="ray", workers=2, on_report=reports.append))
    assert sorted(out) == [i * i for i in ITEMS]
    assert sorted(reports) == [("seen", i) for i in ITEMS]
    with pytest.raises(ValueError, match="three is not allowed"):
        list(run_items(fail_on_3, ITEMS, executor="ray", workers=2))
    out = run_items(die_on_2, ITEMS, executor="ray", workers=2, on_lost=lost_marker)
    lost = [r for r in out if isinstance(r, tuple)]
    assert [r[:3] + r[4:] for r in lost] == [("lost", 2, "died", "ray")]


@pytest.mark.slow
def test_ray_never_cancels_and_starts_only_a_window_of_items(ray_cluster, tmp_path, monkeypatch):
    """ray.cancel racing a task's completion aborts the driver in Ray 2.60 (forced or not;
    benchmarks/maintainers/ray_cancel_race.py): a run stopped early on a caller's cluster
    cancels nothing, and leaves at most its window of tasks in flight instead of every item of
    the run."""
    import ray

    def refuse(*args, **kwargs):
        raise AssertionError("ray.cancel was called")

    monkeypatch.setattr(ray, "cancel", refuse)
    items = [(i, str(tmp_path)) for i in range(20)]
    with pytest.raises(ValueError, match="one is not allowed"):
        list(run_items(started_then_fail_on_1, items, executor="ray", workers=2))
    time.sleep(1.5)  # what was in flight has ended by now (0.3 s each)
    started = sorted(int(f.name) for f in tmp_path.iterdir())
    assert 1 in started and len(started) <= 4, started


@pytest.mark.slow
def test_ray_tasks_get_the_run_deadline_on_their_own_clock(ray_cluster):
    """A caller's cluster is never cancelled into: the work's own alarm (the bench's episode
    alarm) ends a task at the deadline, so the task must know it."""
    deadline = time.monotonic() + 60
    seen = list(run_items(deadline_seen, ITEMS[:2], executor="ray", workers=2, deadline=deadline))
    assert all(d is not None and abs(d - deadline) < 1.0 for d in seen), seen
    assert list(run_items(deadline_seen, ITEMS[:2], executor="ray", workers=2)) == [None, None]


def test_terminate_ends_a_starting_worker_even_under_an_inherited_sigterm_handler():
    """Ray installs a Python SIGTERM handler in its driver; forked workers inherit it. A worker
    stopped before it reset that handler must still end by SIGTERM, not by the SIGKILL backstop
    that follows seconds later."""
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: None)
    try:
        pool = executors._Pool(slow, 2)
        pool.shutdown()  # at once: the workers are still starting
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert [w.proc.exitcode for w in pool.workers] == [-signal.SIGTERM] * 2
