"""Env steps per second of the RL action-space envs, so a training budget can be read in steps.

Usage:
    python benchmarks/rl_env_speed.py [--steps 3000] [--train-steps 4096]

Prints one row per (agent, setting), on the geometric backend over freshly generated training
cases of all three levels (the packdata-20k mix, 600 cases):

- ``env, 1 process``: one env, uniformly random allowed rows (the envs' own cost: candidate
  search, proposer or DBLF rule, features, reward);
- ``DummyVecEnv x 2`` / ``SubprocVecEnv x 2``: two copies, in-process or one process each;
- ``MaskablePPO training, subproc x 2``: ``packlab train rl``'s default (rollouts plus updates,
  one learner thread), without its held-out evaluations.

``Pack-v0`` (the flat 5616-action env with its full mask) is listed for comparison. Timings
depend on the machine's load; run it on an idle machine.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from functools import partial

import numpy as np
import torch
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

from packlab.datagen.generator import generate_cases
from packlab.rl.config import RLTrainConfig
from packlab.rl.envs import ListedActionEnv
from packlab.rl.train import make_model
from packlab.sim.env import PackEnv

MIX = (("easy", 270), ("medium", 210), ("hard", 120))  # packdata-20k's proportions


def _env_rate(env, steps: int, masks) -> float:
    """Random allowed actions; ``masks(env, obs)`` gives the mask of the latest observation."""
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=0)
    started = time.perf_counter()
    for _ in range(steps):
        obs, _, done, _, _ = env.step(int(rng.choice(np.flatnonzero(masks(env, obs)))))
        if done:
            obs, _ = env.reset()
    return steps / (time.perf_counter() - started)


def _vec_rate(venv, steps: int) -> float:
    rng = np.random.default_rng(0)
    venv.reset()
    started = time.perf_counter()
    for _ in range(steps // venv.num_envs):
        masks = venv.env_method("action_masks")
        venv.step(np.array([int(rng.choice(np.flatnonzero(m))) for m in masks]))
    return steps / (time.perf_counter() - started)


def _train_rate(agent: str, cases, steps: int) -> float:
    cfg = RLTrainConfig(agent=agent, envs=2, vec="subproc")
    venv = SubprocVecEnv([partial(ListedActionEnv, agent, cases) for _ in range(2)])
    with tempfile.TemporaryDirectory() as out:
        model = make_model(cfg, venv, out)
        started = time.perf_counter()
        model.learn(steps)
        rate = model.num_timesteps / (time.perf_counter() - started)
    venv.close()
    return rate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--train-steps", type=int, default=4096)
    args = ap.parse_args()
    torch.set_num_threads(1)
    cases = [c for level, n in MIX for c in generate_cases(level, n, 1, False, domain="train")]
    rows = []
    for agent in ("irbpp", "tapnet"):
        env = ListedActionEnv(agent, cases)
        rows.append(
            (agent, "env, 1 process", _env_rate(env, args.steps, lambda e, _: e.action_masks()))
        )
        for name, cls in (("DummyVecEnv x 2", DummyVecEnv), ("SubprocVecEnv x 2", SubprocVecEnv)):
            venv = cls([partial(ListedActionEnv, agent, cases) for _ in range(2)])
            rows.append((agent, name, _vec_rate(venv, args.steps)))
            venv.close()
        rows.append(
            (
                agent,
                "MaskablePPO training, subproc x 2",
                _train_rate(agent, cases, args.train_steps),
            )
        )
    flat = PackEnv(cases)
    rows.append(
        (
            "Pack-v0",
            "env, 1 process",
            _env_rate(flat, args.steps // 3, lambda _, obs: obs["action_mask"]),
        )
    )
    print("| env | setting | steps/s |\n|---|---|---:|")
    for agent, setting, rate in rows:
        print(f"| {agent} | {setting} | {rate:,.0f} |")


if __name__ == "__main__":
    main()
