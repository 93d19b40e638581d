"""Whole bench runs of the ``endpoint`` policy against fake model servers that fail in the ways
real ones do: dead (nothing listening), hung (accepts, never answers), garbage (200 with a body
that is not an answer), 500 (always) and 404 (a wrong model name or URL). Each run must end
within a bound this test asserts, with the exit code and records docs/robustness.md promises;
without those bounds a dead or hung server would cost 5 steps x 3 tries x 60 s per episode, about
45 hours for the default suite.

And a server that dies in the middle of a run with four episodes in flight (``--concurrency
4``): what finished stays as it was, and the same command against the restarted server plays
only what is missing and ends with the oracle's scores."""

from __future__ import annotations

import socket
import sys
import threading
import time
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest
from record_helpers import without_timing
from scripted_server import Script, ScriptedServer

from packlab.bench.records import read_record_file
from packlab.cases.load import load_cases
from packlab.cli.main import main
from packlab.core.errors import EXIT_ABORTED, EXIT_OK
from packlab.core.records import to_builtins
from packlab.sim.env import demo_cases_path
from packlab.vlm.serve.oracle_answers import record_oracle_answers

DEADLINE_S = 0.5  # per request
BOUND_S = 30.0  # a whole faulty run; 3 failed episodes x 2 tries x 0.5 s plus start-up


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _QuietServer(ThreadingHTTPServer):
    """A client that gave up on a hung answer is expected here: no traceback among the dots."""

    def handle_error(self, request: object, client_address: object) -> None:
        if not isinstance(sys.exc_info()[1], (BrokenPipeError, ConnectionResetError)):
            super().handle_error(request, client_address)


class _Handler(BaseHTTPRequestHandler):
    mode = "garbage"

    def log_message(self, *args: object) -> None:  # keep the test output clean
        pass

    def do_POST(self) -> None:
        self.rfile.read(int(self.headers.get("Content-Length", 0)))
        if self.mode == "hung":
            time.sleep(30)  # longer than any deadline in this file
            return
        status, body = {
            "500": (500, b'{"error": {"message": "boom"}}'),
            "404": (404, b'{"error": {"message": "model not found"}}'),
        }.get(self.mode, (200, b"<html>not json</html>"))
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)


@pytest.fixture
def server(request) -> Iterator[str]:
    """Base URL of a fake server in the mode given by the test's parameter."""
    mode = request.param
    if mode == "dead":
        yield f"http://127.0.0.1:{_free_port()}/v1"  # nothing listens there
        return
    handler = type("Handler", (_Handler,), {"mode": mode})
    httpd = _QuietServer(("127.0.0.1", 0), handler)
    httpd.daemon_threads = True
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}/v1"
    finally:
        httpd.shutdown()
        httpd.server_close()


def _bench(tmp_path, capsys, base_url: str) -> tuple[int, float, list[str], list[dict]]:
    run_dir = tmp_path / "run"
    argv = [
        "bench",
        "--cases",
        demo_cases_path(),
        "--backend",
        "geometric",
        "--policies",
        "endpoint",
        "--seeds",
        "0-3",
        "--workers",
        "1",
        "--out",
        str(run_dir),
        "--no-progress",
        "--no-figures",
        "--policy-arg",
        f"endpoint:base_url={base_url}",
        "--policy-arg",
        f"endpoint:deadline_s={DEADLINE_S}",
        "--policy-arg",
        "endpoint:retries=1",
        "--policy-arg",
        "endpoint:backoff_s=0.05",
    ]
    started = time.monotonic()
    code = main(argv)
    wall = time.monotonic() - started
    err = capsys.readouterr().err.strip().splitlines()
    return code, wall, err, list(read_record_file(run_dir / "episodes.jsonl").records)


@pytest.mark.parametrize("server", ["dead", "hung", "500", "404"], indirect=True)
def test_an_unusable_server_stops_the_run_in_bounded_time(tmp_path, capsys, server):
    code, wall, err, records = _bench(tmp_path, capsys, server)
    assert code == EXIT_ABORTED, err
    assert wall < BOUND_S
    # The breaker (default 3 consecutive transport errors) stopped the run; those records stay.
    assert len(records) == 3
    assert all(r.status == "error" and r.error_kind == "transport" for r in records)
    assert records[-1].error.startswith(("EndpointUnavailable", "EndpointError"))
    assert err[-1].startswith("packlab bench: error: stopped after 3 consecutive transport errors")
    assert (tmp_path / "run" / "summary.json").exists()


