"""The candidate-mode recipe's settings (torch-free, so the CLI can build them without torch).
What each setting does: :mod:`packlab.vlm.candidate.dagger`."""

from __future__ import annotations

from dataclasses import dataclass

from packlab.core.choices import TEACHERS, AutocastDType, LineFields, PointerMap, require_choice
from packlab.core.errors import ConfigError
from packlab.policies.candidates import STUDENT_K
from packlab.vlm.candidate.compose import Instructions
from packlab.vlm.candidate.image import TOKENS_PER_SIDE
from packlab.vlm.candidate.precision import check_device, check_dtype

#: The recipe's module (vlm extra), imported when ``packlab train candidate`` runs.
DAGGER_MODULE = "packlab.vlm.candidate.dagger"


def check_model_view(
    map: PointerMap,
    line_fields: LineFields,
    image_tokens: int,
    footprint_pool: bool,
    footprint_context: bool,
) -> None:
    """ConfigError naming the field unless the settings of what the model reads go together
    (the training and the DAgger recipes take the same ones)."""
    require_choice(map, PointerMap, "map")
    require_choice(line_fields, LineFields, "line_fields")
    if image_tokens < 1:
        raise ConfigError(f"image_tokens = {image_tokens}: must be >= 1")
    if footprint_pool and map == "text":
        raise ConfigError("footprint_pool needs a map with an image, not map = 'text'")
    if footprint_context and not footprint_pool:
        raise ConfigError("footprint_context needs footprint_pool (--footprint-pool)")


@dataclass(frozen=True)
class DaggerConfig:
    out: str
    teacher: str = "plan"
    rounds: int = 1  # DAgger rounds after round 0
    cases_per_round: int = 450
    eval_cases_per_level: int = 5
    steps: int = 1500  # round 0's updates
    round_steps: int = 1000  # updates of each later round (warm start)
    model: str = "tiny:qwen3_vl:mini"
    instructions: Instructions = "short"
    blank_map: bool = False  # ablation: zero the heightmap in whatever form ``map`` shows it
    #: How the model sees the heightmap: image (vision tower), text (digit map), both, or blank
    #: (an all-zero image: the blank-image ablation).
    map: PointerMap = "image"
    #: The head also reads each listed line's numeric vector (level fit, geometry).
    line_vectors: bool = True
    #: What each listed line names: its box, rotation, cell and geometry (full) or no geometry
    #: (cell).
    line_fields: LineFields = "full"
    #: Merged visual tokens per side of the heightmap image (image maps).
    image_tokens: int = TOKENS_PER_SIDE
    #: The head also pools the visual tokens under each listed line's footprint (image maps;
    #: such a model plays under torch only).
    footprint_pool: bool = False
    #: With ``footprint_pool``: the head also reads the max over the footprint's tokens and the
    #: mean over the one-token ring around it.
    footprint_context: bool = False
    #: Placements listed per state, in collection and at play time.
    k: int = STUDENT_K
    #: List the placements in a random order per state, so position says nothing.
    shuffle: bool = True
    pool: str = "last"  # how a listed line becomes one vector: "last" token or "mean"
    batch: int = 16
    lr: float = 1e-3
    workers: int = 2
    seed: int = 0
    minutes_per_round: float | None = None
    threads: int | None = None  # torch threads for training (None: torch's default)
    #: Where training and its evaluation run: auto (a GPU when torch sees one), cpu, cuda,
    #: cuda:<index>. Collection plays the previous round's ONNX export on the CPU whatever this
    #: is, and the saved model is on the CPU, so it plays and resumes anywhere.
    device: str = "auto"
    #: fp32, or bf16: forward passes under bf16 autocast on a GPU that has it (weights and
    #: optimizer stay float32); refused where there is none.
    dtype: AutocastDType = "fp32"

    def __post_init__(self) -> None:
        if self.teacher not in TEACHERS:
            raise ConfigError(f"teacher = {self.teacher!r}: expected one of {', '.join(TEACHERS)}")
        for name in ("cases_per_round", "steps", "round_steps", "batch", "workers"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} = {getattr(self, name)}: must be >= 1")
        check_model_view(
            self.map,
            self.line_fields,
            self.image_tokens,
            self.footprint_pool,
            self.footprint_context,
        )
        if self.rounds < 0:
            raise ConfigError(f"rounds = {self.rounds}: must be >= 0")
        check_device("DaggerConfig", self.device)
        check_dtype("DaggerConfig", self.dtype, self.device)
