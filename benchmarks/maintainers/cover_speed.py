"""Exact rectangle cover speed: the bitmask search against the numpy one it replaced.

Usage: python benchmarks/maintainers/cover_speed.py [--states N] [--seed S] [--max-nodes M]

The workload is the planner's (``complete.find_completion``) on seeded guillotine layers: a
layer of a medium (48 x 40 cells) or hard (64 x 48) container partly filled in scan order, the
next few of its boxes shown (the buffer), the rest unseen; each state runs the completion
stages in order (exact tiling, then every shown box plus 1..3 jokers, then a subset plus 2..3)
until one finds a tiling, as the planner does. Every call runs on both implementations, which
must answer the same (slots, nodes, exhausted); the table gives per stage kind the calls, the
nodes, milliseconds per call and microseconds per node of each, and the speed-up. The budget is
smaller than the planner's 100 000 nodes by default so the old search finishes in minutes.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from packlab.policies.plan.cover import CoverResult, CoverRules, Piece, exact_cover

# The frozen reference lives with its equivalence test.
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "policies" / "plan"))
from _cover_reference import exact_cover as reference_cover

#: (grid cells, boxes per layer, buffer) of the two container sizes.
LEVELS = {"medium": ((48, 40), (9, 14), 5), "hard": ((64, 48), (12, 24), 10)}
#: The planner's stages (CompletionConfig.stages with max_jokers 3) and its joker side (cells).
STAGES = ((0, False), (1, True), (2, True), (3, True), (2, False), (3, False))
JOKER_SIDE = 3
GUESSES = 32

Call = tuple[str, np.ndarray, list[Piece], int, CoverRules]
Rect = tuple[int, int, int, int]  # x, y, dx, dy (cells)


def _split(rng: np.random.Generator, nx: int, ny: int, pieces: int) -> list[Rect]:
    """Guillotine-cut an nx x ny layer into up to ``pieces`` rectangles (x, y, dx, dy), sides
    at least 3 cells: the largest cuttable rectangle is cut next."""
    rects: list[Rect] = [(0, 0, nx, ny)]
    while len(rects) < pieces:
        cuttable = [r for r in rects if max(r[2:]) >= 6]
        if not cuttable:
            break
        x, y, dx, dy = max(cuttable, key=lambda r: r[2] * r[3])
        rects.remove((x, y, dx, dy))
        if dx >= dy:
            c = int(rng.integers(3, dx - 2))
            rects += [(x, y, c, dy), (x + c, y, dx - c, dy)]
        else:
            c = int(rng.integers(3, dy - 2))
            rects += [(x, y, dx, c), (x, y + c, dx, dy - c)]
    return rects


def workload(states: int, seed: int, max_nodes: int) -> list[Call]:
    """The exact-cover calls of ``states`` planner states per level (module docstring)."""
    calls: list[Call] = []
    for level, ((nx, ny), (lo, hi), buffer) in LEVELS.items():
        for s in range(states):
            rng = np.random.default_rng([seed, s, nx])
            rects = sorted(_split(rng, nx, ny, int(rng.integers(lo, hi + 1))))  # scan order
            placed = int(rng.integers(0, len(rects) - 1))
            region = np.ones((nx, ny), bool)
            for x, y, dx, dy in rects[:placed]:
                region[x : x + dx, y : y + dy] = False
            rest = rects[placed:]
            shown = [rest[i] for i in rng.permutation(len(rest))[:buffer]]
            unseen = len(rest) - len(shown)
            pieces = [
                Piece(k, dy, dx) if rng.random() < 0.25 else Piece(k, dx, dy)
                for k, (_, _, dx, dy) in enumerate(shown)
            ]
            for jokers, use_all in STAGES:
                if jokers > unseen:
                    continue
                if not jokers and sum(p.area for p in pieces) < int(region.sum()):
                    continue
                rules = CoverRules(jokers, use_all, JOKER_SIDE, GUESSES)
                calls.append((f"{level} j{jokers}", region, pieces, max_nodes, rules))
                if exact_cover(region, pieces, max_nodes, rules).slots:
                    break
    return calls


def _timed(cover: Callable[..., CoverResult], call: Call) -> tuple[CoverResult, float]:
    """One call's result and seconds; a short call is repeated and its fastest time kept (a
    single sub-millisecond timing is mostly the machine's noise)."""
    _, region, pieces, budget, rules = call
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        result = cover(region, pieces, budget, rules)
        best = min(best, time.perf_counter() - t0)
        if best > 0.01:
            break
    return result, best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--states", type=int, default=12, help="states per level (default 12)")
    parser.add_argument("--seed", type=int, default=0, help="workload seed (default 0)")
    parser.add_argument("--max-nodes", type=int, default=20_000, help="budget (default 20000)")
    args = parser.parse_args()
    calls = workload(args.states, args.seed, args.max_nodes)

    rows: dict[str, list[float]] = {}  # kind -> [calls, nodes, old s, new s]
    for call in calls:
        kind = call[0]
        old, old_s = _timed(reference_cover, call)
        new, new_s = _timed(exact_cover, call)
        if new != old:
            raise SystemExit(f"{kind}: the new search answered {new}, the reference {old}")
        for key in (kind, "all"):
            row = rows.setdefault(key, [0, 0, 0.0, 0.0])
            row[0] += 1
            row[1] += old.nodes
            row[2] += old_s
            row[3] += new_s

    print(f"python {platform.python_version()}, numpy {np.__version__}, {platform.machine()}")
    print(f"{args.states} states per level, seed {args.seed}, budget {args.max_nodes} nodes")
    print("identical results (slots, nodes, exhausted) on every call\n")
    header = (
        f"{'stage':<10} {'calls':>5} {'nodes':>8} {'old ms/call':>11} {'new ms/call':>11} "
        f"{'old us/node':>11} {'new us/node':>11} {'old nodes/s':>11} {'new nodes/s':>11} "
        f"{'speed-up':>8}"
    )
    print(header)
    print("-" * len(header))
    for kind in sorted(rows, key=lambda k: (k == "all", k)):
        n, nodes, old_s, new_s = rows[kind]
        per = max(nodes, 1)
        print(
            f"{kind:<10} {int(n):>5} {int(nodes):>8} {old_s / n * 1e3:>11.2f} "
            f"{new_s / n * 1e3:>11.2f} {old_s / per * 1e6:>11.1f} {new_s / per * 1e6:>11.1f} "
            f"{nodes / old_s:>11.0f} {nodes / new_s:>11.0f} {old_s / new_s:>7.1f}x"
        )


if __name__ == "__main__":
    main()
