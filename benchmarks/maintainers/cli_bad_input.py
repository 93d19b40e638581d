"""How fast and how plainly ``packlab`` refuses bad input (target: one line, exit code 2,
nothing written, within 0.5 s on a quiet machine).

Usage:
    python benchmarks/maintainers/cli_bad_input.py            # 5 runs of each, fresh interpreters
    python benchmarks/maintainers/cli_bad_input.py --runs 9

Each bad command line runs in a fresh ``python -m packlab.cli.main`` subprocess inside an empty
temporary directory (so a run directory or dataset it made would show), ``--runs`` times,
interleaved so that a burst of load from other processes spreads over every row. The table
gives the exit code, the lines on stderr, whether anything was written, the median and minimum
wall time, and whether all four goals hold. The machine may be shared: the load average at
start and end is printed; the minimum is the least disturbed run.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

#: Goal wall time of a refusal (seconds).
TARGET_S = 0.5
#: Exit code of bad input (packlab.core.errors.EXIT_USAGE).
EXIT_USAGE = 2
#: (what is wrong, the command line): the typical mistakes of each command.
BAD_INPUTS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("misspelt policy", ("bench", "--policies", "dblff")),
    ("bad policy-arg key", ("bench", "--policy-arg", "irbpp:modle=x")),
    ("bad policy-arg value", ("bench", "--policy-arg", "irbpp:runtime=onxx")),
    ("missing model dir", ("bench", "--policy-arg", "irbpp:model=nosuch")),
    ("--episodes 0", ("generate", "--difficulty", "easy", "--episodes", "0", "--out", "d")),
    ("missing cases file", ("bench", "--cases", "nosuch.jsonl")),
    ("bad --seeds", ("bench", "--seeds", "0-x")),
    ("bad --workers", ("bench", "--workers", "-1")),
    ("misspelt subcommand", ("bnech",)),
    ("misspelt suite", ("bench", "--cases", "packlab-bench-v2")),
    ("policy-arg of a policy not run", ("bench", "--policy-arg", "plan:first=2")),
    ("vlm model dir missing", ("bench", "--policy-arg", "vlm:model=nosuch")),
    ("misspelt backend", ("bench", "--backend", "mujco")),
    (
        "misspelt teacher",
        ("generate", "--difficulty", "easy", "--episodes", "1", "--teacher", "plna", "--out", "d"),
    ),
    ("export: not a model dir", ("export", "onnx", "nosuch")),
)


@dataclass
class Row:
    what: str
    argv: tuple[str, ...]
    codes: set[int] = field(default_factory=set)
    lines: set[int] = field(default_factory=set)
    wrote: bool = False
    times: list[float] = field(default_factory=list)
    message: str = ""


def run_once(row: Row) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "packlab.cli.main", *row.argv],
            cwd=tmp,
            check=False,  # the exit code is what is measured
            capture_output=True,
            text=True,
        )
        row.times.append(time.perf_counter() - start)
        err = done.stderr.strip().splitlines()
        row.codes.add(done.returncode)
        row.lines.add(len(err))
        row.wrote |= any(Path(tmp).iterdir())
        row.message = err[-1] if err else ""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--messages", action="store_true", help="print each error line too")
    args = parser.parse_args()
    rows = [Row(what, argv) for what, argv in BAD_INPUTS]
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    for _ in range(args.runs):
        for row in rows:
            run_once(row)
    print(f"load average at end: {os.getloadavg()[0]:.2f}\n")
    header = f"| {'input':<32} | exit | stderr lines | wrote | median s | min s | goal met |"
    print(header)
    print("|" + "|".join("-" * (len(c)) for c in header.split("|")[1:-1]) + "|")
    met = 0
    for r in rows:
        median, best = statistics.median(r.times), min(r.times)
        ok = r.codes == {EXIT_USAGE} and r.lines == {1} and not r.wrote and best <= TARGET_S
        met += ok
        codes = ",".join(map(str, sorted(r.codes)))
        lines = ",".join(map(str, sorted(r.lines)))
        print(
            f"| {r.what:<32} | {codes:>4} | {lines:>12} | {'yes' if r.wrote else 'no':>5} "
            f"| {median:8.2f} | {best:5.2f} | {'yes' if ok else 'NO':>8} |"
        )
        if args.messages:
            print(f"|   {r.message}")
    print(
        f"\n{met} of {len(rows)} refused in one line, exit {EXIT_USAGE}, nothing written, "
        f"min <= {TARGET_S} s"
    )
    return 0 if met == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
