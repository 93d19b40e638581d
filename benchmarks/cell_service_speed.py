r"""Per-step milliseconds of the cell service (``packlab cell serve``), stage by stage, and the
most sessions it serves at once without an error.

Usage:
    python benchmarks/cell_service_speed.py                      # 8 hard cases x 8 steps
    python benchmarks/cell_service_speed.py --cases 4 --steps 4 --at-once 1,4,8

The cases are hard ones generated here in the ``train`` seed domain (user seed 7410), never read
from a bench suite. Each step is rendered by packlab's simulated cameras (the container packed
by the case's perfect plan so far, the next ``buffer_size`` boxes on the buffer, the
``--preset`` sensor's noise; ``packlab.cell.simulated``) and sent as a cell sends it: a float32
container image, a float32 buffer image, no detections. Request bodies are encoded before the
clock starts (the cell's side).

1. **One core**: ``packlab cell serve --workers 1`` pinned to one core (BLAS and OpenMP at one
   thread), sessions one after another, ``plan-fast``. Per step, p50 / p95 / max of each stage the
   service reports (decode, heightmap, segmentation, policy, its total), of the round trip the
   client sees, and of the *service time*: the round trip less the policy's own time (HTTP,
   JSON, decoding, perception, the answer). Goal: service time p95 <= 60 ms. The server
   process's CPU time per step (from /proc) is shown beside it: a shared machine's other jobs
   stretch wall times, not CPU time.
2. **Two cores**: ``--workers 2`` on two cores; N cells at once (threads), each opening a
   session on a case, sending ``--concurrent-steps`` steps and closing it. Per N: errors (any
   answer but 2xx, or no answer within ``--timeout`` s), steps per second, round-trip p50 /
   p95. The most N with no error is printed (goal: >= 8).

The load average is printed before and after: compare runs only at similar loads.
"""

from __future__ import annotations

import argparse
import os
import platform
import socket
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import httpx
import numpy as np

from packlab.cell.simulated import SimulatedStep, planned_steps, session_request
from packlab.core.types import Case
from packlab.datagen import generate_cases
from packlab.datagen.guard import require_training_cases

SEED = 7410
SERVE = "import sys; from packlab.cli.main import main; sys.exit(main(sys.argv[1:]))"
ONE_THREAD = {v: "1" for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}


@dataclass(frozen=True)
class Cell:
    """One case's session request and step request bodies, encoded."""

    session: bytes
    steps: list[bytes]


def cells(args: argparse.Namespace) -> list[Cell]:
    cases = generate_cases("hard", args.cases, SEED, validate=False, domain="train")
    cases = require_training_cases(cases, f"cell speed cases (seed {SEED})", "timing")
    out = []
    for i, case in enumerate(cases):
        steps = planned_steps(case, args.preset, args.steps, seed=i)
        out.append(_encoded(case, args.preset, steps))
    return out


def _encoded(case: Case, preset: str, steps: list[SimulatedStep]) -> Cell:
    session = session_request(case, preset, steps[0]).model_dump_json(exclude_none=True)
    bodies = [s.request().model_dump_json(exclude_none=True).encode() for s in steps]
    return Cell(session.encode(), bodies)


class Server:
    """``packlab cell serve`` in a subprocess pinned to ``cores``."""

    def __init__(self, workers: int, cores: set[int]):
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            self.port = int(probe.getsockname()[1])
        argv = ["cell", "serve", "--port", str(self.port), "--workers", str(workers)]
        self.process = subprocess.Popen(
            [sys.executable, "-c", SERVE, *argv],
            env={**os.environ, **ONE_THREAD},
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        # Before its first request: the planner processes it starts then inherit the cores.
        os.sched_setaffinity(self.process.pid, cores)
        self.url = f"http://127.0.0.1:{self.port}"
        deadline = time.monotonic() + 60
        while True:
            try:
                httpx.get(f"{self.url}/v1/health", timeout=1.0).raise_for_status()
                break
            except httpx.HTTPError:
                if time.monotonic() > deadline or self.process.poll() is not None:
                    raise RuntimeError("packlab cell serve did not start") from None
                time.sleep(0.2)

    def cpu_ms(self) -> float:
        """The server process's CPU time so far (user + system), ms."""
        with open(f"/proc/{self.process.pid}/stat", encoding="ascii") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) * 1000.0 / os.sysconf("SC_CLK_TCK")

    def stop(self) -> None:
        self.process.terminate()
        self.process.wait(timeout=30)


def _post(client: httpx.Client, path: str, body: bytes) -> httpx.Response:
    return client.post(path, content=body, headers={"content-type": "application/json"})


