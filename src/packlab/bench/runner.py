"""``packlab bench``: run every (case, policy, seed) episode of a configuration, resumably.

The run directory (DESIGN.md section 6) holds ``config.json`` (resolved, written first),
``cases.jsonl`` (the exact cases, so reports and replays need nothing but the directory),
``episodes.jsonl`` (one record per finished episode, appended as they finish),
``invocations.jsonl`` (when each invocation ran and how long it took), then ``summary.json``,
``table.md`` and the figures, all rebuilt from the records by ``packlab.bench.report``.

Resuming: records already in ``episodes.jsonl`` are the work done. A rerun with the same
identity (see ``config.IDENTITY_KEYS``) runs only the missing keys; a different identity is an
error rather than a silent mix of two configurations in one table. Records of transport errors
(the server was unreachable: no result about the policy) are rerun by any rerun; other failed
records only with ``retry_errors``.

Reusing episodes (``packlab.bench.reuse``): a policy that plays the same episode for every run
seed in the run's modes is played for the lowest seed only; each other seed's record is a copy
of that episode, written as soon as it is recorded (on resuming, from the record already
there). When that episode failed, the other seeds are played after the rest. ``--no-reuse``
plays every seed.

Stopping early (``BenchOutcome.aborted``): after ``max_transport_failures`` consecutive
transport-error episodes (the circuit breaker) or at the run's ``deadline_s``. The workers are
stopped, every record written stays, and the summary and table are written for what finished.
"""

from __future__ import annotations

import fcntl
import importlib
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Self

from packlab.bench.config import ResolvedRun, RunConfig, check_resumable, resolve
from packlab.bench.html_report import ReportUnavailable, write_run_html
from packlab.bench.records import (
    CASES_FILE,
    CONFIG_FILE,
    EPISODES_FILE,
    RecordKey,
    RecordWriter,
    error_kind,
    read_records,
    record_key,
)
from packlab.bench.report import write_outputs
from packlab.bench.reuse import ReusePlan, copyable, reuse_plan, reused_record
from packlab.bench.task import VIA_CELL_MODULE, DeadlineReached, Task, error_record, run_task
from packlab.cases import save_cases
from packlab.core.choices import ErrorKind
from packlab.core.errors import ConfigError, RunAborted
from packlab.core.records import EpisodeError, EpisodeOk, EpisodeRecord, RunSummary, Timing
from packlab.core.types import Case
from packlab.executors import Context, Lost, Results, progress_bar, run_items
from packlab.policies import make_policy
from packlab.sim.modes import EXACT_MODES, EpisodeModes

INVOCATIONS_FILE = "invocations.jsonl"


@dataclass(frozen=True, slots=True)
class BenchOutcome:
    """What a bench invocation did and produced."""

    run_dir: Path
    summary: RunSummary
    table_md: str
    planned: int  # episodes in the configuration
    already_done: int  # found in the records at start (not rerun)
    ran: int  # recorded by this invocation (played, or copied: ``reused``)
    failed: int  # of those, recorded with status "error"
    wall_s: float  # this invocation, start to last record
    outputs: tuple[Path, ...]  # summary, table and figures written
    recorded: int = 0  # episodes of the configuration with a record (ok or error) now
    errors: int = 0  # of those, failed (this and earlier invocations)
    aborted: str = ""  # why the run stopped early (breaker, deadline); "" when it ran to the end
    notes: tuple[str, ...] = ()  # one line each for the user (an output skipped, and why)
    #: Of ``ran``, the episodes copied from another seed's instead of played
    #: (``packlab.bench.reuse``).
    reused: int = 0


def task_keys(run: ResolvedRun) -> dict[RecordKey, Task]:
    """Every episode of the run by record key (the backend name is part of the key)."""
    keys: dict[RecordKey, Task] = {}
    for i, case in enumerate(run.cases):
        for policy in run.policies:
            for seed in run.config.seeds:
                keys[(case.episode_id, seed, policy, run.config.backend)] = Task(i, policy, seed)
    return keys


