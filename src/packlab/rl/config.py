"""``RLTrainConfig``: everything ``packlab train rl`` decides, validated on creation and saved
beside the run as ``config.json`` (torch-free, so the CLI reads its defaults without the extra).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from packlab.core.choices import (
    DEFAULT_TAPNET_PLACEMENT,
    RLAgent,
    RLReward,
    TapnetPlacement,
    VecKind,
    require_choice,
)
from packlab.core.errors import ConfigError
from packlab.policies.candidates import STUDENT_K


@dataclass(frozen=True, slots=True)
class RLTrainConfig:
    """One training run of an RL agent (docs/rl.md explains each choice)."""

    agent: RLAgent = "irbpp"
    out: str = "runs/rl"
    steps: int = 500_000  # env steps (decisions) in total, across resumes
    minutes: float = 0.0  # stop after this much training wall time (0: no cap), across resumes
    envs: int = 2  # environment copies
    vec: VecKind = "subproc"
    reward: RLReward = "overall"
    k: int = STUDENT_K  # irbpp: placements listed per step (tapnet: one per buffer slot)
    n_steps: int = 256  # steps per env per PPO rollout
    batch: int = 256
    epochs: int = 4
    lr: float = 3e-4
    gamma: float = 1.0  # episodes are 4-32 decisions; the return is the final Overall
    gae_lambda: float = 0.95
    ent_coef: float = 0.01
    clip_range: float = 0.2
    width: int = 64  # hidden width of the feature extractor and heads
    eval_every: int = 20_000  # env steps between held-out evaluations and checkpoints
    eval_cases_per_level: int = 10  # generated cases per level kept out of training
    seed: int = 0
    threads: int = 1  # torch threads of the learner
    init: str = ""  # a model directory (e.g. ``packlab train rl-imitate``'s) to start from
    #: tapnet: the rule that places the chosen object (an --init model must have the same).
    placement: TapnetPlacement = DEFAULT_TAPNET_PLACEMENT

    def __post_init__(self) -> None:
        require_choice(self.agent, RLAgent, "agent")
        require_choice(self.placement, TapnetPlacement, "placement")
        require_choice(self.reward, RLReward, "reward")
        require_choice(self.vec, VecKind, "vec")
        positive = ("steps", "envs", "k", "n_steps", "batch", "epochs", "width", "eval_every")
        for name in positive:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"{name} = {value!r}: must be a whole number >= 1")
        if self.eval_cases_per_level < 1:
            raise ConfigError(
                f"eval_cases_per_level = {self.eval_cases_per_level!r}: must be at least 1"
            )
        for name in ("lr", "gae_lambda", "clip_range"):
            if not 0 < getattr(self, name) <= 1:
                raise ConfigError(f"{name} = {getattr(self, name)!r}: must be in (0, 1]")
        if not 0 <= self.gamma <= 1 or self.ent_coef < 0 or self.minutes < 0:
            raise ConfigError(
                f"gamma = {self.gamma}, ent_coef = {self.ent_coef}, minutes = {self.minutes}: "
                "gamma must be in [0, 1], the others not negative"
            )
        if self.threads < 1:
            raise ConfigError(f"threads = {self.threads!r}: must be at least 1")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True, slots=True)
class ImitationConfig:
    """One behaviour-cloning run (``packlab train rl-imitate``)."""

    agent: RLAgent = "irbpp"
    out: str = "runs/rl-imitate"
    k: int = STUDENT_K
    width: int = 64
    epochs: int = 20
    batch: int = 256
    lr: float = 1e-3
    value_weight: float = 0.5  # weight of the value regression (samples with a value only)
    seed: int = 0
    threads: int = 1
    placement: TapnetPlacement = DEFAULT_TAPNET_PLACEMENT  # tapnet: places the chosen object
    #: A model directory whose weights the fit starts from (a DAgger round on a trained agent:
    #: the shipped one, a PPO run's ``final``); empty: fresh weights.
    init: str = ""

    def __post_init__(self) -> None:
        require_choice(self.agent, RLAgent, "agent")
        require_choice(self.placement, TapnetPlacement, "placement")
        for name in ("k", "width", "epochs", "batch", "threads"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"{name} = {value!r}: must be a whole number >= 1")
        if not 0 < self.lr <= 1 or self.value_weight < 0:
            raise ConfigError(f"lr = {self.lr}, value_weight = {self.value_weight}: out of range")
