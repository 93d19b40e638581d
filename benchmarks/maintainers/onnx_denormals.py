"""What flushing denormals in ONNX runs saves the learned policies, measured in one process.

Usage:
    python benchmarks/maintainers/onnx_denormals.py [--cases 3] [--repeats 3]
        [--policies vlm,irbpp,tapnet]

``packlab.policies.onnx_model.Session.run`` flushes denormal floats to zero around each run (a
masked softmax makes them; x86 handles them in microcode). Here each policy plays the same
generated hard cases (train seed domain, user seed 7413, geometric backend, one core) with the
flush and with plain runs, alternating the order per repeat, so both see the same machine; the
fastest of the repeats is kept per step and mean / median / p95 ms per decision are printed.
Separate runs of a benchmark vary by about 20 % on a shared machine; this pairing does not.
"""

from __future__ import annotations

import os

os.environ["OMP_NUM_THREADS"] = "1"  # before numpy and onnxruntime read it

import argparse
import time
from typing import Any

import numpy as np

from packlab.datagen import generate_cases
from packlab.policies import onnx_model
from packlab.policies.registry import make_policy
from packlab.sim.episode import run_episode

FLUSHED = onnx_model.Session.run


def plain_run(self: onnx_model.Session, outputs: Any, feed: dict[str, Any]) -> list[Any]:
    return list(self.session.run(outputs, feed))


class Timed:
    def __init__(self, policy: Any) -> None:
        self.policy, self.name, self.times = policy, policy.name, []

    def reset(self, case: Any, seed: int) -> None:
        self.policy.reset(case, seed)

    def act(self, observation: Any) -> Any:
        t = time.perf_counter()
        action = self.policy.act(observation)
        self.times.append(time.perf_counter() - t)
        return action


def play(name: str, cases: list, run: Any) -> list[float]:
    onnx_model.Session.run = run  # type: ignore[method-assign]
    try:
        timed = Timed(make_policy(name, runtime="onnx", threads=1))
        for case in cases:
            run_episode(case, timed, seed=0, backend="geometric")
    finally:
        onnx_model.Session.run = FLUSHED  # type: ignore[method-assign]
    return timed.times


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=3)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--policies", default="vlm,irbpp,tapnet")
    a = p.parse_args()
    cases = generate_cases("hard", a.cases, 7413, False, domain="train")
    print(f"{a.cases} hard cases, {a.repeats} repeats, one core, flushed and plain alternating")
    print("| policy | runs | decisions | mean ms | median ms | p95 ms |")
    print("|---|---|---:|---:|---:|---:|")
    for name in a.policies.split(","):
        play(name, cases[:1], FLUSHED)  # warm-up: model load, caches
        times: dict[str, list[list[float]]] = {"flushed": [], "plain": []}
        for r in range(a.repeats):
            order = [("flushed", FLUSHED), ("plain", plain_run)]
            for label, run in order if r % 2 == 0 else order[::-1]:
                times[label].append(play(name, cases, run))
        for label, runs in times.items():
            best = np.min(np.asarray(runs), axis=0) * 1000
            print(f"| {name} | {label} | {best.size} | {best.mean():.1f} | "
                  f"{np.median(best):.1f} | {np.percentile(best, 95):.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
