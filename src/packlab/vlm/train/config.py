"""The SFT job's configuration (no torch: the CLI validates it before importing the trainer).

Defaults are the paper's recipe where it gives one (AdamW, lr 1e-5, global batch 8 with one
example per device; PackLab, Zhou et al.), and transformers' or TRL's otherwise. The reference
implementation's verl config differs in places; ``configs/accelerate/`` names each number's
source.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from packlab.core.choices import HistoryMode, ImageMode, ModelDType, require_choice
from packlab.core.errors import ConfigError
from packlab.vlm.data.sft_dataset import RECIPES

#: Default learning rates: the paper's 1e-5 for pretrained weights; tiny models start from
#: random weights and need a much larger step.
LR_PRETRAINED = 1e-5
LR_TINY = 1e-3
#: LoRA goes on the language model's projections (the vision tower stays frozen unless asked);
#: the regex also catches Qwen3.5's gated-delta-net projections.
LORA_TARGETS = (
    r".*language_model.*\.(q_proj|k_proj|v_proj|o_proj|gate_proj|up_proj|down_proj"
    r"|in_proj_qkv|in_proj_z|out_proj)"
)
#: With ``train_vision``, LoRA also adapts the vision tower's attention and MLP projections.
LORA_VISION_TARGETS = (
    r".*visual.*\.(qkv|proj|linear_fc1|linear_fc2|fc1|fc2|gate_proj|up_proj|down_proj)"
)
#: ``--dtype`` choices: ``auto`` is bf16 on a GPU that has it, fp32 elsewhere.
DTYPES = ("auto", "fp32", "bf16", "fp16")
#: ``--truncation``: what an example longer than ``max_length`` does.
TRUNCATIONS = ("error", "drop")
#: ``--report-to``: ``auto`` is TensorBoard where it is installed.
REPORTERS = ("auto", "none", "tensorboard", "wandb")


@dataclass(frozen=True)
class SFTConfig:
    """Everything a training run depends on; saved resolved beside its outputs."""

    data: str
    out: str
    model: str = "tiny:qwen3_5:small"  # a checkpoint directory, config:PATH or tiny:F:S
    epochs: int = 1
    lr: float | None = None  # None: LR_TINY for tiny models, LR_PRETRAINED otherwise
    micro_batch: int = 1  # conversations per forward pass per device
    grad_accum: int = 8  # global batch = micro_batch * grad_accum * devices
    weight_decay: float = 0.0
    warmup_ratio: float = 0.03
    max_grad_norm: float = 1.0
    #: Tokens per example. None: the longest example's length. An example longer than this is
    #: refused (``truncation="error"``) or dropped and counted (``"drop"``); never cut silently.
    max_length: int | None = None
    truncation: str = "error"
    max_steps: int | None = None  # optimizer steps cap (smoke tests)
    gradient_checkpointing: bool = False
    dtype: str = "auto"  # weights as loaded; bf16 and fp16 also run the matching autocast
    lora: bool = False
    qlora: bool = False  # 4-bit base weights (bitsandbytes, CUDA) under LoRA adapters
    lora_r: int = 16
    lora_alpha: int = 32
    lora_dropout: float = 0.05
    lora_targets: str = LORA_TARGETS
    train_vision: bool = False  # full fine-tuning: the vision tower trains too; LoRA: adapted
    history: HistoryMode = "full"
    image: ImageMode = "heightmap"
    recipe: str = "mixed"
    data_fraction: float = 1.0
    val_fraction: float = 0.05  # episodes held out for the validation loss
    seed: int = 0
    log_every: int = 1
    save_every: int = 500  # optimizer steps between checkpoints (resume points)
    save_total_limit: int = 2
    eval_every: int = 500  # optimizer steps between validation losses
    #: Closed-loop evaluation: generated validation cases per level played by the model being
    #: trained, every ``play_every`` steps and at the end (0: off).
    play_cases: int = 0
    play_every: int = 500
    play_seed: int = 9_999  # user seed of those cases (training seed domain)
    play_backend: str = "geometric"
    workers: int = 0  # DataLoader worker processes (image decoding and tokenisation)
    report_to: str = "auto"
    template_kwargs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        require_choice(self.history, HistoryMode, "SFTConfig.history")
        require_choice(self.image, ImageMode, "SFTConfig.image")
        checks = [
            (self.epochs >= 1, "epochs", "must be >= 1"),
            (self.micro_batch >= 1, "micro_batch", "must be >= 1"),
            (self.grad_accum >= 1, "grad_accum", "must be >= 1"),
            (self.lr is None or self.lr > 0, "lr", "must be > 0"),
            (self.max_length is None or self.max_length >= 64, "max_length", "must be >= 64"),
            (self.truncation in TRUNCATIONS, "truncation", f"one of {TRUNCATIONS}"),
            (self.max_steps is None or self.max_steps >= 1, "max_steps", "must be >= 1"),
            (self.dtype in DTYPES, "dtype", f"one of {DTYPES}"),
            (self.recipe in RECIPES, "recipe", f"one of {tuple(RECIPES)}"),
            (0.0 < self.data_fraction <= 1.0, "data_fraction", "must be in (0, 1]"),
            (0.0 <= self.val_fraction < 1.0, "val_fraction", "must be in [0, 1)"),
            (0.0 <= self.warmup_ratio < 1.0, "warmup_ratio", "must be in [0, 1)"),
            (self.save_every >= 1, "save_every", "must be >= 1"),
            (self.save_total_limit >= 1, "save_total_limit", "must be >= 1"),
            (self.eval_every >= 1, "eval_every", "must be >= 1"),
            (self.play_cases >= 0, "play_cases", "must be >= 0"),
            (self.play_every >= 1, "play_every", "must be >= 1"),
            (self.play_backend in ("geometric", "mujoco"), "play_backend", "geometric|mujoco"),
            (self.workers >= 0, "workers", "must be >= 0"),
            (self.report_to in REPORTERS, "report_to", f"one of {REPORTERS}"),
            (not self.qlora or self.lora, "qlora", "needs lora (the adapters are what trains)"),
        ]
        for ok, name, rule in checks:
            if not ok:
                raise ConfigError(f"SFTConfig.{name} = {getattr(self, name)!r}: {rule}")

    @property
    def is_tiny(self) -> bool:
        return self.model.startswith("tiny:")

    @property
    def resolved_lr(self) -> float:
        return self.lr if self.lr is not None else (LR_TINY if self.is_tiny else LR_PRETRAINED)

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "lr": self.resolved_lr}


#: Fields a resumed run may change (how it is run, not what it learns).
RESUME_FREE_FIELDS = frozenset(
    {"out", "max_steps", "workers", "report_to", "log_every", "save_total_limit", "play_every"}
)


def resume_conflicts(saved: dict[str, Any], cfg: SFTConfig) -> list[str]:
    """Fields whose value differs from the run being resumed (``name: saved -> now``)."""
    now = cfg.to_dict()
    return [
        f"{k}: {saved[k]!r} -> {now[k]!r}"
        for k in sorted(now)
        if k in saved and k not in RESUME_FREE_FIELDS and saved[k] != now[k]
    ]


def model_dtype(cfg: SFTConfig) -> ModelDType:
    """The dtype the weights load in (``auto`` resolved by the caller, who knows the device)."""
    if cfg.dtype == "auto":
        raise ValueError("resolve dtype 'auto' against the device first")
    return cfg.dtype  # type: ignore[return-value]
