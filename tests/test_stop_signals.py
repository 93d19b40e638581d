"""SIGINT and SIGTERM sent to the main process alone (as ``timeout``, systemd, a container runtime
or a job scheduler's cancel do) stop every command and every executor: real subprocesses, real
signals. Each test checks that the main process exits with the documented code, that every
process it started is gone within 5 s, that the records written so far are intact, and that the
same command resumes (for the bench: to the table an uninterrupted run prints)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from packlab.core.errors import EXIT_INTERRUPTED, EXIT_TERMINATED

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc"),
]

#: How long the goal allows from the signal until no process of the run is left.
STOP_WITHIN_S = 5.0
CODES = {signal.SIGINT: EXIT_INTERRUPTED, signal.SIGTERM: EXIT_TERMINATED}


def _packlab(*args: str) -> list[str]:
    return [sys.executable, "-m", "packlab.cli.main", *args]


def _children() -> dict[int, list[int]]:
    """Parent pid -> its children's pids, for every process on the machine."""
    tree: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # ended meanwhile
            continue
        # The command name is in parentheses and may hold spaces: fields start after the last ')'.
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        tree.setdefault(ppid, []).append(int(entry.name))
    return tree


def _descendants(pid: int) -> set[int]:
    tree, found, todo = _children(), set(), [pid]
    while todo:
        for child in tree.get(todo.pop(), []):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"  # a zombie has exited; only its parent's wait is missing


def _names(pids: set[int]) -> str:
    """The command lines of the processes still alive, for a failure message."""
    alive = []
    for pid in sorted(p for p in pids if _alive(p)):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        alive.append(f"{pid} {cmd[:80]}")
    return "; ".join(alive) or "none"


def _wait_until(condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    until = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > until:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.1)


