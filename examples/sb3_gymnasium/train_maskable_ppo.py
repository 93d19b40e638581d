"""Train sb3-contrib's MaskablePPO on packlab's Gymnasium environment ``packlab/Pack-v0``,
then play one episode with the trained agent and print its metrics.

Needs the rl extra (torch, stable-baselines3, sb3-contrib). A few hundred steps show the
wiring, not a good packer: packlab's own agents (``irbpp``, ``tapnet``) train far longer, on
action spaces of a few listed rows (``packlab train rl``, docs/rl.md).

    python examples/sb3_gymnasium/train_maskable_ppo.py                 # 512 steps
    python examples/sb3_gymnasium/train_maskable_ppo.py --steps 64 --n-steps 32
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from sb3_contrib import MaskablePPO

import packlab.sim.env  # noqa: F401 - registers packlab/Pack-v0 with Gymnasium

#: Observation keys the network reads; the action mask goes to MaskablePPO instead.
NETWORK_KEYS = ("heightmap", "buffer", "buffer_mask")
MM_PER_M = 1000.0


class MaskedPack(gym.Wrapper):
    """Pack-v0 as MaskablePPO wants it: ``action_masks()`` from the observation's mask, and the
    network's inputs in metres (heightmap and box sizes) so they stay near 1."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        inner = env.observation_space
        self.observation_space = spaces.Dict(
            {
                "heightmap": spaces.Box(0, np.inf, inner["heightmap"].shape, np.float32),
                "buffer": spaces.Box(0, np.inf, inner["buffer"].shape, np.float32),
                "buffer_mask": inner["buffer_mask"],
            }
        )
        self._mask = np.ones(env.action_space.n, dtype=bool)

    def _network_view(self, observation: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        self._mask = observation["action_mask"].astype(bool)
        view = {key: observation[key] for key in NETWORK_KEYS}
        view["heightmap"] = view["heightmap"].astype(np.float32) / MM_PER_M
        view["buffer"] = view["buffer"].astype(np.float32) / MM_PER_M
        return view

    def reset(self, **kwargs: Any) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        return self._network_view(observation), info

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        return self._network_view(observation), float(reward), terminated, truncated, info

    def action_masks(self) -> np.ndarray:
        """Where the flattened (object, rotation, x, y) action puts a box on the floor."""
        return self._mask


def make_env(cases: str | None) -> MaskedPack:
    # The geometric backend drops boxes exactly (no physics): thousands of steps a minute.
    return MaskedPack(gym.make("packlab/Pack-v0", cases=cases, backend="geometric"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=512, help="training steps (default 512)")
    parser.add_argument("--n-steps", type=int, default=128, help="rollout length (default 128)")
    parser.add_argument("--cases", help="a case file (default: packlab's demo cases)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)

    env = make_env(args.cases)
    print(f"Pack-v0: {env.action_space.n} actions, cases {len(env.unwrapped.cases)}")
    model = MaskablePPO(
        "MultiInputPolicy",
        env,
        n_steps=args.n_steps,
        batch_size=min(64, args.n_steps),
        n_epochs=4,
        seed=args.seed,
        device="cpu",
        verbose=0,
    )
    model.learn(total_timesteps=args.steps)
    print(f"trained {model.num_timesteps} steps")

    # One episode of the first case, greedy, masked the same way as in training.
    observation, info = env.reset(seed=args.seed, options={"case_index": 0, "run_seed": 0})
    total, done = 0.0, False
    while not done:
        action, _ = model.predict(observation, action_masks=env.action_masks(), deterministic=True)
        observation, reward, terminated, truncated, info = env.step(action)
        total += reward
        done = terminated or truncated
    metrics = info["metrics"]
    print(
        f"episode {env.unwrapped.cases[0].episode_id}: return {total:.3f}, "
        f"success ratio {metrics['success_ratio']:.3f}, compactness {metrics['compactness']:.3f}, "
        f"overall {metrics['overall']:.3f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
