"""Time of one perception step (``packlab.sim.sensing.perceive_state``) on bench-sized states.

Usage: OMP_NUM_THREADS=1 python benchmarks/perception_speed.py [--cases N] [--repeats R]

For each difficulty of packlab-bench-v1 it takes N cases, packs each by its perfect plan (the
fullest container, so the most boxes to ray-cast), shows the first ``buffer_size`` objects and
times ``perceive_state`` per preset and segmentation; separately the container part alone
(depth image, noise, heightmap). Prints mean and p95 milliseconds per step and the errors.
The target is <= 20 ms per step on hard, on one core.
"""

from __future__ import annotations

import argparse
import platform
import time
from functools import partial

import numpy as np

from packlab.bench.suites import load_suite
from packlab.core.types import Case
from packlab.sim.sensing import (
    add_sensor_noise,
    container_camera,
    heightmap_from_depth,
    perceive_state,
    sensor_preset,
)
from packlab.sim.sensing.scene import planned_scene

PRESETS = ("none", "structured-light", "stereo")


def _time(fn, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        out.append((time.perf_counter() - start) * 1000.0)
    return out


def _container_only(case: Case, sizes, positions, quats, name: str, rng) -> None:
    """The container part of a step: depth image, sensor noise, heightmap."""
    preset = sensor_preset(name)
    image = container_camera(case.container, sizes, positions, quats, preset)
    heightmap_from_depth(add_sensor_noise(image, preset, rng), case.container)


def bench_level(cases: list[Case], repeats: int) -> list[tuple]:
    """Rows (preset, segmentation, mean ms, p95 ms, container ms, hm MAE, dims err, yaw err)."""
    rows = []
    for name in PRESETS:
        for segmentation in ("truth", "depth"):
            total, part, mae, dims, yaw = [], [], [], [], []
            for case in cases:
                sizes, positions, quats = planned_scene(case)
                shown = sizes[: case.buffer_size].astype(int)
                rng = np.random.default_rng(0)
                args = (case.container, sizes, positions, quats, shown, name, rng, segmentation)
                step = partial(perceive_state, *args)
                step()  # warm-up
                total += _time(step, repeats)
                part += _time(
                    partial(_container_only, case, sizes, positions, quats, name, rng), repeats
                )
                stats = step().stats
                mae.append(stats.heightmap_mae_mm)
                dims.extend(stats.dims_error_mm)
                yaw.extend(stats.yaw_error_deg)
            rows.append(
                (
                    name,
                    segmentation,
                    np.mean(total),
                    np.percentile(total, 95),
                    np.mean(part),
                    np.mean(mae),
                    np.mean(dims),
                    np.max(yaw),
                )
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    suite = load_suite("packlab-bench-v1")
    print(f"# perception step time ({platform.processor() or platform.machine()}, one process)")
    print(
        "| level | preset | segmentation | mean ms | p95 ms | container ms | hm MAE mm "
        "| dims err mm | max yaw err deg |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for level in ("easy", "medium", "hard"):
        cases = [c for c in suite if c.difficulty == level][: args.cases]
        for row in bench_level(cases, args.repeats):
            name, segmentation, mean, p95, part, mae, dims, yaw = row
            print(
                f"| {level} | {name} | {segmentation} | {mean:.1f} | {p95:.1f} | {part:.1f} "
                f"| {mae:.2f} | {dims:.2f} | {yaw:.2f} |"
            )


if __name__ == "__main__":
    main()
