"""Time and accuracy of one perception step (``packlab.sim.sensing.perceive_state``).

Usage: OMP_NUM_THREADS=1 python benchmarks/perception_speed.py [--cases N] [--repeats R]
       [--presets none,structured-light,stereo] [--budgets 60000,80000,100000]

The cases are generated here in the ``train`` seed domain (user seed 7304, N per level), never
read from a bench suite: the buffer camera's pixel budget and the segmentation's thresholds
were chosen on this table. Each case is packed by its perfect plan (the fullest container, so
the most boxes to ray-cast) and its first ``buffer_size`` objects are shown. For each preset,
segmentation (``depth``: the robot's; ``truth``: the simulator's masks) and buffer arrangement
(``touching``: pushed together in a tote, the default; ``apart``) it reports CPU milliseconds
per step (one core: time.process_time, so other jobs on the machine do not inflate it), the
container part alone, the share of objects missed and of steps that needed a re-scan, the
share of boxes whose snapped size is exact, the mean size and yaw errors and the heightmap
error. ``--budgets`` repeats the depth / touching rows at other pixel budgets of the buffer
camera (``packlab.sim.sensing.camera.MAX_BUFFER_PIXELS``). The target is <= 25 ms per hard step.
"""

from __future__ import annotations

import argparse
import platform
import time
from functools import partial

import numpy as np

from packlab.core.types import Case
from packlab.datagen import generate_cases
from packlab.datagen.guard import require_training_cases
from packlab.sim.sensing import (
    add_sensor_noise,
    camera,
    container_camera,
    heightmap_from_depth,
    perceive_state,
    sensor_preset,
)
from packlab.sim.sensing.scene import planned_scene

SEED = 7304
LEVELS = ("easy", "medium", "hard")
VARIANTS = (("depth", "touching"), ("truth", "touching"), ("depth", "apart"))


def _cpu_ms(fn, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        start = time.process_time()
        fn()
        out.append((time.process_time() - start) * 1000.0)
    return out


def _container_only(case: Case, sizes, positions, quats, name: str, rng) -> None:
    """The container part of a step: depth image, sensor noise, heightmap."""
    preset = sensor_preset(name)
    image = container_camera(case.container, sizes, positions, quats, preset)
    heightmap_from_depth(add_sensor_noise(image, preset, rng), case.container)


def _row(cases: list[Case], preset: str, segmentation: str, arrangement: str, repeats: int):
    """Timing and error figures of one setting over the cases (a dict)."""
    total, part, mae, dims, yaw = [], [], [], [], []
    missed = shown_count = rescans = steps = 0
    for case in cases:
        sizes, positions, quats = planned_scene(case)
        shown = sizes[: case.buffer_size].astype(int)
        for r in range(repeats):
            rng = np.random.default_rng(r)
            args = (case.container, sizes, positions, quats, shown, preset, rng)
            start = time.process_time()  # one call, timed and scored
            stats = perceive_state(*args, segmentation, arrangement).stats
            total.append((time.process_time() - start) * 1000.0)
            missed += stats.missed
            shown_count += len(shown)
            rescans += stats.scans > 1
            steps += 1
            mae.append(stats.heightmap_mae_mm)
            dims.extend(stats.dims_error_mm[np.isfinite(stats.dims_error_mm)])
            yaw.extend(stats.yaw_error_deg[np.isfinite(stats.yaw_error_deg)])
        rng = np.random.default_rng(0)
        part += _cpu_ms(partial(_container_only, case, sizes, positions, quats, preset, rng), 1)
    dims_arr, yaw_arr = np.array(dims), np.array(yaw)
    return {
        "mean_ms": float(np.mean(total)),
        "p95_ms": float(np.percentile(total, 95)),
        "container_ms": float(np.mean(part)),
        "missed": missed / max(shown_count, 1),
        "rescans": rescans / max(steps, 1),
        "exact": float(np.mean(dims_arr == 0)) if dims else float("nan"),
        "dims": float(np.mean(dims_arr)) if dims else float("nan"),
        "yaw": float(np.mean(yaw_arr)) if yaw else float("nan"),
        "yaw_max": float(np.max(yaw_arr)) if yaw else float("nan"),
        "mae": float(np.mean(mae)),
    }


def _print(level: str, label: str, row: dict) -> None:
    print(
        f"| {level} | {label} | {row['mean_ms']:.1f} | {row['p95_ms']:.1f} "
        f"| {row['container_ms']:.1f} | {100 * row['missed']:.1f} | {100 * row['rescans']:.0f} "
        f"| {100 * row['exact']:.1f} | {row['dims']:.2f} | {row['yaw']:.2f} / {row['yaw_max']:.1f} "
        f"| {row['mae']:.2f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=10, help="generated cases per level")
    parser.add_argument("--repeats", type=int, default=3, help="scans per case (noise seeds)")
    parser.add_argument("--presets", default="none,structured-light,stereo")
    parser.add_argument("--budgets", default="", help="extra MAX_BUFFER_PIXELS values to try")
    parser.add_argument("--levels", default=",".join(LEVELS))
    args = parser.parse_args()
    print(f"# perception step ({platform.processor() or platform.machine()}, CPU time, one core)")
    print(f"# generated train-domain cases, seed {SEED}, {args.cases} per level")
    print(
        "| level | preset / segmentation / buffer | mean ms | p95 ms | container ms | missed % "
        "| re-scans % | sizes exact % | dims err mm | yaw err mean / max deg | hm MAE mm |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    default_budget = camera.MAX_BUFFER_PIXELS
    for level in args.levels.split(","):
        cases = generate_cases(level, args.cases, SEED, validate=False, domain="train")
        cases = require_training_cases(cases, f"perception cases (seed {SEED})", "tuning")
        for preset in args.presets.split(","):
            for segmentation, arrangement in VARIANTS:
                row = _row(cases, preset, segmentation, arrangement, args.repeats)
                _print(level, f"{preset} / {segmentation} / {arrangement}", row)
            for budget in (int(b) for b in args.budgets.split(",") if b):
                camera.MAX_BUFFER_PIXELS = budget
                row = _row(cases, preset, "depth", "touching", args.repeats)
                _print(level, f"{preset} / depth / touching, {budget:,} px", row)
                camera.MAX_BUFFER_PIXELS = default_budget


if __name__ == "__main__":
    main()