@dataclass(frozen=True, slots=True)
class EpisodeWork:
    """The bench's work function for ``packlab.executors``: a Task -> its record. Holds what every
    worker needs besides its tasks (the cases go to workers once: by fork or Ray's object store)."""

    cases: tuple[Case, ...]
    backend: str
    physics: Any
    policy_kwargs: dict[str, dict[str, Any]]
    timeout_s: float | None
    modes: EpisodeModes = EXACT_MODES  # the observation / execution modes (exact: empty)
    via_cell: str | None = None  # the cell service whose policies play (None: in-process)

    def __call__(self, task: Task, ctx: Context) -> EpisodeRecord:
        # ctx.deadline is set in this process and on Ray: there the episode's alarm is the only
        # stop (a pool worker is stopped by the pool).
        return run_task(
            self.cases[task.case_index],
            task.policy,
            task.seed,
            self.backend,
            self.physics,
            self.policy_kwargs.get(task.policy),
            timeout_s=self.timeout_s,
            deadline=ctx.deadline,
            modes=self.modes,
            via_cell=self.via_cell,
        )

    def lost(self, task: Task, lost: Lost) -> EpisodeError:
        """The error record of an episode whose worker died or was killed (silent too long)."""
        kind: ErrorKind
        if lost.kind == "overdue":
            kind = "timeout"
            message = (
                f"EpisodeTimeout: no result {lost.elapsed_s:.0f} s after the start, past "
                f"the {self.timeout_s:g} s limit (--episode-timeout) and the alarm; worker "
                f"process killed"
            )
        elif lost.executor == "ray":
            kind, message = "exception", lost.detail
        else:
            kind = "exception"
            message = f"WorkerDied: the worker process running this episode died ({lost.detail})"
        timing = Timing() if lost.elapsed_s is None else Timing(episode_s=round(lost.elapsed_s, 6))
        return error_record(
            self.cases[task.case_index],
            task.policy,
            task.seed,
            self.backend,
            kind,
            message,
            timing=timing,
        )


def is_timeout(record: EpisodeRecord) -> bool:
    """A timed-out episode's worker is replaced: the alarm interrupted the policy at an arbitrary
    point, and a fresh process leaves no half-updated state (a cached model, a socket
    mid-message) to the next episode."""
    return error_kind(record) == "timeout"


def execute(
    run: ResolvedRun, tasks: list[Task], deadline: float | None = None
) -> Results[EpisodeRecord]:
    """Records of ``tasks`` as they finish, on the run's executor and workers."""
    config = run.config
    work = EpisodeWork(
        run.cases,
        config.backend,
        run.physics_config(),
        run.policy_kwargs(),
        config.episode_timeout_s,
        run.episode_modes(),
        config.via_cell,
    )
    return run_items(
        work,
        tasks,
        executor=config.executor,
        workers=run.workers,
        timeout_s=config.episode_timeout_s,
        deadline=deadline,
        on_lost=work.lost,
        recycle=is_timeout,
        concurrency=config.concurrency,
    )


def longest_first(tasks: list[Task], run: ResolvedRun) -> list[Task]:
    """Big cases first, so the last tasks handed out are short and no core idles at the end.

    Episode cost grows with the number of objects (more decisions, larger piles to settle);
    ties keep the configuration's order.
    """
    return sorted(tasks, key=lambda t: -len(run.cases[t.case_index].objects))


def _check_or_write_config(run: ResolvedRun) -> None:
    path = run.out / CONFIG_FILE
    current = run.to_json()
    if path.exists():
        try:
            saved = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ConfigError(
                f"{path}: unreadable ({exc.msg}); not a bench run directory?"
            ) from None
        check_resumable(saved, current, path)
    elif (run.out / EPISODES_FILE).exists():
        raise ConfigError(
            f"{run.out}: has {EPISODES_FILE} but no {CONFIG_FILE}; cannot tell what it ran"
        )
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(current, indent=1) + "\n", encoding="utf-8")
    tmp.replace(path)


def prepare_run_dir(run: ResolvedRun) -> list[EpisodeRecord]:
    """Create or check the run directory; return the records already there for this run."""
    run.out.mkdir(parents=True, exist_ok=True)
    _check_or_write_config(run)
    save_cases(run.cases, run.out / CASES_FILE)
    planned = task_keys(run)
    return [r for r in read_records(run.out / EPISODES_FILE) if record_key(r) in planned]


