"""``packlab bench --concurrency N``: several episodes in flight in each worker.

Each episode's record must not depend on N (its RNG, policy and physics are its own), a model
server must see several requests at once when N > 1, a run may resume under another N, and a
server dying mid-run leaves every finished record for the rerun to build on.
"""

from __future__ import annotations

import json
import time

import fault_policies
import pytest
from bench_helpers import run_tiny
from record_helpers import without_timing
from scripted_server import Script, ScriptedServer

from packlab import executors
from packlab.bench.config import RunConfig
from packlab.bench.records import read_record_file, record_key
from packlab.bench.runner import run_bench
from packlab.cli.main import main
from packlab.core.errors import EXIT_ABORTED, EXIT_EPISODE_ERRORS, EXIT_OK, ConfigError
from packlab.core.records import to_builtins

#: A parsable answer: the first box shown, unrotated, in the container's corner.
ANSWER = json.dumps({"object_id": 0, "rotation": 0, "x": 0, "y": 0})


def _records(out) -> dict:
    records = read_record_file(out / "episodes.jsonl").records
    by_key = {record_key(r): without_timing(to_builtins(r)) for r in records}
    assert len(by_key) == len(records)  # every episode once
    return by_key


def _bench(cases, out, *extra: str) -> int:
    argv = ["bench", "--cases", str(cases), "--seeds", "0,1", "--out", str(out)]
    return main([*argv, "--no-progress", "--no-figures", *extra])


def test_records_do_not_depend_on_concurrency(tiny_suite, tmp_path, capsys):
    base = ("--backend", "geometric", "--policies", "dblf,ffp,random")
    assert _bench(tiny_suite, tmp_path / "one", *base, "--workers", "1") == EXIT_OK
    for workers, n in (("1", "4"), ("2", "3")):
        out = tmp_path / f"w{workers}-n{n}"
        assert _bench(tiny_suite, out, *base, "--workers", workers, "--concurrency", n) == 0
        assert _records(out) == _records(tmp_path / "one")
        assert json.loads((out / "config.json").read_text())["execution"]["concurrency"] == int(n)


def test_mujoco_records_do_not_depend_on_concurrency(tiny_suite, tmp_path, capsys):
    base = ("--backend", "mujoco", "--policies", "dblf", "--difficulty", "easy", "--workers", "1")
    assert _bench(tiny_suite, tmp_path / "one", *base) == EXIT_OK
    assert _bench(tiny_suite, tmp_path / "four", *base, "--concurrency", "4") == EXIT_OK
    assert len(_records(tmp_path / "one")) == 2 * 2
    assert _records(tmp_path / "four") == _records(tmp_path / "one")


def test_a_run_resumes_under_another_concurrency(tiny_suite, tmp_path):
    out = tmp_path / "run"

    def stop_after_two(record) -> None:
        if len(read_record_file(out / "episodes.jsonl").records) == 2:
            raise KeyboardInterrupt

    config = RunConfig(
        cases=str(tiny_suite),
        out=str(out),
        backend="geometric",
        policies=("dblf",),
        seeds=(0, 1),
        workers=1,
        progress=False,
    )
    with pytest.raises(KeyboardInterrupt):
        run_bench(config, on_record=stop_after_two, figures=False, html=False)
    outcome = run_tiny(tiny_suite, out, seeds=(0, 1), workers=2, concurrency=3)
    assert (outcome.already_done, outcome.ran, outcome.recorded) == (2, 6, 8)


def test_concurrency_is_checked():
    for bad in (0, -1, 65, 2.5, True):
        with pytest.raises(ConfigError, match="concurrency"):
            RunConfig(concurrency=bad)


def _endpoint_args(base_url: str) -> tuple[str, ...]:
    return (
        "--backend", "geometric", "--policies", "endpoint",
        "--policy-arg", f"endpoint:base_url={base_url}",
        "--policy-arg", "endpoint:deadline_s=2",
        "--policy-arg", "endpoint:retries=0",
    )  # fmt: skip


