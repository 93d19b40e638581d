"""How long the training guard takes (target: under 1 s for 20 000 cases).

Usage: python benchmarks/maintainers/guard_speed.py [--cases 20000]

Times the first load of the known fingerprints (once per process) and
``require_training_cases`` on generated training cases of each level (ids renamed so every case
is checked afresh), best of 3.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from packlab.cases.known import known_cases
from packlab.datagen import generate_cases
from packlab.datagen.guard import require_training_cases


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=20_000)
    args = parser.parse_args()
    start = time.perf_counter()
    n_known = len(known_cases())
    print(f"load of {n_known} known fingerprints: {time.perf_counter() - start:.3f} s")
    print("| level | cases | best of 3 s |\n|---|---:|---:|")
    for level in ("easy", "medium", "hard"):
        base = generate_cases(level, 20, 5, False, domain="train")
        many = [
            dataclasses.replace(c, episode_id=f"{i}-{c.episode_id}")
            for i in range(args.cases // len(base))
            for c in base
        ]
        best = float("inf")
        for _ in range(3):
            start = time.perf_counter()
            require_training_cases(many, "many.jsonl")
            best = min(best, time.perf_counter() - start)
        print(f"| {level} | {len(many)} | {best:.3f} |")


if __name__ == "__main__":
    main()
