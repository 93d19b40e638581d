"""Per-step latency of the ``vlm`` policy against history length, with and without prefix reuse.

Usage: python benchmarks/vlm_step_latency.py [--family qwen3_5] [--size tiny] [--objects 24]
       [--buffer 5] [--max-new-tokens 16] [--repeats 2] [--threads 1] [--every 1]

Runs one closed-loop episode (geometric backend) of a hard-sized case (48 x 40 cell container,
``--objects`` boxes, buffer ``--buffer``) with the ``vlm`` policy on a random-weight tiny model,
twice: reusing the cached conversation prefix across steps (the default) and re-encoding the
whole context every step. Both runs take the same actions (greedy, checked here), so they see
the same prompts; step t's context holds t past steps (heightmap image + buffer + answer each).
Prints, per step: prompt tokens, tokens taken from the cache, wall milliseconds of ``act``
(render + encode + prefill + decode) with and without the cache, and the prefill part alone.
Each mode runs ``--repeats`` times and the fastest time of each step is kept (the machine is
shared; the minimum is the least disturbed). A random model does not stop early, so every step
decodes ``--max-new-tokens`` tokens in both modes: the difference is the prefill.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from packlab.core.types import Box, Case, Container
from packlab.policies import make_policy
from packlab.sim.episode import Episode

CELL_MM = 25


def make_case(n_objects: int, buffer: int, seed: int = 0) -> Case:
    """A hard-sized container with ``n_objects`` random boxes (their fit does not matter here:
    the history grows by one step per object whatever the model answers)."""
    rng = np.random.default_rng(seed)
    objects = []
    for i in range(n_objects):
        l, w = (int(v) * CELL_MM for v in rng.integers(3, 16, size=2))
        objects.append(Box(i, (l, w, int(rng.integers(40, 300)) // 2 * 2), i, i % 7))
    return Case(
        f"latency-{n_objects}",
        Container((1200, 1000, 900)),
        buffer,
        tuple(objects),
        seed=seed,
        difficulty="hard",
    )


def run(case: Case, policy) -> tuple[list[float], list[dict], list]:
    """Wall seconds of each ``act``, the policy's step log, and the actions."""
    episode = Episode("geometric")
    obs = episode.reset(case, seed=0)
    policy.reset(case, 0)
    times, actions = [], []
    while not episode.done:
        t0 = time.perf_counter()
        action = policy.act(obs)
        times.append(time.perf_counter() - t0)
        actions.append(action)
        episode.step(action)
        if not episode.done:
            obs = episode.observe()
    return times, list(policy.step_log), actions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--family", default="qwen3_5", choices=("qwen3_5", "qwen3_vl", "qwen2_5_vl")
    )
    parser.add_argument("--size", default="tiny", choices=("tiny", "small", "base"))
    parser.add_argument("--objects", type=int, default=24)
    parser.add_argument("--buffer", type=int, default=5)
    parser.add_argument("--max-new-tokens", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    parser.add_argument("--every", type=int, default=1, help="print every n-th step")
    args = parser.parse_args()

    import torch

    case = make_case(args.objects, args.buffer)
    model = f"tiny:{args.family}:{args.size}"
    common = {
        "model": model,
        "max_new_tokens": args.max_new_tokens,
        "threads": args.threads,
        "device": "cpu",
    }
    policies = {
        mode: make_policy("vlm", reuse_cache=(mode == "cached"), **common)
        for mode in ("cached", "uncached")
    }
    for p in policies.values():  # load and warm up outside the timings
        p.load()
        run(make_case(3, args.buffer, seed=1), p)

    best: dict[str, np.ndarray] = {}
    prefill: dict[str, np.ndarray] = {}
    logs: dict[str, list[dict]] = {}
    actions: dict[str, list] = {}
    for _ in range(args.repeats):
        for mode, policy in policies.items():
            times, log, acts = run(case, policy)
            t = np.array(times)
            pf = np.array([s["prefill_s"] for s in log])
            best[mode] = np.minimum(best[mode], t) if mode in best else t
            prefill[mode] = np.minimum(prefill[mode], pf) if mode in prefill else pf
            logs[mode], actions[mode] = log, acts
    if actions["cached"] != actions["uncached"]:
        raise SystemExit("cached and uncached runs took different actions: the cache is wrong")

    print(
        f"python {platform.python_version()}, torch {torch.__version__}, {platform.machine()}, "
        f"{torch.get_num_threads()} thread(s), device cpu"
    )
    print(
        f"model {model} ({policies['cached'].resolved['family']}, "
        f"{sum(p.numel() for p in policies['cached'].generator.model.parameters()) / 1e6:.2f} M "
        f"params), {args.objects} objects, buffer {args.buffer}, 224 px heightmaps, "
        f"{args.max_new_tokens} new tokens per step, best of {args.repeats}"
    )
    print("same actions with and without the cache: yes\n")
    header = (
        f"{'step':>4} {'history':>7} {'prompt tok':>10} {'reused tok':>10} "
        f"{'ms cached':>9} {'ms uncached':>11} {'speedup':>7} "
        f"{'prefill ms c':>12} {'prefill ms u':>12}"
    )
    print(header)
    print("-" * len(header))
    cached, uncached = logs["cached"], logs["uncached"]
    for i, (c, u) in enumerate(zip(cached, uncached)):
        if i % args.every and i != len(cached) - 1:
            continue
        assert c["prompt_tokens"] == u["prompt_tokens"]
        mc, mu = best["cached"][i] * 1e3, best["uncached"][i] * 1e3
        print(
            f"{i:>4} {i:>7} {c['prompt_tokens']:>10} {c['reused_tokens']:>10} "
            f"{mc:>9.1f} {mu:>11.1f} {mu / mc:>6.2f}x "
            f"{prefill['cached'][i] * 1e3:>12.1f} {prefill['uncached'][i] * 1e3:>12.1f}"
        )
    tc, tu = best["cached"].sum(), best["uncached"].sum()
    print(f"\nepisode total: {tc:.2f} s cached, {tu:.2f} s uncached ({tu / tc:.2f}x)")


if __name__ == "__main__":
    main()