def preflight_policies(
    names: tuple[str, ...], kwargs: dict[str, dict[str, Any]] | None = None
) -> None:
    """Build each policy once here, so a policy that cannot even be created (missing extra,
    broken import) is one clear error now instead of a failed record for every episode."""
    for name in names:
        try:
            make_policy(name, **(kwargs or {}).get(name, {}))
        except Exception as exc:
            raise ConfigError(
                f"policy = {name!r}: cannot be created ({type(exc).__name__}: {exc})"
            ) from exc


def _log_invocation(
    run: ResolvedRun,
    started: float,
    wall_s: float,
    ran: int,
    failed: int,
    aborted: str = "",
    reused: int = 0,
) -> None:
    entry: dict[str, object] = {
        "started": datetime.fromtimestamp(started, UTC).isoformat(timespec="seconds"),
        "wall_s": round(wall_s, 3),
        "ran": ran,
        "failed": failed,
        "workers": run.workers,
        "executor": run.config.executor,
        "concurrency": run.config.concurrency,
    }
    if reused:  # of ``ran``, the episodes copied from another seed's (packlab.bench.reuse)
        entry["reused"] = reused
    if aborted:
        entry["aborted"] = aborted
    with open(run.out / INVOCATIONS_FILE, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(entry) + "\n")


def needs_rerun(record: EpisodeRecord, retry_errors: bool) -> bool:
    """Whether a record from an earlier invocation is work still to do.

    A transport error is always rerun: it records that a server was unreachable, not what the
    policy does, so a plain rerun once the server is back completes the run. Other failures are
    results of the policy (deterministic more often than not) and rerun only when asked.
    """
    kind = error_kind(record)
    return kind is not None and (retry_errors or kind == "transport")


class TransportBreaker:
    """Counts consecutive transport-error records; trips at ``limit`` (0: never).

    Consecutive in completion order: any other record (a result, or a failure of the policy
    itself) proves the path to the server worked and resets the count.
    """

    def __init__(self, limit: int) -> None:
        self.limit, self.count = limit, 0
        self.last: EpisodeError | None = None

    def observe(self, record: EpisodeRecord) -> bool:
        """Count one record; True when the breaker trips."""
        if isinstance(record, EpisodeError) and record.error_kind == "transport":
            self.count += 1
            self.last = record
        else:
            self.count = 0
        return self.limit > 0 and self.count >= self.limit

    def reason(self) -> str:
        last = self.last
        where = (
            ""
            if last is None
            else f"last: {last.policy} on {last.case_id} seed {last.seed}: {last.error}"
        )
        return (
            f"stopped after {self.count} consecutive transport errors "
            f"(--max-transport-failures {self.limit}); "
            f"{where}"
        )


