"""Per-decision time of every packing heuristic on easy / medium / hard sized states.

Usage: python benchmarks/heuristic_decision_time.py [--cases N] [--seed S]

For each difficulty it makes N layered cases (container and buffer sizes of that level, a
self-contained guillotine generator so the benchmark does not depend on the data engine), runs
every heuristic through whole episodes on the geometric backend, and times each ``act`` call:
so the states are the realistic ones each heuristic meets, from the empty floor to nearly full.
Prints mean, p95 and max milliseconds per decision. The target is < 50 ms on hard.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from packlab.core.types import Box, Case, Container
from packlab.policies.heuristics import SCORERS, make_heuristic, observation_candidates
from packlab.sim.episode import Episode

CELL_MM = 25

#: (container mm, buffer, layers, objects) per level: the largest base container of each level
#: and the object and layer counts of the paper's Table 1.
LEVELS = {
    "easy": ((800, 600, 550), 3, (1, 2), (4, 8)),
    "medium": ((1200, 1000, 900), 5, (2, 3), (9, 18)),
    "hard": ((1600, 1200, 1100), 10, (3, 4), (19, 32)),
}


def _split_layer(rng: np.random.Generator, nx: int, ny: int, pieces: int) -> list[tuple[int, int]]:
    """Footprints (cells) tiling an nx x ny layer: cut the largest cuttable piece until done."""
    rects = [(nx, ny)]
    while len(rects) < pieces:
        cuttable = [r for r in rects if max(r) >= 6]  # both halves keep >= 3 cells
        if not cuttable:
            break
        r = max(cuttable, key=lambda r: r[0] * r[1])
        rects.remove(r)
        dx, dy = r
        if dx >= dy:
            c = int(rng.integers(3, dx - 2))
            rects += [(c, dy), (dx - c, dy)]
        else:
            c = int(rng.integers(3, dy - 2))
            rects += [(dx, c), (dx, dy - c)]
    return rects


def make_case(level: str, seed: int) -> Case:
    size, buffer, layer_range, object_range = LEVELS[level]
    rng = np.random.default_rng(seed)
    nx, ny = size[0] // CELL_MM, size[1] // CELL_MM
    n_layers = int(rng.integers(layer_range[0], layer_range[1] + 1))
    n_objects = int(rng.integers(object_range[0], object_range[1] + 1))
    stack_mm = int(size[2] * rng.uniform(0.84, 0.96))
    heights = np.maximum(rng.dirichlet(np.ones(n_layers)) * stack_mm // 10 * 10, 80).astype(int)
    objects = []
    for layer in range(n_layers):
        pieces = n_objects // n_layers + (layer < n_objects % n_layers)
        for fx, fy in _split_layer(rng, nx, ny, pieces):
            l, w = (fy, fx) if rng.random() < 0.25 else (fx, fy)
            size_mm = (l * CELL_MM, w * CELL_MM, int(heights[layer]))
            objects.append(Box(len(objects), size_mm, len(objects)))
    return Case(
        f"{level}-{seed}", Container(size), buffer, tuple(objects), seed=seed, difficulty=level
    )


def time_episode(case: Case, name: str) -> list[float]:
    """Seconds of each decision of heuristic ``name`` over one geometric episode of ``case``."""
    policy = make_heuristic(name)
    episode = Episode("geometric")
    obs = episode.reset(case, seed=0)
    policy.reset(case, 0)
    times = []
    while not episode.done:
        t0 = time.perf_counter()
        action = policy.act(obs)
        times.append(time.perf_counter() - t0)
        episode.step(action)
        if not episode.done:
            obs = episode.observe()
    return times


def time_search(case: Case) -> list[float]:
    """Seconds of the bare candidate search on the states DBLF meets (for reference)."""
    policy = make_heuristic("dblf")
    episode = Episode("geometric")
    obs = episode.reset(case, seed=0)
    times = []
    while not episode.done:
        t0 = time.perf_counter()
        observation_candidates(obs)
        times.append(time.perf_counter() - t0)
        episode.step(policy.act(obs))
        if not episode.done:
            obs = episode.observe()
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=3, help="cases per difficulty (default 3)")
    parser.add_argument("--seed", type=int, default=0, help="first case seed (default 0)")
    args = parser.parse_args()

    # Warm up imports and first-call costs outside the timings.
    warm = make_case("easy", 10**6)
    for name in SCORERS:
        time_episode(warm, name)

    print(f"python {platform.python_version()}, numpy {np.__version__}, {platform.machine()}")
    print(f"{args.cases} cases per difficulty, geometric backend, one row per heuristic\n")
    header = (
        f"{'difficulty':<10} {'grid':>7} {'buf':>3} {'method':<7} {'decisions':>9} "
        f"{'mean ms':>8} {'p95 ms':>8} {'max ms':>8}"
    )
    print(header)
    print("-" * len(header))
    for level, (size, buffer, _, _) in LEVELS.items():
        cases = [make_case(level, args.seed + i) for i in range(args.cases)]
        grid = f"{size[0] // CELL_MM}x{size[1] // CELL_MM}"
        rows = [(name, [t for case in cases for t in time_episode(case, name)]) for name in SCORERS]
        rows.append(("search", [t for case in cases for t in time_search(case)]))
        for name, times in rows:
            ms = np.array(times) * 1e3
            print(
                f"{level:<10} {grid:>7} {buffer:>3} {name:<7} {ms.size:>9} "
                f"{ms.mean():>8.2f} {np.percentile(ms, 95):>8.2f} {ms.max():>8.2f}"
            )


if __name__ == "__main__":
    main()