def _stop_mid_run(
    command: list[str],
    cwd: Path,
    started: Callable[[], bool],
    signum: int,
    min_children: int,
    what: str,
    timeout_s: float = 240.0,
) -> tuple[subprocess.CompletedProcess[str], set[int]]:
    """Start ``command``, wait for ``started()`` with the run still going, signal the main process
    only; return how it ended and the processes it had started (for the orphan check)."""
    proc = subprocess.Popen(
        command, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        _wait_until(lambda: started() or proc.poll() is not None, timeout_s, what)
        assert proc.poll() is None, f"the run ended before the signal:\n{proc.stderr.read()}"
        _wait_until(
            lambda: len(_descendants(proc.pid)) >= min_children, 60, f"{min_children} workers"
        )
        workers = _descendants(proc.pid)
        sent = time.monotonic()
        os.kill(proc.pid, signum)  # the main process alone, not its group
        out, err = proc.communicate(timeout=60)
        try:
            _wait_until(
                lambda: not any(_alive(p) for p in workers), STOP_WITHIN_S, "the workers to end"
            )
        except AssertionError as exc:
            raise AssertionError(f"{exc}; still running: {_names(workers)}") from None
        stopped_in = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert stopped_in <= STOP_WITHIN_S, f"stopped in {stopped_in:.1f} s"
    return subprocess.CompletedProcess(command, proc.returncode, out, err), workers


def _records(path: Path) -> list[dict]:
    """Every line of a JSONL file, each a whole JSON object (a torn line fails the test)."""
    return [json.loads(line) for line in path.read_text().splitlines()]


def _results_table(table_md: str) -> str:
    """table.md without its run details (times differ between runs; scores must not)."""
    return table_md.split("### Run details", 1)[0]


BENCH = (
    "bench",
    "--cases",
    "packlab-bench-v1",
    "--difficulty",
    "hard",
    "--policies",
    "dblf",
    "--seeds",
    "0",
    "--backend",
    "mujoco",
    "--workers",
    "2",
    "--no-html",
    "--no-figures",
    "--no-progress",
)


@pytest.fixture(scope="module")
def bench_reference(tmp_path_factory) -> str:
    """The results table of the same bench run, uninterrupted."""
    out = tmp_path_factory.mktemp("reference") / "run"
    subprocess.run(_packlab(*BENCH, "--out", str(out)), check=True, capture_output=True)
    return _results_table((out / "table.md").read_text())


@pytest.mark.parametrize(
    ("executor", "signum"),
    [("process", signal.SIGTERM), ("process", signal.SIGINT), ("ray", signal.SIGTERM)],
)
def test_bench_stops_keeps_its_records_and_resumes_to_the_same_table(
    executor, signum, tmp_path, bench_reference
):
    if executor == "ray":
        pytest.importorskip("ray")
    out = tmp_path / "run"
    episodes = out / "episodes.jsonl"
    command = _packlab(*BENCH, "--executor", executor, "--out", str(out))

    def two_records() -> bool:
        return episodes.is_file() and len(episodes.read_text().splitlines()) >= 2

    ended, _ = _stop_mid_run(command, tmp_path, two_records, signum, 2, "two records")
    assert ended.returncode == CODES[signum], ended.stderr
    assert "rerun the same command to resume" in ended.stderr.strip().splitlines()[-1]
    kept = _records(episodes)
    assert 2 <= len(kept) < 20 and all(r["status"] == "ok" for r in kept)
    invocation = _records(out / "invocations.jsonl")[-1]
    assert invocation["ran"] == len(kept)  # the run logged itself on its way out

    again = subprocess.run(command, check=False, cwd=tmp_path, capture_output=True, text=True)
    assert again.returncode == 0, again.stderr
    assert f"{len(kept)} already done" in again.stderr
    assert _results_table((out / "table.md").read_text()) == bench_reference


@pytest.mark.parametrize("executor", ["process", "ray"])
def test_generate_stops_keeps_finished_shards_and_resumes(executor, tmp_path):
    if executor == "ray":
        pytest.importorskip("ray")
    out = tmp_path / "data"
    shards = out / "meta" / "shards"
    command = _packlab(
        "generate", "--difficulty", "hard", "--episodes", "12", "--seed", "3",
        "--shard-size", "1", "--teacher", "plan", "--sft", "none", "--workers", "2",
        "--executor", executor, "--no-progress", "--out", str(out),
    )  # fmt: skip

    def one_shard() -> bool:
        return shards.is_dir() and any(shards.glob("*.json"))

    ended, _ = _stop_mid_run(command, tmp_path, one_shard, signal.SIGTERM, 2, "a finished shard")
    assert ended.returncode == EXIT_TERMINATED, ended.stderr
    done = sorted(p.name for p in shards.glob("*.json"))
    assert 1 <= len(done) < 12
    for shard in done:  # every finished shard is whole
        json.loads((shards / shard).read_text())

    again = subprocess.run(command, check=False, cwd=tmp_path, capture_output=True, text=True)
    assert again.returncode == 0, again.stderr
    assert set(done) <= {p.name for p in shards.glob("*.json")}
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["counts"]["episodes"] == 12


def test_train_rl_stops_its_env_processes(tmp_path):
    pytest.importorskip("sb3_contrib")
    out = tmp_path / "rl"
    command = _packlab(
        "train", "rl", "--agent", "irbpp", "--cases", "packdata-mini", "--steps", "200000",
        "--envs", "2", "--vec", "subproc", "--eval-every", "100000", "--eval-cases", "2",
        "--out", str(out),
    )  # fmt: skip
    ended, workers = _stop_mid_run(
        command, tmp_path, lambda: (out / "config.json").is_file(), signal.SIGTERM, 2,
        "the run to start", timeout_s=300,
    )  # fmt: skip
    assert ended.returncode == EXIT_TERMINATED, ended.stderr
    assert len(workers) >= 2  # the env processes were there, and are gone (checked above)
    assert "rerun the same command to resume" in ended.stderr


def test_a_pool_worker_ends_when_its_parent_is_killed(tmp_path):
    """SIGKILL cannot be handled: the workers must notice on their own (executors)."""
    out = tmp_path / "run"
    episodes = out / "episodes.jsonl"
    command = _packlab(*BENCH, "--out", str(out))
    ended, _ = _stop_mid_run(
        command,
        tmp_path,
        lambda: episodes.is_file() and bool(episodes.read_text().strip()),
        signal.SIGKILL,
        2,
        "a record",
    )
    assert ended.returncode == -signal.SIGKILL
    assert all(r["status"] == "ok" for r in _records(episodes))