class RunLock:
    """An exclusive lock on a run directory: two invocations appending to one episodes.jsonl
    would both run the missing episodes and duplicate them. ``flock`` is released by the
    kernel when the holder dies, so a killed run never leaves a stale lock behind."""

    def __init__(self, run_dir: Path) -> None:
        self.path = run_dir / ".lock"
        self._fh: Any = None

    def __enter__(self) -> Self:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.path, "a+", encoding="utf-8")
        try:
            fcntl.flock(self._fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._fh.seek(0)
            holder = self._fh.read().strip() or "?"
            self._fh.close()
            raise ConfigError(
                f"{self.path.parent}: another bench run (pid {holder}) is writing there; "
                f"wait for it or use another --out"
            ) from None
        self._fh.seek(0)
        self._fh.truncate()
        self._fh.write(str(os.getpid()))
        self._fh.flush()
        return self

    def __exit__(self, *exc: object) -> None:
        self._fh.close()  # closing releases the flock


def run_bench(
    config: RunConfig,
    *,
    on_record: Callable[[EpisodeRecord], None] | None = None,
    figures: bool = True,
    html: bool = True,
) -> BenchOutcome:
    """Run (or resume) a bench configuration and write its records, summary, table and figures,
    and (``html``) the interactive report.html; without plotly that is skipped with a note.

    ``on_record`` is called after each new record is safely written (tests use it to interrupt
    a run part-way, exactly where a kill would land). A run stopped early by the circuit
    breaker or the deadline returns normally with ``aborted`` set.
    """
    # The deadline counts from the start of the invocation: loading cases is part of the run.
    deadline = None if config.deadline_s is None else time.monotonic() + config.deadline_s
    run = resolve(config)
    preflight_policies(run.policies, run.policy_kwargs())
    if run.config.via_cell is not None:
        try:  # the cell extra, only when asked
            driver = importlib.import_module(VIA_CELL_MODULE)
        except ImportError as exc:
            raise ConfigError(
                f"via-cell needs the cell extra ({exc.name} not installed): "
                "pip install -e '.[cell]'"
            ) from None
        driver.preflight_service(run.config.via_cell, run.policies)
    with RunLock(run.out):
        return _run_locked(run, on_record, figures, deadline, html)


def _box_progress(
    run: ResolvedRun, planned: dict[RecordKey, Task], done_keys: set[RecordKey]
) -> tuple[dict[RecordKey, int], Any]:
    """Boxes per planned episode and a progress bar that counts boxes placed.

    The largest cases run first (:func:`longest_first`), so a bar counting episodes would make
    its first estimate of the time left several times too long; counted in boxes it holds.
    """
    boxes = {k: len(run.cases[t.case_index].objects) for k, t in planned.items()}
    done = sum(boxes[k] for k in done_keys if k in boxes)
    label = f"bench {run.source.label}"
    return boxes, progress_bar(sum(boxes.values()), done, label, run.config.progress, unit="box")


class _Recorder:
    """Writes one invocation's records and keeps its counts: played records as they arrive
    (the progress bar, the circuit breaker, ``on_record``) and copies of seed-free episodes
    (:mod:`packlab.bench.reuse`) as soon as their lead is recorded."""

    def __init__(
        self,
        run: ResolvedRun,
        writer: RecordWriter,
        latest: dict[RecordKey, EpisodeRecord],
        reuse: ReusePlan,
        on_record: Callable[[EpisodeRecord], None] | None,
    ) -> None:
        self.run, self.writer, self.latest, self.reuse = run, writer, latest, reuse
        self.on_record = on_record
        self.breaker = TransportBreaker(run.config.max_transport_failures)
        self.boxes: dict[RecordKey, int] = {}
        self.bar: Any = None
        self.ran = self.failed = self.reused = 0
        #: Copies waiting for their lead, by the lead's key: (key, task) of each other seed.
        self.waiting: dict[RecordKey, list[tuple[RecordKey, Task]]] = {}
        #: Tasks whose lead could not be copied (it failed): played after the leads.
        self.unmatched: list[Task] = []

    def _write(self, record: EpisodeRecord) -> None:
        self.writer.write(record)
        self.latest[record_key(record)] = record
        if self.bar is not None:
            self.bar.update(self.boxes.get(record_key(record), 0))
        if self.on_record is not None:
            self.on_record(record)

    def played(self, record: EpisodeRecord) -> bool:
        """Write a played episode's record, then any copies of it; True when the circuit
        breaker trips."""
        self.ran += 1
        if isinstance(record, EpisodeError):
            self.failed += 1
            if self.bar is not None:
                self.bar.set_postfix_str(f"{self.failed} failed", refresh=False)
        self._write(record)
        self.follow(record)
        return self.breaker.observe(record)

    def follow(self, lead: EpisodeRecord) -> None:
        """The other seeds waiting for ``lead``: copied where it can stand for them, else
        played after the leads."""
        followers = self.waiting.pop(record_key(lead), [])
        mode = self.reuse.mode
        if mode is None or not followers:
            return
        if not (isinstance(lead, EpisodeOk) and copyable(lead, mode)):
            self.unmatched += [task for _, task in followers]
            return
        case = self.run.cases[followers[0][1].case_index]
        for _, task in followers:
            self.ran += 1
            self.reused += 1
            self._write(reused_record(lead, case, task.seed, mode))

    def plan(self, todo: dict[RecordKey, Task]) -> list[Task]:
        """The tasks to play now; the rest of ``todo`` waits for a lead being played, or is
        copied at once from a lead already recorded (a resumed run)."""
        play: list[Task] = []
        ready: dict[RecordKey, EpisodeRecord] = {}
        for key, task in todo.items():
            if not self.reuse.reuses(task.policy, task.seed):
                play.append(task)
                continue
            lead = (key[0], self.reuse.lead, key[2], key[3])
            self.waiting.setdefault(lead, []).append((key, task))
            if lead not in todo:
                ready[lead] = self.latest[lead]
        for record in ready.values():
            self.follow(record)
        play += self.unmatched
        self.unmatched = []
        return play


def _run_locked(
    run: ResolvedRun,
    on_record: Callable[[EpisodeRecord], None] | None,
    figures: bool,
    deadline: float | None,
    html: bool = True,
) -> BenchOutcome:
    config = run.config
    # Every record of this configuration by key, as a report would read the file: a new record
    # replaces the old one of its key; old failures not rerun (yet) stay in the tables' counts.
    latest = {record_key(r): r for r in prepare_run_dir(run)}
    done_keys = {k for k, r in latest.items() if not needs_rerun(r, config.retry_errors)}
    planned = task_keys(run)
    todo = {k: t for k, t in planned.items() if k not in done_keys}
    reuse = reuse_plan(config, run.policies, run.policy_kwargs())
    aborted = ""
    started_wall, started = time.time(), time.perf_counter()
    recorder: _Recorder | None = None
    if todo:
        with RecordWriter(run.out / EPISODES_FILE) as writer:
            recorder = _Recorder(run, writer, latest, reuse, on_record)
            try:
                # Copies of leads already recorded first, then the leads and every other
                # episode; the other seeds of a lead that failed are played last.
                pending = recorder.plan(todo)
                while pending and not aborted:
                    aborted = _play(run, longest_first(pending, run), recorder, deadline, planned)
                    pending, recorder.unmatched = recorder.unmatched, []
            finally:
                wall_s = time.perf_counter() - started
                _log_invocation(
                    run,
                    started_wall,
                    wall_s,
                    recorder.ran,
                    recorder.failed,
                    aborted,
                    recorder.reused,
                )
    wall_s = time.perf_counter() - started
    records = list(latest.values())
    summary, table_md, outputs = write_outputs(
        run.out, run.to_json(), records, run.cases, figures=figures
    )
    notes: list[str] = []
    if html and records:
        try:
            outputs.append(write_run_html(run.out, run.to_json(), records, run.cases, summary))
        except ReportUnavailable as exc:
            notes.append(f"report.html skipped: {exc}")
    errors = sum(1 for r in records if isinstance(r, EpisodeError))
    return BenchOutcome(
        run.out,
        summary,
        table_md,
        len(planned),
        len(done_keys),
        0 if recorder is None else recorder.ran,
        0 if recorder is None else recorder.failed,
        wall_s,
        tuple(outputs),
        len(records),
        errors,
        aborted,
        tuple(notes),
        0 if recorder is None else recorder.reused,
    )


def _play(
    run: ResolvedRun,
    tasks: list[Task],
    recorder: _Recorder,
    deadline: float | None,
    planned: dict[RecordKey, Task],
) -> str:
    """Play ``tasks`` on the run's workers, recording each result as it arrives; returns why
    the run stopped early ("" when every task finished)."""
    results = execute(run, tasks, deadline)  # workers start (fork) before the bar's thread
    # Done: every planned episode neither played now nor waiting to be copied from one.
    waiting = {key for followers in recorder.waiting.values() for key, _ in followers}
    done = set(planned) - _keys(tasks, run) - waiting
    recorder.boxes, recorder.bar = _box_progress(run, planned, done)
    aborted = ""
    try:
        for record in results:
            if recorder.played(record):
                aborted = recorder.breaker.reason()
                break
    except DeadlineReached:
        aborted = f"stopped at the run deadline (--deadline {run.config.deadline_s:g} s)"
    except RunAborted as exc:
        aborted = str(exc)
    finally:
        recorder.bar.close()
        recorder.bar = None
        results.close()  # stops the workers now when we leave early (breaker, error, interrupt)
    return aborted


def _keys(tasks: list[Task], run: ResolvedRun) -> set[RecordKey]:
    """The record keys of ``tasks``."""
    backend = run.config.backend
    return {(run.cases[t.case_index].episode_id, t.seed, t.policy, backend) for t in tasks}


__all__ = [
    "BenchOutcome",
    "EpisodeWork",
    "RunLock",
    "TransportBreaker",
    "execute",
    "is_timeout",
    "longest_first",
    "needs_rerun",
    "prepare_run_dir",
    "run_bench",
    "task_keys",
]
