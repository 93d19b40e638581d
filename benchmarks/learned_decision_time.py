"""Milliseconds per decision of the shipped learned policies (and the proposer and plan-fast), one
thread, on generated hard cases.

Usage: OMP_NUM_THREADS=1 python benchmarks/learned_decision_time.py [--cases 3] [--repeats 2]
       [--policies proposer,vlm,irbpp,tapnet,plan-fast]

Each policy plays ``--cases`` generated hard cases (train seed domain, user seed 7413, geometric
backend) ``--repeats`` times; ``act`` is timed at every step and the fastest of the repeats kept
per step (the machine is shared: the minimum is the least disturbed). Prints mean, median and
p95 per policy. A decision includes everything the policy does: the proposer's listing, the
line vectors, the image, tokenising and the forward pass.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from packlab.datagen import generate_cases
from packlab.policies.registry import make_policy
from packlab.sim.episode import run_episode


class Timed:
    def __init__(self, policy) -> None:
        self.policy, self.name, self.times = policy, policy.name, []

    def reset(self, case, seed: int) -> None:
        self.policy.reset(case, seed)

    def act(self, observation):
        t = time.perf_counter()
        action = self.policy.act(observation)
        self.times.append(time.perf_counter() - t)
        return action


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=3)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--policies", default="proposer,vlm,irbpp,tapnet,plan-fast")
    a = p.parse_args()
    torch.set_num_threads(1)
    cases = generate_cases("hard", a.cases, 7413, False, domain="train")
    print(f"{a.cases} hard cases, {a.repeats} repeats, one thread")
    print("| policy | decisions | mean ms | median ms | p95 ms |\n|---|---:|---:|---:|---:|")
    for name in a.policies.split(","):
        runs = []
        for _ in range(a.repeats):
            timed = Timed(make_policy(name))
            for case in cases:
                run_episode(case, timed, seed=0, backend="geometric")
            runs.append(np.asarray(timed.times))
        best = np.min(np.stack(runs), axis=0) * 1000
        print(f"| {name} | {best.size} | {best.mean():.1f} | {np.median(best):.1f} | "
              f"{np.percentile(best, 95):.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
