"""``packlab bench``: run every (case, policy, seed) episode of a configuration, resumably.

The run directory (DESIGN.md section 6) holds ``config.json`` (resolved, written first),
``cases.jsonl`` (the exact cases, so reports and replays need nothing but the directory),
``episodes.jsonl`` (one record per finished episode, appended as they finish),
``invocations.jsonl`` (when each invocation ran and how long it took), then ``summary.json``,
``table.md`` and the figures, all rebuilt from the records by ``packlab.bench.report``.

Resuming: records already in ``episodes.jsonl`` are the work done. A rerun with the same
identity (see ``config.IDENTITY_KEYS``) runs only the missing keys; a different identity is an
error rather than a silent mix of two configurations in one table.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Self

from packlab.bench.config import ResolvedRun, RunConfig, check_resumable, resolve
from packlab.bench.executors import execute
from packlab.bench.records import (
    CASES_FILE,
    CONFIG_FILE,
    EPISODES_FILE,
    RecordKey,
    RecordWriter,
    read_records,
    record_key,
)
from packlab.bench.task import Task
from packlab.cases import save_cases
from packlab.errors import ConfigError

INVOCATIONS_FILE = "invocations.jsonl"


@dataclass(frozen=True, slots=True)
class BenchOutcome:
    """What a bench invocation did and produced."""

    run_dir: Path
    summary: dict[str, Any]
    table_md: str
    planned: int  # episodes in the configuration
    already_done: int  # found in the records at start (not rerun)
    ran: int  # run by this invocation
    failed: int  # of those, recorded with status "error"
    wall_s: float  # this invocation, start to last record
    outputs: tuple[Path, ...]  # summary, table and figures written


def task_keys(run: ResolvedRun) -> dict[RecordKey, Task]:
    """Every episode of the run by record key (the backend name is part of the key)."""
    keys: dict[RecordKey, Task] = {}
    for i, case in enumerate(run.cases):
        for policy in run.policies:
            for seed in run.config.seeds:
                keys[(case.episode_id, seed, policy, run.config.backend)] = Task(i, policy, seed)
    return keys


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
            raise ConfigError(f"{path}: unreadable ({exc.msg}); not a bench run directory?") from None
        check_resumable(saved, current, path)
    elif (run.out / EPISODES_FILE).exists():
        raise ConfigError(f"{run.out}: has {EPISODES_FILE} but no {CONFIG_FILE}; cannot tell what it ran")
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(current, indent=1) + "\n", encoding="utf-8")
    tmp.replace(path)


def prepare_run_dir(run: ResolvedRun) -> list[dict[str, Any]]:
    """Create or check the run directory; return the records already there for this run."""
    run.out.mkdir(parents=True, exist_ok=True)
    _check_or_write_config(run)
    save_cases(run.cases, run.out / CASES_FILE)
    planned = task_keys(run)
    return [r for r in read_records(run.out / EPISODES_FILE) if record_key(r) in planned]


def preflight_policies(names: tuple[str, ...], kwargs: dict[str, dict[str, Any]] | None = None) -> None:
    """Build each policy once here, so a policy that cannot even be created (missing extra,
    broken import) is one clear error now instead of a failed record for every episode."""
    from packlab.policies import make_policy

    for name in names:
        try:
            make_policy(name, **(kwargs or {}).get(name, {}))
        except Exception as exc:
            raise ConfigError(f"policy = {name!r}: cannot be created ({type(exc).__name__}: {exc})") from exc


def _progress_bar(total: int, initial: int, label: str, enabled: bool) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=label, unit="ep", file=sys.stderr, disable=not enabled,
                dynamic_ncols=True, smoothing=0.05)


def _log_invocation(run: ResolvedRun, started: float, wall_s: float, ran: int, failed: int) -> None:
    entry = {
        "started": datetime.fromtimestamp(started, UTC).isoformat(timespec="seconds"),
        "wall_s": round(wall_s, 3), "ran": ran, "failed": failed,
        "workers": run.workers, "exec_backend": run.config.exec_backend,
    }
    with open(run.out / INVOCATIONS_FILE, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(entry) + "\n")


class RunLock:
    """An exclusive lock on a run directory: two invocations appending to one episodes.jsonl
    would both run the missing episodes and duplicate them. ``flock`` is released by the
    kernel when the holder dies, so a killed run never leaves a stale lock behind."""

    def __init__(self, run_dir: Path) -> None:
        self.path = run_dir / ".lock"
        self._fh: Any = None

    def __enter__(self) -> Self:
        import fcntl

        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.path, "a+", encoding="utf-8")
        try:
            fcntl.flock(self._fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._fh.seek(0)
            holder = self._fh.read().strip() or "?"
            self._fh.close()
            raise ConfigError(f"{self.path.parent}: another bench run (pid {holder}) is writing there; "
                              f"wait for it or use another --out") from None
        self._fh.seek(0)
        self._fh.truncate()
        self._fh.write(str(os.getpid()))
        self._fh.flush()
        return self

    def __exit__(self, *exc: object) -> None:
        self._fh.close()  # closing releases the flock


def run_bench(config: RunConfig, *, on_record: Callable[[dict[str, Any]], None] | None = None,
              figures: bool = True) -> BenchOutcome:
    """Run (or resume) a bench configuration and write its records, summary, table and figures.

    ``on_record`` is called after each new record is safely written (tests use it to interrupt
    a run part-way, exactly where a kill would land).
    """
    run = resolve(config)
    preflight_policies(run.policies, run.policy_kwargs())
    with RunLock(run.out):
        return _run_locked(run, on_record, figures)


def _run_locked(run: ResolvedRun, on_record: Callable[[dict[str, Any]], None] | None,
                figures: bool) -> BenchOutcome:
    from packlab.bench.report import write_outputs

    config = run.config
    done = prepare_run_dir(run)
    if config.retry_errors:
        done = [r for r in done if r.get("status", "ok") == "ok"]
    done_keys = {record_key(r) for r in done}
    planned = task_keys(run)
    pending = longest_first([t for k, t in planned.items() if k not in done_keys], run)
    records = list(done)
    failed = 0
    started_wall, started = time.time(), time.perf_counter()
    if pending:
        if run.config.backend == "mujoco":
            # Import the engine before forking so workers inherit it instead of loading it each.
            import packlab.sim.physics.mujoco_backend  # noqa: F401
        results = execute(run.cases, pending, run.config.backend, run.physics_config(), run.workers,
                          run.config.exec_backend, run.policy_kwargs())
        bar = _progress_bar(len(planned), len(done), f"bench {run.source.label}", run.config.progress)
        try:
            with RecordWriter(run.out / EPISODES_FILE) as writer:
                for record in results:
                    writer.write(record)
                    records.append(record)
                    if record["status"] != "ok":
                        failed += 1
                        bar.set_postfix_str(f"{failed} failed", refresh=False)
                    bar.update(1)
                    if on_record is not None:
                        on_record(record)
        finally:
            bar.close()
            close = getattr(results, "close", None)
            if close is not None:
                close()  # stops a pool early when we leave by an exception
            wall_s = time.perf_counter() - started
            _log_invocation(run, started_wall, wall_s, len(records) - len(done), failed)
    wall_s = time.perf_counter() - started
    summary, table_md, outputs = write_outputs(run.out, run.to_json(), records, run.cases, figures=figures)
    return BenchOutcome(run.out, summary, table_md, len(planned), len(done), len(records) - len(done), failed,
                        wall_s, tuple(outputs))


__all__ = ["BenchOutcome", "RunLock", "longest_first", "prepare_run_dir", "run_bench", "task_keys"]
