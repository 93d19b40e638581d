"""Reinforcement-learning baselines (docs/rl.md): action-space envs, features and rewards here,
torch-free; the networks, trainer and policies need the ``rl`` extra (stable-baselines3,
sb3-contrib, torch)."""
