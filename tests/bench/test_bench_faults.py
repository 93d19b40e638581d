"""Faults during a bench run: dead server (circuit breaker), hung policy (episode time limit),
run deadline, a dying worker; each ends in bounded time with records kept and the exit code
that says what happened (packlab.core.errors.EXIT_*)."""

from __future__ import annotations

import json
import time

import fault_policies
import pytest
from record_helpers import error_record, ok_record

from packlab import executors
from packlab.bench.records import read_record_file
from packlab.cli.main import main
from packlab.core.errors import EXIT_ABORTED, EXIT_EPISODE_ERRORS, EXIT_OK
from packlab.core.records import episode_from_json
from packlab.sim.env import demo_cases_path

#: Every faulty run below must end within this many seconds (each case would otherwise hang
#: for ever or, against a dead server, for hours).
BOUND_S = 20.0
N_DEMO = 3  # cases in the bundled demo file


@pytest.fixture(autouse=True)
def faulty_policies():
    fault_policies.register_all()
    try:
        yield
    finally:
        fault_policies.unregister_all()


def bench(tmp_path, capsys, *flags: str) -> tuple[int, float, list[str], list[dict]]:
    """Run ``packlab bench`` on the demo cases (geometric backend); exit code, wall time,
    stderr lines and the records on disk."""
    run_dir = tmp_path / "run"
    argv = [
        "bench",
        "--cases",
        demo_cases_path(),
        "--backend",
        "geometric",
        "--out",
        str(run_dir),
        "--no-progress",
        "--no-figures",
        *flags,
    ]
    started = time.monotonic()
    code = main(argv)
    wall = time.monotonic() - started
    err = capsys.readouterr().err.strip().splitlines()
    return code, wall, err, list(read_record_file(run_dir / "episodes.jsonl").records)


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_dead_server_trips_the_breaker_and_a_rerun_completes_the_run(tmp_path, capsys, workers):
    flags = ("--policies", "test-unreachable", "--seeds", "0-9", "--workers", workers)
    code, wall, err, records = bench(tmp_path, capsys, *flags)
    assert code == EXIT_ABORTED and wall < BOUND_S
    # Stopped at the third consecutive transport error: those three are the records kept.
    assert len(records) == 3 and all(
        r.status == "error" and r.error_kind == "transport" for r in records
    )
    assert "EndpointUnavailable" in records[0].error and "Traceback" in records[0].traceback
    last = err[-1]
    assert last.startswith("packlab bench: error: stopped after 3 consecutive transport errors")
    assert "connection refused" in last and f"3 of {N_DEMO * 10} episodes recorded" in last
    assert (tmp_path / "run" / "summary.json").exists() and (tmp_path / "run" / "table.md").exists()

    fault_policies.Unreachable.down = False  # the server is back: a plain rerun redoes those three
    code, _, err, records = bench(tmp_path, capsys, *flags)
    assert code == EXIT_OK and f"{N_DEMO * 10} episodes run" in err[-1]
    latest = {(r.case_id, r.seed): r for r in records}
    assert len(latest) == N_DEMO * 10 and all(r.status == "ok" for r in latest.values())


def test_breaker_off_runs_everything_and_exits_1_with_the_count(tmp_path, capsys):
    code, wall, err, records = bench(
        tmp_path,
        capsys,
        "--policies",
        "test-unreachable",
        "--seeds",
        "0",
        "--workers",
        "1",
        "--max-transport-failures",
        "0",
    )
    assert code == EXIT_EPISODE_ERRORS and wall < BOUND_S and len(records) == N_DEMO
    assert err[-1] == (
        f"packlab bench: {N_DEMO} of {N_DEMO} episodes ended in error "
        f"(see {tmp_path / 'run' / 'episodes.jsonl'}; rerun with --retry-errors)"
    )


def test_other_records_reset_the_breaker(tmp_path, capsys):
    # Serial, one seed: per case the unreachable policy, then dblf; never two transport errors
    # in a row, so a breaker at 2 never trips and the run finishes (exit 1, not 3).
    code, _, err, records = bench(
        tmp_path,
        capsys,
        "--policies",
        "test-unreachable,dblf",
        "--seeds",
        "0",
        "--workers",
        "1",
        "--max-transport-failures",
        "2",
    )
    assert code == EXIT_EPISODE_ERRORS and len(records) == 2 * N_DEMO
    assert f"{N_DEMO} of {2 * N_DEMO} episodes ended in error" in err[-1]


@pytest.mark.parametrize(
    "policy, stuck_in", [("test-sleep", "sleep"), ("test-socket-hang", "recv")]
)
@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_hung_policy_is_a_timeout_record_and_the_run_goes_on(
    tmp_path, capsys, policy, stuck_in, workers
):
    code, wall, err, records = bench(
        tmp_path,
        capsys,
        "--policies",
        f"{policy},dblf",
        "--seeds",
        "0",
        "--workers",
        workers,
        "--episode-timeout",
        "0.5",
    )
    assert code == EXIT_EPISODE_ERRORS and wall < BOUND_S
    hung = [r for r in records if r.policy == policy]
    assert len(hung) == N_DEMO and all(r.error_kind == "timeout" for r in hung)
    assert all("--episode-timeout" in r.error and stuck_in in r.traceback for r in hung)
    assert all(r.status == "ok" for r in records if r.policy == "dblf")
    assert f"{N_DEMO} of {2 * N_DEMO} episodes ended in error" in err[-1]


