"""The ``endpoint`` policy against broken servers: dead, hung, trickling, garbage,
5xx and 4xx fake servers on 127.0.0.1 (raw sockets, one thread per connection). Each test
asserts what happens AND that it happens within a bound derived from the configured deadline:
one request can take at most ``tries * deadline_s + backoffs`` (``worst_case_request_s``), and
the first request that fails for good ends its episode. No torch needed.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Callable, Iterator

import pytest
from _cases import small_case

from packlab.core.errors import ConfigError, EndpointUnavailable
from packlab.core.types import Unparsable
from packlab.policies import make_policy
from packlab.sim.episode import Episode, run_episode
from packlab.vlm.serve.endpoint import (
    DEFAULT_BACKOFF_S,
    DEFAULT_DEADLINE_S,
    DEFAULT_RETRIES,
    EndpointError,
    EndpointPolicy,
)

DEADLINE_S = 0.5
CONFIG = {"deadline_s": DEADLINE_S, "retries": 1, "backoff_s": 0.05}
SLACK_S = 0.3  # thread start-up and scheduling on a shared machine

Handler = Callable[[socket.socket, threading.Event], None]


class FakeServer:
    """Listens on a free port of 127.0.0.1; runs ``handler(conn, stop)`` per connection."""

    def __init__(self, handler: Handler) -> None:
        self.handler = handler
        self.stop = threading.Event()
        self.connections = 0
        self._sock = socket.create_server(("127.0.0.1", 0))
        self._sock.settimeout(0.05)
        self.port = self._sock.getsockname()[1]
        self._threads: list[threading.Thread] = []
        self._accepter = threading.Thread(target=self._accept, daemon=True)
        self._accepter.start()

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.port}/v1"

    def _accept(self) -> None:
        while not self.stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.connections += 1
            t = threading.Thread(target=self._serve, args=(conn,), daemon=True)
            t.start()
            self._threads.append(t)

    def _serve(self, conn: socket.socket) -> None:
        with conn:
            try:
                self.handler(conn, self.stop)
            except OSError:  # the client gave up: what these servers are for
                pass

    def close(self) -> None:
        self.stop.set()
        self._sock.close()
        self._accepter.join(timeout=2)
        for t in self._threads:
            t.join(timeout=2)


def read_request(conn: socket.socket) -> bytes:
    """Read one whole request (headers and Content-Length body), so that closing the socket
    afterwards does not reset the connection under an answer the client has not read yet."""
    conn.settimeout(5)
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = conn.recv(65536)
        if not chunk:
            return data
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    length = next(
        (
            int(line.split(b":", 1)[1])
            for line in head.split(b"\r\n")
            if line.lower().startswith(b"content-length:")
        ),
        0,
    )
    while len(body) < length:
        chunk = conn.recv(65536)
        if not chunk:
            break
        body += chunk
    return body


def answer(status: str, body: bytes, content_type: str = "application/json") -> Handler:
    def handle(conn: socket.socket, stop: threading.Event) -> None:
        read_request(conn)
        conn.sendall(
            f"HTTP/1.1 {status}\r\nContent-Type: {content_type}\r\n"
            f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n".encode()
            + body
        )

    return handle


def hung(conn: socket.socket, stop: threading.Event) -> None:
    read_request(conn)
    stop.wait()  # accepts, reads, never answers


def trickle_body(conn: socket.socket, stop: threading.Event) -> None:
    """Headers at once, then one byte of a never-ending body every 50 ms: each byte comes well
    within any socket timeout, so only a deadline on the whole request can end it."""
    read_request(conn)
    conn.sendall(
        b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: 1000000\r\n\r\n"
    )
    while not stop.wait(0.05):
        conn.sendall(b" ")


def trickle_headers(conn: socket.socket, stop: threading.Event) -> None:
    """The status line, then an endless header one byte every 50 ms."""
    read_request(conn)
    conn.sendall(b"HTTP/1.1 200 OK\r\nX-Slow: ")
    while not stop.wait(0.05):
        conn.sendall(b"a")


def cut_short(conn: socket.socket, stop: threading.Event) -> None:
    read_request(conn)
    conn.sendall(b'HTTP/1.1 200 OK\r\nContent-Length: 500\r\n\r\n{"choices": [')


def error_body(message: str) -> bytes:
    return json.dumps({"error": {"message": message, "type": "invalid_request_error"}}).encode()


@pytest.fixture
def fake() -> Iterator[Callable[[Handler], FakeServer]]:
    servers: list[FakeServer] = []

    def start(handler: Handler) -> FakeServer:
        servers.append(FakeServer(handler))
        return servers[-1]

    yield start
    for s in servers:
        s.close()


def closed_port_url() -> str:
    with socket.socket() as s:  # bound then closed: nothing listens, connections are refused
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"http://127.0.0.1:{port}/v1"


def first_step(base_url: str, **config):
    """(policy, observation) at the first step of the small case."""
    policy = make_policy("endpoint", base_url=base_url, **{**CONFIG, **config})
    case = small_case()
    obs = Episode("geometric").reset(case, 0)
    policy.reset(case, 0)
    return policy, obs


def timed_act(policy: EndpointPolicy, obs) -> tuple[float, object]:
    t0 = time.monotonic()
    try:
        out: object = policy.act(obs)
    except (EndpointUnavailable, EndpointError) as e:
        out = e
    return time.monotonic() - t0, out


# -- transport failures: retried, then EndpointUnavailable -----------------------------------------
def test_dead_server_is_unavailable_after_its_tries():
    url = closed_port_url()
    policy, obs = first_step(url)
    elapsed, out = timed_act(policy, obs)
    assert isinstance(out, EndpointUnavailable)
    message = str(out)
    assert "\n" not in message and url in message and "connection refused" in message
    assert "2 tries" in message and policy.step_log[0]["attempts"] == 2
    # Refused connections do not wait for the deadline: only the backoff.
    assert elapsed < DEADLINE_S


@pytest.mark.parametrize("handler", [hung, trickle_body, trickle_headers], ids=lambda h: h.__name__)
def test_hung_or_trickling_server_is_cut_at_the_deadline(fake, handler):
    server = fake(handler)
    policy, obs = first_step(server.base_url)
    elapsed, out = timed_act(policy, obs)
    assert isinstance(out, EndpointUnavailable), out
    assert f"no complete answer within the {DEADLINE_S:g} s deadline" in str(out)
    assert policy.step_log[0]["attempts"] == 2 and server.connections == 2
    # Two tries of 0.5 s and a 0.05 s backoff: the whole request is bounded by the deadline.
    assert elapsed < 3 * DEADLINE_S
    assert elapsed <= policy.worst_case_request_s + SLACK_S


def test_an_answer_cut_short_is_a_transport_failure(fake):
    server = fake(cut_short)
    policy, obs = first_step(server.base_url)
    elapsed, out = timed_act(policy, obs)
    assert isinstance(out, EndpointUnavailable) and "cut short" in str(out)
    assert server.connections == 2 and elapsed < DEADLINE_S


def test_500_always_is_retried_then_unavailable(fake):
    server = fake(answer("500 Internal Server Error", error_body("CUDA out of memory")))
    policy, obs = first_step(server.base_url)
    elapsed, out = timed_act(policy, obs)
    assert isinstance(out, EndpointUnavailable)
    assert "HTTP 500: CUDA out of memory" in str(out) and server.connections == 2
    assert elapsed < DEADLINE_S


def test_hung_server_ends_the_episode_within_one_request_bound(fake):
    server = fake(hung)
    policy = make_policy("endpoint", base_url=server.base_url, **CONFIG)
    t0 = time.monotonic()
    with pytest.raises(EndpointUnavailable, match="deadline"):
        run_episode(small_case(), policy, seed=0, backend="geometric")
    assert time.monotonic() - t0 <= policy.worst_case_request_s + SLACK_S
    assert len(policy.step_log) == 1  # the first failing request ended the episode


# -- 4xx: never retried --------------------------------------------------------------------------
def test_400_is_not_retried_and_names_status_and_reason(fake):
    server = fake(
        answer("400 Bad Request", error_body("messages[1].content[0]: image is not decodable"))
    )
    policy, obs = first_step(server.base_url)
    elapsed, out = timed_act(policy, obs)
    assert isinstance(out, Unparsable) and out.text == ""
    assert out.error == (
        f"endpoint: HTTP 400 from {policy.url}: messages[1].content[0]: image is not decodable"
    )
    assert server.connections == 1 and policy.step_log[0]["attempts"] == 1
    assert elapsed < DEADLINE_S


def test_busy_4xx_is_unavailable_at_once(fake):
    server = fake(answer("429 Too Many Requests", error_body("rate limit reached")))
    policy, obs = first_step(server.base_url)
    _, out = timed_act(policy, obs)
    assert isinstance(out, EndpointUnavailable) and "HTTP 429" in str(out)
    assert "rate limit reached" in str(out) and server.connections == 1


@pytest.mark.parametrize("status", ["401 Unauthorized", "404 Not Found", "307 Temporary Redirect"])
def test_configuration_errors_raise_at_once(fake, status):
    server = fake(answer(status, error_body("no such model: x")))
    policy, obs = first_step(server.base_url, model="x")
    _, out = timed_act(policy, obs)
    assert isinstance(out, EndpointError) and f"HTTP {status.split()[0]}" in str(out)
    assert "no such model: x" in str(out) and server.connections == 1


# -- garbage 200: the step is unparsable, nothing raises -----------------------------------------
@pytest.mark.parametrize(
    "body,reason",
    [
        (b"<html>oops</html>", "not JSON"),
        (b"\xff\xfe\x00garbage", "not JSON"),
        (b"[" * 100_000, "not JSON"),
        (b"[1, 2]", "not a JSON object"),
        (b'{"id": "x"}', "no choices[0].message"),
        (b'{"choices": [{"message": {"content": null}}]}', "no text content"),
        (b"", "not JSON"),
    ],
    ids=["html", "binary", "deep", "list", "no-choices", "null-content", "empty"],
)
def test_garbage_answers_are_unparsable_steps(fake, body, reason):
    server = fake(answer("200 OK", body))
    policy, obs = first_step(server.base_url)
    elapsed, out = timed_act(policy, obs)
    assert isinstance(out, Unparsable) and reason in out.error and out.text == ""
    assert server.connections == 1 and elapsed < DEADLINE_S


def test_garbage_episode_runs_to_the_end(fake):
    server = fake(answer("200 OK", b"<html>maintenance</html>"))
    policy = make_policy("endpoint", base_url=server.base_url, **CONFIG)
    result = run_episode(small_case(), policy, seed=0, backend="geometric")
    assert {s.reason for s in result.steps} == {"unparsable"}
    assert result.metrics.invalid_by_reason == {"unparsable": len(result.steps)}


# -- configuration -------------------------------------------------------------------------------
def test_defaults_and_worst_case_are_as_documented():
    policy = EndpointPolicy()
    assert (
        (policy.deadline_s, policy.tries) == (DEFAULT_DEADLINE_S, 1 + DEFAULT_RETRIES) == (30.0, 3)
    )
    assert DEFAULT_BACKOFF_S == 0.5 and [policy.backoff(k) for k in (1, 2)] == [0.5, 1.0]
    assert policy.worst_case_request_s == 91.5
    assert policy.config()["worst_case_request_s"] == 91.5


def test_deadline_configuration():
    assert EndpointPolicy(timeout_s=7).deadline_s == 7.0  # the older name
    for bad in (
        {"deadline_s": 0},
        {"deadline_s": float("nan")},
        {"deadline_s": "5"},
        {"retries": -1},
        {"backoff_s": float("inf")},
    ):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            EndpointPolicy(**bad)
    with pytest.raises(ConfigError, match="old name"):
        EndpointPolicy(deadline_s=5, timeout_s=5)
