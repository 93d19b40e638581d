"""Time per env step where piles are messy (random, FFP) and per placement on clean hard stacks.

    python benchmarks/messy_pile_settle.py [--per-level 5] [--seed 7] [--policies random,ffp]
                                           [--default] [--physics KEY=VALUE ...]

The cases are made like packlab-bench-v1 from user seed ``--seed`` of the training seed domain
(``packlab cases fresh``), never the suite itself. Every policy plays every case once on the
MuJoCo backend, in this process; then the oracle replays the hard cases. Printed per row: wall
and CPU milliseconds per env step (the oracle's per placement; the last one of an episode holds
the final settle), simulated steps per env step, the mean Overall, and the load average when the
row started and ended: on a shared machine the wall time follows the load, the CPU time less so.

It runs the settle region (``freeze=true``, ``rest_check_steps=4``); ``--default`` runs the
default settle (every box simulated, the rest test after every step); ``--physics`` changes any
``PhysicsConfig`` field as ``packlab bench --physics`` does.
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

import numpy as np

from packlab.bench.config import parse_physics
from packlab.bench.suites import build_suite, fresh_spec
from packlab.policies import make_policy
from packlab.sim.episode import run_episode
from packlab.sim.physics.mujoco_backend import PhysicsConfig

REGION: tuple[tuple[str, Any], ...] = (("freeze", True), ("rest_check_steps", 4))


def _load() -> str:
    return f"{os.getloadavg()[0]:.2f}"


def measure(cases, policy: str, physics: PhysicsConfig) -> dict:
    """Play ``policy`` on every case; times per env step (for the oracle: per placement)."""
    load_before = _load()
    wall, cpu, env_steps, sim_steps, overall, placement_s = 0.0, 0.0, 0, 0, [], []
    for case in cases:
        w0, c0 = time.perf_counter(), time.process_time()
        result = run_episode(case, make_policy(policy), seed=0, backend="mujoco", physics=physics)
        wall += time.perf_counter() - w0
        cpu += time.process_time() - c0
        env_steps += len(result.steps)
        sim_steps += sum(s.settle_steps for s in result.steps) + result.metrics.final_settle_steps
        overall.append(result.metrics.overall)
        placement_s += [s.wall_time_s for s in result.steps]
    return {
        "policy": policy,
        "cases": len(cases),
        "wall_ms": 1e3 * wall / env_steps,
        "cpu_ms": 1e3 * cpu / env_steps,
        "placement_p95_ms": 1e3 * float(np.percentile(placement_s, 95)),
        "sim_steps": sim_steps / env_steps,
        "overall": float(np.mean(overall)),
        "load": f"{load_before} -> {_load()}",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-level", type=int, default=5, help="cases per difficulty")
    parser.add_argument("--seed", type=int, default=7, help="training-domain user seed")
    parser.add_argument("--policies", default="random,ffp")
    parser.add_argument("--default", action="store_true", help="the default settle, no region")
    parser.add_argument("--physics", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()

    overrides: dict[str, Any] = {} if args.default else dict(REGION)
    overrides.update(parse_physics(args.physics))
    physics = PhysicsConfig(**overrides)
    spec = fresh_spec("packlab-bench-v1", args.seed, args.per_level)
    cases = build_suite(spec)
    hard = [c for c in cases if c.difficulty == "hard"]

    rows = [measure(cases, p, physics) for p in args.policies.split(",") if p]
    rows.append(measure(hard, "oracle", physics))
    settings = ", ".join(f"{k}={v}" for k, v in overrides.items()) or "defaults"
    print(f"MuJoCo settle ({settings}); {len(cases)} cases like packlab-bench-v1, seed {args.seed}")
    header = (
        f"{'policy':10s} {'cases':>5s} {'wall ms':>8s} {'cpu ms':>7s} {'p95 ms':>7s} "
        f"{'sim steps':>9s} {'overall':>8s}  load (1 min)"
    )
    print(header)
    print("-" * len(header))
    for r in rows:
        name = "oracle hard" if r["policy"] == "oracle" else r["policy"]
        print(
            f"{name:10s} {r['cases']:5d} {r['wall_ms']:8.2f} {r['cpu_ms']:7.2f} "
            f"{r['placement_p95_ms']:7.2f} {r['sim_steps']:9.1f} {r['overall']:8.4f}  {r['load']}"
        )
    print("ms per env step (oracle hard: per placement); sim steps: engine steps per env step")


if __name__ == "__main__":
    main()