def test_code_the_alarm_cannot_reach_is_killed_by_the_pool(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(executors, "HARD_KILL_GRACE_S", 0.5)
    code, wall, _, records = bench(
        tmp_path,
        capsys,
        "--policies",
        "test-deaf,dblf",
        "--seeds",
        "0",
        "--workers",
        "2",
        "--episode-timeout",
        "0.5",
    )
    assert code == EXIT_EPISODE_ERRORS and wall < BOUND_S
    deaf = [r for r in records if r.policy == "test-deaf"]
    assert len(deaf) == N_DEMO and all(
        r.error_kind == "timeout" and "worker process killed" in r.error for r in deaf
    )
    assert sum(r.status == "ok" for r in records) == N_DEMO


def test_a_worker_that_dies_is_an_error_record_not_a_hang(tmp_path, capsys):
    code, wall, _, records = bench(
        tmp_path, capsys, "--policies", "test-sigkill,dblf", "--seeds", "0", "--workers", "2"
    )
    assert code == EXIT_EPISODE_ERRORS and wall < BOUND_S
    died = [r for r in records if r.policy == "test-sigkill"]
    assert len(died) == N_DEMO and all(
        r.error_kind == "exception" and "SIGKILL" in r.error for r in died
    )
    assert sum(r.status == "ok" for r in records) == N_DEMO


@pytest.mark.parametrize("workers", ["1", "2"])
def test_the_run_deadline_stops_the_run_keeps_records_and_resumes(tmp_path, capsys, workers):
    flags = ("--policies", "dblf,test-sleep", "--seeds", "0", "--workers", workers)
    code, wall, err, records = bench(
        tmp_path, capsys, *flags, "--episode-timeout", "0", "--deadline", "2"
    )
    assert code == EXIT_ABORTED and 2 <= wall < BOUND_S
    assert records and all(r.policy == "dblf" and r.status == "ok" for r in records)
    assert err[-1].startswith("packlab bench: error: stopped at the run deadline (--deadline 2 s)")
    assert f"{len(records)} of {2 * N_DEMO} episodes recorded" in err[-1]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary  # written for what finished
    # The same run resumed with a time limit per episode: only the missing episodes run.
    code, _, err, after = bench(tmp_path, capsys, *flags, "--episode-timeout", "0.5")
    assert code == EXIT_EPISODE_ERRORS and len(after) == 2 * N_DEMO
    assert f"{2 * N_DEMO - len(records)} episodes run" in err[-2]


def test_errors_of_earlier_invocations_count_in_the_exit_code(tmp_path, capsys):
    flags = (
        "--policies",
        "test-sleep,dblf",
        "--seeds",
        "0",
        "--workers",
        "1",
        "--episode-timeout",
        "0.2",
    )
    assert bench(tmp_path, capsys, *flags)[0] == EXIT_EPISODE_ERRORS
    code, _, err, _ = bench(tmp_path, capsys, *flags)
    assert code == EXIT_EPISODE_ERRORS and "0 episodes run" in err[-2]
    assert f"{N_DEMO} of {2 * N_DEMO} episodes ended in error" in err[-1]


def test_a_clean_run_exits_0_with_no_error_line(tmp_path, capsys):
    code, _, err, records = bench(
        tmp_path, capsys, "--policies", "dblf", "--seeds", "0-1", "--workers", "2"
    )
    assert code == EXIT_OK and len(records) == 2 * N_DEMO and "error" not in err[-1]


@pytest.mark.slow
def test_ray_time_limit_and_deadline(tmp_path, capsys, ray_cluster):
    code, wall, _, records = bench(
        tmp_path,
        capsys,
        "--policies",
        "test-sleep,dblf",
        "--seeds",
        "0",
        "--executor",
        "ray",
        "--workers",
        "2",
        "--episode-timeout",
        "1",
    )
    assert code == EXIT_EPISODE_ERRORS and wall < 60
    assert (
        sorted(getattr(r, "error_kind", "ok") for r in records)
        == ["ok"] * N_DEMO + ["timeout"] * N_DEMO
    )
    code, wall, err, _ = bench(
        tmp_path / "b",
        capsys,
        "--policies",
        "test-sleep",
        "--seeds",
        "0",
        "--executor",
        "ray",
        "--workers",
        "2",
        "--episode-timeout",
        "0",
        "--deadline",
        "3",
    )
    assert code == EXIT_ABORTED and wall < 60 and "--deadline 3 s" in err[-1]


def test_breaker_counts_only_consecutive_transport_errors():
    from packlab.bench.runner import TransportBreaker, needs_rerun

    transport = error_record(
        policy="endpoint", kind="transport", error="EndpointUnavailable: refused"
    )
    breaker = TransportBreaker(2)
    assert not breaker.observe(transport) and not breaker.observe(ok_record())
    assert not breaker.observe(transport) and breaker.observe(transport)
    assert "2 consecutive transport errors" in breaker.reason() and "refused" in breaker.reason()
    assert not any(TransportBreaker(0).observe(transport) for _ in range(10))
    # Transport errors are always redone; other failures (old records have no kind) on request.
    old_error = episode_from_json(
        {
            "status": "error",
            "case_id": "c",
            "seed": 0,
            "policy": "p",
            "backend": "geometric",
            "difficulty": "easy",
            "n_objects": 1,
            "error": "RuntimeError: x",
        },
        "old",
    )
    assert old_error.error_kind == "exception"  # migrated
    assert (
        needs_rerun(transport, False)
        and not needs_rerun(old_error, False)
        and needs_rerun(old_error, True)
    )
    assert not needs_rerun(ok_record(), True)