def one_core(all_cells: list[Cell], timeout: float) -> dict[str, list[float]]:
    """Per-stage ms of every step, sessions one after another, on one core."""
    server = Server(workers=1, cores={0})
    rows: dict[str, list[float]] = {}
    try:
        with httpx.Client(base_url=server.url, timeout=timeout) as client:
            for cell in all_cells:
                session_id = _post(client, "/v1/sessions", cell.session).json()["session_id"]
                for body in cell.steps:
                    cpu, started = server.cpu_ms(), time.perf_counter()
                    response = _post(client, f"/v1/sessions/{session_id}/step", body)
                    trip = 1e3 * (time.perf_counter() - started)
                    response.raise_for_status()
                    t = response.json()["timings_ms"]
                    row = {
                        **t,
                        "service total less policy": t["total"] - t["policy"],
                        "round trip": trip,
                        "service time (round trip less policy)": trip - t["policy"],
                        "server CPU less policy": server.cpu_ms() - cpu - t["policy"],
                    }
                    for key, value in row.items():
                        rows.setdefault(key, []).append(value)
                client.delete(f"/v1/sessions/{session_id}")
    finally:
        server.stop()
    return rows


def _run_cell(url: str, cell: Cell, steps: int, timeout: float) -> tuple[list[float], int]:
    """One cell's session: (round-trip ms per step, errors)."""
    trips, errors = [], 0
    try:
        with httpx.Client(base_url=url, timeout=timeout) as client:
            opened = _post(client, "/v1/sessions", cell.session)
            if opened.status_code != 201:
                return trips, 1
            session_id = opened.json()["session_id"]
            for body in cell.steps[:steps]:
                started = time.perf_counter()
                response = _post(client, f"/v1/sessions/{session_id}/step", body)
                trips.append(1e3 * (time.perf_counter() - started))
                errors += response.status_code != 200
            errors += client.delete(f"/v1/sessions/{session_id}").status_code != 204
    except httpx.HTTPError:
        errors += 1
    return trips, errors


def two_cores(all_cells: list[Cell], counts: list[int], steps: int, timeout: float) -> list[dict]:
    """Per count of sessions at once: errors, steps per second, round-trip percentiles."""
    server = Server(workers=2, cores={0, 1})
    out = []
    try:
        with ThreadPoolExecutor(2) as pool:  # start both planner processes, unmeasured
            list(pool.map(lambda c: _run_cell(server.url, c, 1, timeout), all_cells[:2] * 2))
        for n in counts:
            chosen = [all_cells[i % len(all_cells)] for i in range(n)]
            started = time.perf_counter()
            with ThreadPoolExecutor(n) as pool:
                done = list(pool.map(lambda c: _run_cell(server.url, c, steps, timeout), chosen))
            wall = time.perf_counter() - started
            trips = [t for cell_trips, _ in done for t in cell_trips]
            errors = sum(e for _, e in done)
            p50, p95 = np.percentile(trips, [50, 95]) if trips else (np.nan, np.nan)
            out.append({"n": n, "errors": errors, "steps": len(trips), "per_s": len(trips) / wall,
                        "p50": p50, "p95": p95})  # fmt: skip
    finally:
        server.stop()
    return out


def _print_stages(rows: dict[str, list[float]]) -> None:
    print("\n| stage (ms per step) | p50 | p95 | max |")
    print("|---|---:|---:|---:|")
    for name, values in rows.items():
        p50, p95 = np.percentile(values, [50, 95])
        print(f"| {name.replace('_', ' ')} | {p50:.1f} | {p95:.1f} | {max(values):.1f} |")


def _print_sessions(rows: list[dict]) -> None:
    print("\n| sessions at once | errors | steps | steps/s | round trip p50 ms | p95 ms |")
    print("|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['n']} | {r['errors']} | {r['steps']} | {r['per_s']:.1f} | "
            f"{r['p50']:.0f} | {r['p95']:.0f} |"
        )
    clean = [r["n"] for r in rows if r["errors"] == 0]
    print(f"\nmost sessions at once without an error: {max(clean) if clean else 0}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=8, help="hard cases (default 8)")
    parser.add_argument("--steps", type=int, default=8, help="steps per case (default 8)")
    parser.add_argument("--preset", default="structured-light", help="sensor preset")
    parser.add_argument("--at-once", default="1,2,4,8,16,32,64", help="sessions at once")
    parser.add_argument("--concurrent-steps", type=int, default=3, help="steps per session")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds per request")
    args = parser.parse_args()
    if len(os.sched_getaffinity(0)) < 2:
        sys.exit("needs two cores")
    machine = platform.processor() or platform.machine()
    print(f"{machine}, {os.cpu_count()} cores, Python {platform.python_version()}")
    print(f"load average {os.getloadavg()[0]:.2f} at the start")
    all_cells = cells(args)
    total = sum(len(c.steps) for c in all_cells)
    print(f"{len(all_cells)} hard cases, {total} steps, preset {args.preset}, plan-fast")
    print("\n1. One core, sessions one after another (packlab cell serve --workers 1)")
    _print_stages(one_core(all_cells, args.timeout))
    print(f"\nload average {os.getloadavg()[0]:.2f}")
    print("\n2. Two cores (packlab cell serve --workers 2), sessions at once")
    counts = [int(v) for v in args.at_once.split(",")]
    _print_sessions(two_cores(all_cells, counts, args.concurrent_steps, args.timeout))
    print(f"\nload average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
