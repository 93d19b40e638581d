"""How fast a stop signal to the main process ends every process of a run (target: <= 5 s,
records intact, the same command resumes).

Usage:
    python benchmarks/maintainers/stop_time.py    # every command, executor and signal, once
    python benchmarks/maintainers/stop_time.py --repeats 3

Each row starts a real ``packlab`` command in a fresh temporary directory, waits until it has
written its first result (a bench record, a generate shard) or started its environment
processes (``train rl``), sends the signal to the main process alone (as ``timeout``, systemd or
a job scheduler do), and measures the seconds until the main process exited and until no
process it had started was left. Then it reruns the same command and says whether it resumed
(bench: records found already done; generate: the dataset completed; train rl is not rerun,
its resume is a checkpoint's and is tested in tests/rl). The machine may be shared: the load
average is printed.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from packlab.core.stop import descendants, is_alive

GOAL_S = 5.0

BENCH = (
    "bench", "--cases", "packlab-bench-v1", "--difficulty", "hard", "--policies", "dblf",
    "--seeds", "0", "--workers", "2", "--no-html", "--no-figures", "--no-progress", "--out", "run",
)  # fmt: skip
GENERATE = (
    "generate", "--difficulty", "hard", "--episodes", "12", "--seed", "3", "--shard-size", "1",
    "--teacher", "plan", "--sft", "none", "--workers", "2", "--no-progress", "--out", "data",
)  # fmt: skip
TRAIN = (
    "train", "rl", "--agent", "irbpp", "--cases", "packdata-mini", "--steps", "200000",
    "--envs", "2", "--eval-every", "100000", "--eval-cases", "2", "--out", "rl",
)  # fmt: skip


def _lines(path: Path) -> int:
    return len(path.read_text().splitlines()) if path.is_file() else 0


@dataclass(frozen=True)
class Case:
    name: str
    args: tuple[str, ...]
    started: Callable[[Path], bool]  # the run has a result to keep (or its workers)
    resumed: Callable[[Path, str], bool] | None  # rerun's stderr -> did it resume


CASES = {
    "bench": Case(
        "bench",
        BENCH,
        lambda d: _lines(d / "run" / "episodes.jsonl") >= 2,
        lambda d, err: "already done" in err,
    ),
    "generate": Case(
        "generate",
        GENERATE,
        lambda d: any((d / "data" / "meta" / "shards").glob("*.json")),
        lambda d, err: (d / "data" / "meta" / "info.json").is_file(),
    ),
    "train rl": Case("train rl", TRAIN, lambda d: (d / "rl" / "config.json").is_file(), None),
}


def measure(case: Case, executor: str | None, signum: int) -> list[str]:
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        args = [*case.args, *(("--executor", executor) if executor else ())]
        command = [sys.executable, "-m", "packlab.cli.main", *args]
        proc = subprocess.Popen(
            command, cwd=d, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
        )
        while not case.started(d) or len(descendants(proc.pid)) < 2:
            if proc.poll() is not None:
                return [case.name, executor or "-", signal.Signals(signum).name, "ended early"]
            time.sleep(0.05)
        started = set(descendants(proc.pid))
        sent = time.monotonic()
        os.kill(proc.pid, signum)
        proc.communicate(timeout=120)
        main_s = time.monotonic() - sent
        while any(is_alive(p) for p in started) and time.monotonic() - sent < 60:
            time.sleep(0.02)
        all_s = time.monotonic() - sent
        left = sum(is_alive(p) for p in started)
        resumed = "-"
        if case.resumed is not None:
            again = subprocess.run(command, cwd=d, capture_output=True, text=True, check=False)
            resumed = "yes" if again.returncode == 0 and case.resumed(d, again.stderr) else "NO"
        ok = all_s <= GOAL_S and left == 0 and resumed != "NO"
        return [
            case.name,
            executor or "-",
            signal.Signals(signum).name,
            str(proc.returncode),
            str(len(started)),
            f"{main_s:.2f}",
            f"{all_s:.2f}",
            str(left),
            resumed,
            "yes" if ok else "NO",
        ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--no-ray", action="store_true", help="skip the Ray rows")
    args = parser.parse_args()
    plan = [
        (CASES["bench"], "process", signal.SIGTERM),
        (CASES["bench"], "process", signal.SIGINT),
        (CASES["bench"], "ray", signal.SIGTERM),
        (CASES["generate"], "process", signal.SIGTERM),
        (CASES["generate"], "ray", signal.SIGINT),
        (CASES["train rl"], None, signal.SIGTERM),
        (CASES["train rl"], None, signal.SIGINT),
    ]
    if args.no_ray:
        plan = [p for p in plan if p[1] != "ray"]
    print(f"load average at start: {os.getloadavg()[0]:.1f}", file=sys.stderr)
    header = ["command", "executor", "signal", "exit", "processes", "main gone s",
              "all gone s", "left", "resumed", f"<= {GOAL_S:g} s"]  # fmt: skip
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for _ in range(args.repeats):
        for case, executor, signum in plan:
            print("| " + " | ".join(measure(case, executor, signum)) + " |", flush=True)
    print(f"load average at end: {os.getloadavg()[0]:.1f}", file=sys.stderr)


if __name__ == "__main__":
    main()
