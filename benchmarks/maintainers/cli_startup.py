"""Start-up time of ``packlab --help`` and of every ``packlab <command> --help``.

Usage:
    python benchmarks/maintainers/cli_startup.py              # 7 runs of each, fresh interpreters
    python benchmarks/maintainers/cli_startup.py --runs 15

Each command line runs in a fresh subprocess of the ``packlab`` console script beside this
interpreter (``python -m packlab.cli.main`` when there is none; a pyenv shim in PATH would add
its own start-up), ``--runs`` times, interleaved so that a burst of load from other processes
spreads over every row. ``python -c pass`` is the floor: an
interpreter that imports nothing. The table gives the median and the minimum wall time and whether
the median is within the target (0.3 s). The machine may be shared: the load average at start
and end is printed too; the minimum is the least disturbed run.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

#: Target wall time of a help text (seconds).
TARGET_S = 0.3
#: The command lines timed; the first row is the interpreter alone.
LINES: tuple[tuple[str, ...], ...] = (
    ("-c", "pass"),
    ("--help",),
    ("bench", "--help"),
    ("bench", "report", "--help"),
    ("bench", "compare", "--help"),
    ("cases", "--help"),
    ("generate", "--help"),
    ("inspect-data", "--help"),
    ("train", "--help"),
    ("export", "--help"),
    ("serve", "--help"),
    ("viz", "--help"),
)


#: The installed console script, else the module it runs.
SCRIPT = Path(sys.executable).with_name("packlab")
PACKLAB = [str(SCRIPT)] if SCRIPT.is_file() else [sys.executable, "-m", "packlab.cli.main"]


def argv_of(line: tuple[str, ...]) -> list[str]:
    return [sys.executable, *line] if line[0] == "-c" else [*PACKLAB, *line]


def label_of(line: tuple[str, ...]) -> str:
    return "python -c pass" if line[0] == "-c" else "packlab " + " ".join(line)


def time_once(argv: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


def measure(runs: int) -> dict[tuple[str, ...], list[float]]:
    """Seconds per run of every line; round-robin over the lines, after one warm-up each."""
    for line in LINES:  # the first run fills the OS file cache and writes .pyc files
        time_once(argv_of(line))
    times: dict[tuple[str, ...], list[float]] = {line: [] for line in LINES}
    for _ in range(runs):
        for line in LINES:
            times[line].append(time_once(argv_of(line)))
    return times


def table(times: dict[tuple[str, ...], list[float]]) -> str:
    rows = [
        f"| command | median (s) | min (s) | median <= {TARGET_S} s |",
        "|---|---:|---:|---|",
    ]
    for line, seconds in times.items():
        median = statistics.median(seconds)
        ok = "(floor)" if line[0] == "-c" else ("yes" if median <= TARGET_S else "**no**")
        rows.append(f"| `{label_of(line)}` | {median:.3f} | {min(seconds):.3f} | {ok} |")
    return "\n".join(rows)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7, help="timed runs of each line (default 7)")
    args = parser.parse_args()
    print(f"load average at start: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    times = measure(args.runs)
    print(f"load average at end: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{args.runs} runs each of {' '.join(PACKLAB)} (Python {sys.version.split()[0]})\n")
    print(table(times))
    return 0


if __name__ == "__main__":
    sys.exit(main())
