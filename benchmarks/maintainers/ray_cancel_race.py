"""Does ``ray.cancel`` abort the driver? The reason packlab's Ray executor never cancels a task.

Usage:
    python benchmarks/maintainers/ray_cancel_race.py                 # 400 rounds per mode
    python benchmarks/maintainers/ray_cancel_race.py --rounds 1000

Each mode runs in a fresh driver process with its own local Ray cluster (2 CPUs). A round
submits 12 tasks of 0-4 ms, waits for the first, and then, after 0-4 ms, treats the rest as
packlab's executor would on an early stop: ``force`` cancels them with ``force=True``, ``soft``
with ``force=False``, ``none`` leaves them to finish. A driver that dies prints Ray's check
failure ("Tried to complete task that was not pending") and exits 1, in the middle of whatever
cleanup its program had left to run. The table gives the exit code, the rounds completed
before it and whether the check failure was printed.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import textwrap
from dataclasses import dataclass

DRIVER = textwrap.dedent(
    """
    import random, sys, time
    import ray

    mode, rounds = sys.argv[1], int(sys.argv[2])
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)

    @ray.remote(num_cpus=1)
    def task(i, seconds):
        time.sleep(seconds)
        return i

    rng = random.Random(0)
    for done in range(rounds):
        refs = [task.remote(i, rng.random() * 0.004) for i in range(12)]
        ready, rest = ray.wait(refs, num_returns=1)
        time.sleep(rng.random() * 0.004)
        if mode != "none":
            for ref in rest:
                ray.cancel(ref, force=mode == "force")
        print("ROUND", done + 1, flush=True)
    ray.shutdown()
    """
)


@dataclass(frozen=True, slots=True)
class Outcome:
    mode: str
    exit_code: int
    rounds_done: int
    check_failed: bool


def run_mode(mode: str, rounds: int, timeout_s: float) -> Outcome:
    try:
        done = subprocess.run(
            [sys.executable, "-c", DRIVER, mode, str(rounds)],
            check=False,
            capture_output=True,
            text=True,
            timeout=timeout_s,
        )
        code, out = done.returncode, done.stdout + done.stderr
    except subprocess.TimeoutExpired as exc:
        code = -1
        out = (exc.stdout or b"").decode() + (exc.stderr or b"").decode()
    lines = [line for line in out.splitlines() if line.startswith("ROUND ")]
    rounds_done = int(lines[-1].split()[1]) if lines else 0
    return Outcome(mode, code, rounds_done, "Tried to complete task that was not pending" in out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=400)
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per mode")
    args = parser.parse_args()
    import ray

    print(f"Ray {ray.__version__}, {args.rounds} rounds per mode")
    print(f"{'mode':<6} {'exit':>5} {'rounds done':>12} {'check failure':>14}")
    for mode in ("force", "soft", "none"):
        o = run_mode(mode, args.rounds, args.timeout)
        failed = "yes" if o.check_failed else "no"
        print(f"{o.mode:<6} {o.exit_code:>5} {o.rounds_done:>12} {failed:>14}")


if __name__ == "__main__":
    main()