@pytest.mark.parametrize("server", ["garbage"], indirect=True)
def test_garbage_answers_are_invalid_steps_and_the_run_completes(tmp_path, capsys, server):
    code, wall, err, records = _bench(tmp_path, capsys, server)
    assert code == EXIT_OK, err
    assert wall < BOUND_S
    assert len(records) == 3 * 4 and all(r.status == "ok" for r in records)
    # Every step is an invalid, unparsable one: the objects are set aside, nothing is packed.
    steps = [s for r in records for s in r.steps]
    assert steps and all(not s.valid and s.reason == "unparsable" for s in steps)
    assert all(r.metrics.overall == 0.0 for r in records)


# -- a server that dies mid-run with several episodes in flight ------------------------------
SEEDS = (0, 1)


def _played(records) -> dict:
    return {(r.case_id, r.seed): r for r in records}


def _score(record) -> dict:
    """An episode's metrics, less the wall-clock ones."""
    return without_timing(to_builtins(record.metrics))


def test_a_server_dying_with_episodes_in_flight_resumes_to_the_oracles_scores(
    tiny_suite, tmp_path, capsys
):
    answers = record_oracle_answers(load_cases(str(tiny_suite)), SEEDS)
    seeds = ",".join(map(str, SEEDS))
    common = ["bench", "--cases", str(tiny_suite), "--backend", "geometric", "--seeds", seeds]
    common += ["--workers", "1", "--no-progress", "--no-figures", "--no-html"]
    assert main([*common, "--policies", "oracle", "--out", str(tmp_path / "oracle")]) == EXIT_OK
    oracle = _played(read_record_file(tmp_path / "oracle" / "episodes.jsonl").records)
    steps = {k: len(r.steps) for k, r in oracle.items()}
    # The longest episodes run first, four at once: the server dies a little after the requests
    # of those four, with the next ones under way.
    die_after = sum(sorted(steps.values(), reverse=True)[:4]) + 2
    out = tmp_path / "run"

    def bench(base_url: str) -> int:
        endpoint = [
            f"endpoint:base_url={base_url}",
            f"endpoint:deadline_s={DEADLINE_S}",
            "endpoint:retries=1",
            "endpoint:backoff_s=0.05",
            "endpoint:tag_requests=true",  # the scripted oracle's key
        ]
        flags = [a for arg in endpoint for a in ("--policy-arg", arg)]
        argv = [*common, "--policies", "endpoint", "--concurrency", "4", "--out", str(out)]
        return main([*argv, *flags])

    script = Script(answers=answers, default="no answer", die_after=die_after)
    with ScriptedServer(script, tmp_path / "server") as server:
        port = server.port
        code = bench(server.base_url)
        assert server.process.wait(timeout=10) == 0  # it did die
    assert code == EXIT_ABORTED, capsys.readouterr().err
    first = read_record_file(out / "episodes.jsonl").records
    finished = {k: r for k, r in _played(first).items() if r.status == "ok"}
    assert finished and len(finished) < len(oracle)
    # What finished before the death is whole and scored as the oracle's; the rest failed to
    # reach the server (or never started: the breaker stopped the run).
    assert all(_score(r) == _score(oracle[k]) for k, r in finished.items())
    assert all(r.error_kind == "transport" for r in first if r.status != "ok")

    # The same URL (part of the run's identity) answers again: the rerun plays what is missing.
    with ScriptedServer(
        Script(answers=answers, default="no answer"), tmp_path / "server", port=port
    ) as server:
        code = bench(server.base_url)
    assert code == EXIT_OK, capsys.readouterr().err
    records = read_record_file(out / "episodes.jsonl").records
    assert records[: len(first)] == first  # nothing written before was touched
    assert {(r.case_id, r.seed) for r in records[len(first) :]}.isdisjoint(finished)
    assert server.stats()["answered"] == sum(n for k, n in steps.items() if k not in finished)
    latest = _played(records)
    assert latest.keys() == oracle.keys() and all(r.status == "ok" for r in latest.values())
    assert {k: _score(r) for k, r in latest.items()} == {k: _score(r) for k, r in oracle.items()}
