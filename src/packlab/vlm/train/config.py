"""The SFT job's configuration (no torch: the CLI validates it before importing the trainer)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from packlab.core.choices import HistoryMode, ImageMode, Precision, require_choice
from packlab.core.errors import ConfigError
from packlab.vlm.data.sft_examples import RECIPES

#: Default learning rates: the paper's 1e-5 for pretrained weights; tiny models start from
#: random weights and need a much larger step.
LR_PRETRAINED = 1e-5
LR_TINY = 1e-3
#: LoRA goes on the language model's projections only (the vision tower stays frozen); the
#: regex also catches Qwen3.5's gated-delta-net projections.
LORA_TARGETS = (
    r".*language_model.*\.(q_proj|k_proj|v_proj|o_proj|gate_proj|up_proj|down_proj"
    r"|in_proj_qkv|in_proj_z|out_proj)"
)


@dataclass(frozen=True)
class SFTConfig:
    """Everything a training run depends on; saved resolved beside its outputs."""

    data: str
    out: str
    model: str = "tiny:qwen3_5:small"  # a checkpoint directory, or tiny:<family>:<size>
    epochs: int = 1
    lr: float | None = None  # None: LR_TINY for tiny models, LR_PRETRAINED otherwise
    micro_batch: int = 1  # examples per forward pass per device
    grad_accum: int = 8  # global batch = micro_batch * grad_accum * devices
    weight_decay: float = 0.0
    warmup_ratio: float = 0.03
    max_grad_norm: float = 1.0
    max_length: int = 4096  # tokens; older past steps are dropped to fit (encode_fitting)
    max_steps: int | None = None  # optimizer steps cap (smoke tests)
    gradient_checkpointing: bool = False
    precision: Precision = "auto"  # auto (bf16 when a GPU supports it) | bf16 | no
    lora: bool = False
    lora_r: int = 16
    lora_alpha: int = 32
    lora_dropout: float = 0.05
    history: HistoryMode = "full"
    image: ImageMode = "heightmap"
    recipe: str = "mixed"
    data_fraction: float = 1.0
    seed: int = 0
    log_every: int = 1
    save_every_epoch: bool = True
    template_kwargs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        require_choice(self.precision, Precision, "SFTConfig.precision")
        require_choice(self.history, HistoryMode, "SFTConfig.history")
        require_choice(self.image, ImageMode, "SFTConfig.image")
        checks = [
            (self.epochs >= 1, "epochs", "must be >= 1"),
            (self.micro_batch >= 1, "micro_batch", "must be >= 1"),
            (self.grad_accum >= 1, "grad_accum", "must be >= 1"),
            (self.lr is None or self.lr > 0, "lr", "must be > 0"),
            (self.max_length >= 64, "max_length", "must be >= 64"),
            (self.recipe in RECIPES, "recipe", f"one of {tuple(RECIPES)}"),
            (0.0 < self.data_fraction <= 1.0, "data_fraction", "must be in (0, 1]"),
            (0.0 <= self.warmup_ratio < 1.0, "warmup_ratio", "must be in [0, 1)"),
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
