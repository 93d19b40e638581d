"""What each part of the execution noise costs, with and without the place skill's seating.

Usage: python benchmarks/execution_noise_ablation.py [--policies dblf,sdf] [--every 4]
       [--seed 0] [--workers 1] [--variants "structured-light"]

Runs each policy on every ``--every``-th case of packlab-bench-v1 (mujoco, exact observation,
run seed ``--seed``) under the structured-light robot noise split into its parts (xy offset,
yaw error, release height), all together, and the stereo preset, each with seating off
(``seat_mm = 0``: a box stays where the noise put it, sliding aside only to clear a
neighbour) and with the honest seat (the presets' ``seat_mm``: guarded pushes toward the sides
the observed heightmap shows its plan flush with, stopped by contact force).
``--variants`` keeps the noise variants whose names contain one of its comma-separated words.
Prints mean Overall per policy and variant beside the exact execution, and the wall time.
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np

from packlab.bench.suites import load_suite
from packlab.policies import make_policy
from packlab.sim.episode import run_episode
from packlab.sim.execution import EXECUTION_PRESETS, ExecutionNoise

LIGHT = EXECUTION_PRESETS["structured-light"]


def _variants() -> dict[str, ExecutionNoise | None]:
    """Name -> noise (None: exact execution); every noisy variant with seating on and off."""
    parts = {
        "xy only": ExecutionNoise(xy_sigma_mm=LIGHT.xy_sigma_mm, comply_mm=LIGHT.comply_mm),
        "yaw only": ExecutionNoise(yaw_sigma_deg=LIGHT.yaw_sigma_deg, comply_mm=LIGHT.comply_mm),
        "release only": ExecutionNoise(release_mm=LIGHT.release_mm, comply_mm=LIGHT.comply_mm),
        "structured-light": LIGHT,
        "stereo": EXECUTION_PRESETS["stereo"],
    }
    variants: dict[str, ExecutionNoise | None] = {"exact": None}
    for name, noise in parts.items():
        seat = noise.seat_mm or LIGHT.seat_mm
        variants[f"{name}, no seat"] = replace(noise, seat_mm=0.0)
        variants[f"{name}, honest seat"] = replace(noise, seat_mm=seat)
    return variants


def _overall(task: tuple[str, str, int, int]) -> tuple[str, str, float]:
    policy, variant, index, seed = task
    case = load_suite()[index]
    result = run_episode(case, make_policy(policy), seed, "mujoco", execution=_variants()[variant])
    return policy, variant, result.metrics.overall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policies", default="dblf,sdf")
    parser.add_argument("--every", type=int, default=4, help="every N-th bench case")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--variants", default="", help="comma-separated name filters")
    args = parser.parse_args()
    policies = args.policies.split(",")
    words = [w for w in args.variants.split(",") if w]
    variants = [v for v in _variants() if v == "exact" or not words or any(w in v for w in words)]
    indices = range(0, len(load_suite()), args.every)
    tasks = [(p, v, i, args.seed) for p in policies for v in variants for i in indices]
    started = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(_overall, tasks, chunksize=4))
    print(f"packlab-bench-v1, every {args.every}th case ({len(indices)}), mujoco, seed {args.seed}")
    print(f"{len(tasks)} episodes, {time.perf_counter() - started:.0f} s, {args.workers} worker(s)")
    print("| Execution | " + " | ".join(policies) + " |")
    print("|---" * (len(policies) + 1) + "|")
    for variant in variants:
        means = [
            np.mean([o for p, v, o in results if p == policy and v == variant])
            for policy in policies
        ]
        print(f"| {variant} | " + " | ".join(f"{m:.3f}" for m in means) + " |")


if __name__ == "__main__":
    main()