# The model servers below run in processes of their own (scripted_server): the bench forks its
# pool worker, which must not happen while a server thread runs in this process.
def test_a_served_model_sees_several_requests_at_once(tiny_suite, tmp_path, capsys):
    with ScriptedServer(Script(default=ANSWER, delay_s=0.1), tmp_path / "server") as server:
        args = _endpoint_args(server.base_url)
        code = _bench(tiny_suite, tmp_path / "run", *args, "--workers", "1", "--concurrency", "4")
    assert code == EXIT_OK, capsys.readouterr().err
    assert 1 < server.stats()["most"] <= 4
    records = _records(tmp_path / "run")
    assert len(records) == 8 and all(r["status"] == "ok" for r in records.values())


def test_a_server_dying_mid_run_keeps_the_finished_records(tiny_suite, tmp_path, capsys):
    out = tmp_path / "run"
    dying = Script(default=ANSWER, delay_s=0.02, answer_at_most=40)
    with ScriptedServer(dying, tmp_path / "server") as server:
        port, args = server.port, _endpoint_args(server.base_url)
        code = _bench(tiny_suite, out, *args, "--workers", "1", "--concurrency", "4")
    assert code == EXIT_ABORTED, capsys.readouterr().err
    first = read_record_file(out / "episodes.jsonl").records
    finished = {record_key(r) for r in first if r.status == "ok"}
    assert finished and len(finished) < 8
    # The same URL (part of the run's identity) answers again: the rerun runs the rest only.
    with ScriptedServer(Script(default=ANSWER), tmp_path / "server", port=port):
        code = _bench(tiny_suite, out, *args, "--workers", "1", "--concurrency", "2")
    assert code == EXIT_OK, capsys.readouterr().err
    records = read_record_file(out / "episodes.jsonl").records
    assert records[: len(first)] == first  # nothing written before was touched
    latest = {record_key(r): r for r in records}
    assert len(latest) == 8 and all(r.status == "ok" for r in latest.values())
    assert {record_key(r) for r in records[len(first) :]}.isdisjoint(finished)


@pytest.fixture
def faulty_policies():
    fault_policies.register_all()
    try:
        yield
    finally:
        fault_policies.unregister_all()


@pytest.mark.usefixtures("faulty_policies")
@pytest.mark.parametrize(
    "policy, grace_s, message",
    [
        ("test-spin", None, "limit (--episode-timeout)"),  # the thread's own time limit
        ("test-sleep", 0.5, "worker process killed"),  # beyond its reach: the pool's kill
    ],
)
def test_a_hung_episode_in_a_thread_times_out_and_the_others_finish(
    tiny_suite, tmp_path, capsys, monkeypatch, policy, grace_s, message
):
    if grace_s is not None:
        monkeypatch.setattr(executors, "HARD_KILL_GRACE_S", grace_s)
    started = time.monotonic()
    flags = ("--backend", "geometric", "--policies", f"{policy},dblf", "--workers", "1")
    code = _bench(
        tiny_suite, tmp_path / "run", *flags, "--concurrency", "3", "--episode-timeout", "0.5"
    )
    assert code == EXIT_EPISODE_ERRORS and time.monotonic() - started < 20
    records = read_record_file(tmp_path / "run" / "episodes.jsonl").records
    hung = [r for r in records if r.policy == policy]
    assert len(hung) == 8 and all(r.error_kind == "timeout" and message in r.error for r in hung)
    assert sum(r.status == "ok" for r in records) == 8 == len(records) - len(hung)


@pytest.mark.usefixtures("faulty_policies")
def test_the_run_deadline_stops_concurrent_episodes_and_keeps_records(tiny_suite, tmp_path, capsys):
    flags = ("--backend", "geometric", "--policies", "dblf,test-sleep", "--workers", "1")
    started = time.monotonic()
    code = _bench(
        tiny_suite,
        tmp_path / "run",
        *flags,
        "--concurrency",
        "4",
        "--episode-timeout",
        "0",
        "--deadline",
        "2",
    )
    assert code == EXIT_ABORTED and 2 <= time.monotonic() - started < 20
    records = read_record_file(tmp_path / "run" / "episodes.jsonl").records
    assert records and all(r.policy == "dblf" and r.status == "ok" for r in records)
