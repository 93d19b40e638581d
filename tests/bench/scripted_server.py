"""A scripted OpenAI-compatible model server in a process of its own, for bench runs of the
``endpoint`` policy.

With ``--concurrency`` above 1 (or ``--workers`` above 1) the bench forks its workers
(``packlab.executors``). Forking while a server thread runs in the same process copies that
thread's locks in whatever state they happen to be, so these tests never serve from the test
process: :class:`ScriptedServer` starts ``python scripted_server.py`` (packlab's own
``serve()`` with a :class:`Script`) and talks to it through files.

A script answers a request by its key (:func:`packlab.vlm.serve.oracle_answers.request_key`),
else with
``default``; it can wait ``delay_s`` before each answer, answer
503 after ``answer_at_most`` answers (a server going away) or exit at once on the request after
``die_after`` answers (a server that dies: every connection is dropped, then refused).
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Self

from packlab.vlm.serve.oracle_answers import request_key

#: Seconds a server process may take to start listening.
START_TIMEOUT_S = 30.0


@dataclass(frozen=True)
class Script:
    answers: dict[str, str] = field(default_factory=dict)  # request_key -> answer text
    default: str = "?"
    delay_s: float = 0.0
    answer_at_most: int | None = None
    die_after: int | None = None


class _Model:
    """The server process's answer function; counts the requests it holds at once."""

    def __init__(self, script: Script) -> None:
        self.script = script
        self.lock = threading.Lock()
        self.now = self.most = self.answered = 0

    def __call__(self, body: dict[str, Any]) -> str:
        from packlab.vlm.serve.protocol import RequestError

        s = self.script
        with self.lock:
            if s.die_after is not None and self.answered >= s.die_after:
                os._exit(0)  # no goodbye: every open connection drops with the process
            if s.answer_at_most is not None and self.answered >= s.answer_at_most:
                raise RequestError("the model server is going away", status=503)
            self.now += 1
            self.most = max(self.most, self.now)
        try:
            time.sleep(s.delay_s)
            return s.answers.get(request_key(body), s.default)
        finally:
            with self.lock:
                self.now -= 1
                self.answered += 1


class ScriptedServer:
    """A server process playing ``script`` on 127.0.0.1 (``port`` 0: a free one); a context
    manager. ``stats()`` after ``close()``: answered, most requests held at once."""

    def __init__(self, script: Script, folder: Path, port: int = 0) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        self._stats = folder / f"stats-{time.monotonic_ns()}.json"
        spec = self._stats.with_suffix(".script.json")
        spec.write_text(json.dumps(dataclasses.asdict(script)), encoding="utf-8")
        self.process = subprocess.Popen(
            [sys.executable, __file__, str(spec), str(port), str(self._stats)],
            stdout=subprocess.PIPE,
            text=True,
        )
        self.port = self._read_port()
        self.base_url = f"http://127.0.0.1:{self.port}/v1"

    def _read_port(self) -> int:
        assert self.process.stdout is not None
        timer = threading.Timer(START_TIMEOUT_S, self.process.kill)
        timer.start()
        try:
            line = self.process.stdout.readline()
        finally:
            timer.cancel()
        if not line.strip().isdigit():
            self.process.kill()
            raise RuntimeError(f"the scripted server did not start (said {line!r})")
        return int(line)

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        if self.process.stdout is not None:
            self.process.stdout.close()

    def stats(self) -> dict[str, int]:
        return json.loads(self._stats.read_text(encoding="utf-8"))

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def main(spec: str, port: str, stats: str) -> int:
    from packlab.vlm.serve.server import serve

    script = Script(**json.loads(Path(spec).read_text(encoding="utf-8")))
    model = _Model(script)

    def stop(*_: object) -> None:
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, stop)
    server = serve(model, port=int(port))
    print(server.port, flush=True)
    try:
        while True:
            time.sleep(3600)
    finally:
        server.close()
        counts = {"answered": model.answered, "most": model.most}
        Path(stats).write_text(json.dumps(counts), encoding="utf-8")


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
