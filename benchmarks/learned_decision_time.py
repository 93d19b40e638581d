"""Milliseconds per decision of the shipped learned policies under both runtimes (ONNX Runtime
and torch), and of the proposer and plan-fast, on one core, on generated hard cases.

Usage: python benchmarks/learned_decision_time.py [--cases 3] [--repeats 2]
       [--policies proposer,vlm,irbpp,tapnet,plan-fast] [--runtimes onnx,torch]
       [--suite packlab-bench-v1]

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
disturbed). Prints mean, median and p95 per row. A decision includes everything the policy
does: the proposer's listing, the line vectors, the image, tokenising and the forward
pass.
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
        self.policy, self.name, self.times = policy, policy.name, []

    def reset(self, case, seed: int) -> None:
        self.policy.reset(case, seed)

    def act(self, observation):
        t = time.perf_counter()
        action = self.policy.act(observation)
        self.times.append(time.perf_counter() - t)
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


def time_row(name: str, options: dict, cases, repeats: int) -> np.ndarray:
    """Milliseconds per decision, the fastest of the repeats at each step."""
    run_episode(cases[0], make_policy(name, **options), seed=0, backend="geometric")  # warm-up
    runs = []
    for _ in range(repeats):
        timed = Timed(make_policy(name, **options))
        for case in cases:
            run_episode(case, timed, seed=0, backend="geometric")
        runs.append(np.asarray(timed.times))
    return np.min(np.stack(runs), axis=0) * 1000


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=3)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--policies", default="proposer,vlm,irbpp,tapnet,plan-fast")
    p.add_argument("--runtimes", default="onnx,torch")
    p.add_argument("--suite", default=None, help="a bundled suite's hard cases instead")
    a = p.parse_args()
    torch.set_num_threads(1)
    if a.suite is None:
        cases = generate_cases("hard", a.cases, 7413, False, domain="train")
        where = "generated"
    else:
        cases = [c for c in load_suite(a.suite) if c.difficulty == "hard"][: a.cases]
        where = a.suite
    print(f"{len(cases)} {where} hard cases, {a.repeats} repeats, one core (OMP_NUM_THREADS=1)")
    print("| policy | decisions | mean ms | median ms | p95 ms |\n|---|---:|---:|---:|---:|")
    for label, options in rows(a.policies.split(","), a.runtimes.split(",")):
        name = label.split(" ")[0]
        try:
            best = time_row(name, options, cases, a.repeats)
        except ConfigError as exc:  # e.g. a policy that does not take runtime (yet)
            print(f"| {label} | - | - | - | - |  <!-- {exc} -->")
            continue
        print(f"| {label} | {best.size} | {best.mean():.1f} | {np.median(best):.1f} | "
              f"{np.percentile(best, 95):.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
