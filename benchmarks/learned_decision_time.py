"""Milliseconds per decision of the shipped learned policies under both runtimes (ONNX Runtime
and torch), and of the proposer and plan-fast, on one core, on generated hard cases.

Usage: python benchmarks/learned_decision_time.py [--cases 3] [--repeats 2]
       [--policies proposer,vlm,irbpp,tapnet,plan-fast] [--runtimes onnx,torch]
       [--suite packlab-bench-v1] [--levels easy,medium,hard]

One core: ``OMP_NUM_THREADS=1`` is set before numpy, torch and ONNX Runtime load, torch runs one
thread and every learned policy gets ``threads=1``. The learned policies (vlm, irbpp, tapnet)
play once per runtime (``runtime=onnx`` | ``runtime=torch``); a policy without the option is
reported as such. Each row plays ``--cases`` generated hard cases (train seed domain, user seed
7413, geometric backend; ``--suite NAME``: the first hard cases of a bundled suite instead, the
cases the learned policies' ratio to ``plan-fast`` is stated on, as the planner takes about 1 ms
a decision on generated hard cases and far longer on the suite's; timing only, nothing is chosen
by it)
``--repeats`` times after one untimed warm-up case; ``act`` is timed at every step and the
fastest of the repeats kept per step (the machine is shared: the minimum is the least
disturbed). Prints, per row, wall mean, median and p95, and the CPU time of a decision
(``time.process_time``, which other work on a shared machine disturbs less than the wall clock)
as mean, p95 and max; with ``--levels`` one row per policy and level (``--cases`` cases of
each), with the load average before and after. A decision includes everything the policy does:
the proposer's listing, the line vectors, the image, tokenising and the forward pass.
"""

from __future__ import annotations

import os

os.environ["OMP_NUM_THREADS"] = "1"  # before numpy / torch / onnxruntime read it

import argparse
import time

import numpy as np
import torch

from packlab.bench.suites import load_suite
from packlab.core.errors import ConfigError
from packlab.datagen import generate_cases
from packlab.policies.registry import make_policy
from packlab.sim.episode import run_episode

#: The policies that take ``runtime`` (and ``threads``).
LEARNED = ("vlm", "irbpp", "tapnet")


class Timed:
    def __init__(self, policy) -> None:
        self.policy, self.name, self.times, self.cpu = policy, policy.name, [], []

    def reset(self, case, seed: int) -> None:
        self.policy.reset(case, seed)

    def act(self, observation):
        c, t = time.process_time(), time.perf_counter()
        action = self.policy.act(observation)
        self.times.append(time.perf_counter() - t)
        self.cpu.append(time.process_time() - c)
        return action


def rows(policies: list[str], runtimes: list[str]) -> list[tuple[str, dict]]:
    """(label, options) of every row: each learned policy once per runtime."""
    out = []
    for name in policies:
        if name in LEARNED:
            out += [(f"{name} ({rt})", {"runtime": rt, "threads": 1}) for rt in runtimes]
        else:
            out.append((name, {}))
    return out


def time_row(name: str, options: dict, cases, repeats: int) -> tuple[np.ndarray, np.ndarray]:
    """Wall and CPU milliseconds per decision, each the least of the repeats at each step."""
    run_episode(cases[0], make_policy(name, **options), seed=0, backend="geometric")  # warm-up
    wall, cpu = [], []
    for _ in range(repeats):
        timed = Timed(make_policy(name, **options))
        for case in cases:
            run_episode(case, timed, seed=0, backend="geometric")
        wall.append(np.asarray(timed.times))
        cpu.append(np.asarray(timed.cpu))
    return np.min(np.stack(wall), axis=0) * 1000, np.min(np.stack(cpu), axis=0) * 1000


def level_cases(level: str, n: int, suite: str | None) -> list:
    """``n`` cases of one level: generated (module docstring) or a bundled suite's first."""
    if suite is None:
        return generate_cases(level, n, 7413, False, domain="train")
    return [c for c in load_suite(suite) if c.difficulty == level][:n]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=3)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--policies", default="proposer,vlm,irbpp,tapnet,plan-fast")
    p.add_argument("--runtimes", default="onnx,torch")
    p.add_argument("--suite", default=None, help="a bundled suite's cases instead")
    p.add_argument("--levels", default="hard", help="comma-separated levels, one row each")
    a = p.parse_args()
    torch.set_num_threads(1)
    levels = a.levels.split(",")
    where = "generated" if a.suite is None else a.suite
    print(f"{a.cases} {where} cases per level ({', '.join(levels)}), {a.repeats} repeats, "
          f"one core (OMP_NUM_THREADS=1); load average {os.getloadavg()[0]:.2f}")  # fmt: skip
    print("| policy | level | decisions | mean ms | median ms | p95 ms | CPU mean ms | CPU p95 ms "
          "| CPU max ms |\n|---|---|---:|---:|---:|---:|---:|---:|---:|")  # fmt: skip
    for level in levels:
        cases = level_cases(level, a.cases, a.suite)
        for label, options in rows(a.policies.split(","), a.runtimes.split(",")):
            name = label.split(" ")[0]
            try:
                wall, cpu = time_row(name, options, cases, a.repeats)
            except ConfigError as exc:  # e.g. a policy that does not take runtime (yet)
                print(f"| {label} | {level} | - | - | - | - | - | - | - |  <!-- {exc} -->")
                continue
            print(f"| {label} | {level} | {wall.size} | {wall.mean():.1f} | "
                  f"{np.median(wall):.1f} | {np.percentile(wall, 95):.1f} | {cpu.mean():.1f} | "
                  f"{np.percentile(cpu, 95):.1f} | {cpu.max():.1f} |")  # fmt: skip
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
