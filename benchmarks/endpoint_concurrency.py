r"""Episodes per minute of the ``endpoint`` policy against a model server with a fixed latency,
by ``packlab bench --concurrency N``.

Usage:
    python benchmarks/endpoint_concurrency.py                          # all levels, seed 0
    python benchmarks/endpoint_concurrency.py --difficulty medium --seeds 0-3 --backend mujoco

A scripted OpenAI-compatible server runs in this process (``packlab.vlm.serve.server``); it
answers every request after ``--delay-ms`` (default 200) and counts the requests it holds at
once. ``--answers oracle`` (default) answers with the oracle's action for the step
(:mod:`packlab.vlm.serve.oracle_answers`), so every step places a box and the worker simulates it
as a played model's would; ``--answers corner`` answers the first box shown, unrotated, in the
container's corner (valid for the first box, an invalid step that sets the box aside later:
little physics per step, which isolates the client side). For each N it runs
``packlab bench --policies endpoint --workers W --concurrency N`` on
packlab-bench-v1 in a fresh scratch directory and prints:

* episodes per minute, over the invocation's own wall time (invocations.jsonl: start to last
  record, so interpreter start-up is left out);
* requests in flight as the server saw them: the time-weighted mean over the run and the max;
* efficiency = episodes per minute / (N x episodes per minute at N=1): 1.0 is perfect scaling
  (the first N is the reference; ``--concurrency-values`` should start with 1).

With few episodes per slot (episodes / (W x N)) the last, longest episodes dominate the wall
time and efficiency drops for that reason alone; ``--seeds`` adds episodes.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from packlab.bench.options import parse_seeds
from packlab.bench.suites import load_suite
from packlab.vlm.serve.oracle_answers import OracleModel, oracle_model
from packlab.vlm.serve.server import serve

#: The ``corner`` answer to every request: a parsable action (see the module docstring).
CORNER = json.dumps({"object_id": 0, "rotation": 0, "x": 0, "y": 0})
SUITE = "packlab-bench-v1"
CLI = "import sys; from packlab.cli.main import main; sys.exit(main(sys.argv[1:]))"


class DelayedModel:
    """Answers after a fixed delay; tracks requests in flight (max, and their integral over
    time for the mean)."""

    def __init__(self, delay_s: float, oracle: OracleModel | None) -> None:
        self.delay_s, self.oracle = delay_s, oracle
        self._lock = threading.Lock()
        self.now = self.most = self.requests = 0
        self._area = 0.0
        self._since: float | None = None  # first request
        self._last = 0.0  # last change of `now`

    def _change(self, by: int) -> None:
        with self._lock:
            t = time.monotonic()
            if self._since is None:
                self._since = self._last = t
            self._area += self.now * (t - self._last)
            self._last, self.now = t, self.now + by
            self.most = max(self.most, self.now)
            self.requests += by > 0

    def __call__(self, body: dict) -> str:
        self._change(+1)
        try:
            time.sleep(self.delay_s)
            return CORNER if self.oracle is None else self.oracle(body).content
        finally:
            self._change(-1)

    def mean_in_flight(self) -> float:
        span = 0.0 if self._since is None else self._last - self._since
        return self._area / span if span > 0 else 0.0


@dataclass(frozen=True)
class Row:
    concurrency: int
    episodes: int
    wall_s: float
    mean_in_flight: float
    max_in_flight: int
    requests: int

    @property
    def per_minute(self) -> float:
        return 60.0 * self.episodes / self.wall_s


def run_one(
    args: argparse.Namespace, concurrency: int, scratch: Path, oracle: OracleModel | None
) -> Row:
    """One bench invocation at ``concurrency`` against a fresh server."""
    model = DelayedModel(args.delay_ms / 1000.0, oracle)
    out = scratch / f"n{concurrency}"
    with serve(model) as server:
        argv = ["bench", "--policies", "endpoint", "--backend", args.backend]
        argv += ["--seeds", args.seeds, "--workers", str(args.workers)]
        argv += ["--concurrency", str(concurrency), "--out", str(out)]
        argv += ["--policy-arg", f"endpoint:base_url={server.base_url}"]
        argv += ["--policy-arg", f"endpoint:prompt={args.prompt}"]
        argv += ["--policy-arg", "endpoint:tag_requests=true"]  # the oracle's key needs it
        argv += ["--no-progress", "--no-figures", "--no-html"]
        if args.difficulty:
            argv += ["--difficulty", args.difficulty]
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        done = subprocess.run(
            [sys.executable, "-c", CLI, *argv], check=False, env=env, capture_output=True, text=True
        )
    if done.returncode != 0:
        raise SystemExit(f"packlab bench failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
    log = [json.loads(line) for line in (out / "invocations.jsonl").read_text().splitlines()]
    return Row(
        concurrency,
        log[-1]["ran"],
        log[-1]["wall_s"],
        model.mean_in_flight(),
        model.most,
        model.requests,
    )


def table(rows: list[Row]) -> str:
    """The results as a Markdown table (efficiency against the first row, per request slot)."""
    base = rows[0].per_minute / rows[0].concurrency
    lines = [
        "|  N | episodes | wall s | episodes/min | requests/s | in flight: mean | max | eff. |",
        "| -: | -------: | -----: | -----------: | ---------: | --------------: | --: | ---: |",
    ]
    for r in rows:
        eff = r.per_minute / (r.concurrency * base)
        lines.append(
            f"| {r.concurrency:2d} | {r.episodes:8d} | {r.wall_s:6.1f} | {r.per_minute:12.1f} "
            f"| {r.requests / r.wall_s:10.1f} | {r.mean_in_flight:15.1f} | {r.max_in_flight:3d} "
            f"| {eff:4.2f} |"
        )
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--concurrency-values", default="1,2,4,8,16", help="N values; first: reference")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--delay-ms", type=float, default=200.0, help="server latency per request")
    p.add_argument("--backend", choices=("geometric", "mujoco"), default="geometric")
    p.add_argument("--difficulty", default="", help="levels to run (default: all)")
    p.add_argument("--seeds", default="0")
    p.add_argument("--answers", choices=("oracle", "corner"), default="oracle")
    p.add_argument("--prompt", choices=("packlab", "reference"), default="packlab")
    args = p.parse_args()
    values = [int(v) for v in args.concurrency_values.split(",")]
    print(
        f"{SUITE}, levels {args.difficulty or 'all'}, seeds {args.seeds}, {args.answers} "
        f"answers, prompt {args.prompt}, "
        f"backend {args.backend}, workers {args.workers}, server delay {args.delay_ms:g} ms, "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}",
        flush=True,
    )
    oracle = None
    if args.answers == "oracle":
        levels = set(args.difficulty.split(",")) if args.difficulty else None
        cases = [c for c in load_suite(SUITE) if levels is None or c.difficulty in levels]
        seeds = parse_seeds(args.seeds)
        oracle = oracle_model(cases, seeds, {"prompt": args.prompt})
    rows: list[Row] = []
    with tempfile.TemporaryDirectory(prefix="packlab-concurrency-") as scratch:
        for n in values:
            rows.append(run_one(args, n, Path(scratch), oracle))
            print(f"N={n}: {rows[-1].episodes} episodes in {rows[-1].wall_s:.1f} s", flush=True)
    print(table(rows))
    if oracle is not None:
        print(f"requests without a recorded answer: {oracle.unknown} of {oracle.requests}")
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
