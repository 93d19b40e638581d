"""Every published parameter of the data engine, as data, in one place.

The difficulty table (buffer size, object and layer counts, stack-height ratio, container base
sizes) and the object limits define both PackLab-Bench and PackData, so they live here and
nowhere else: the sampler, the tests, the dataset card and ``inspect-data`` all read them from
this module. Lengths are integer millimetres (the core's unit); the comments give the paper's cm.

Config dataclasses validate themselves on creation and raise ``ConfigError`` with one line
naming the field, so a bad configuration fails before any work starts.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from typing import Any

from packlab.core.choices import (
    DEFAULT_SIDES,
    ArrivalOrder,
    CaseSizes,
    Executor,
    LayoutFamily,
    PhysicsBackend,
    SFTExport,
    SideNames,
    require_choice,
)
from packlab.core.errors import ConfigError
from packlab.core.types import DEFAULT_CELL_XY_MM, DEFAULT_CELL_Z_MM

#: Families with no perfect layout (no ``gt_plan``, no replay validation; draw order).
NO_LAYOUT_FAMILIES: tuple[str, ...] = ("random", "rs")
#: Arrival orders made for cut layouts only (``packlab.datagen.cut_order``).
CUT_ORDERS: tuple[str, ...] = ("base-height", "support")

#: Bumped whenever the same seed would produce a different case (sampler or layout change).
GENERATOR_VERSION = "packlab-datagen-1"
GENERATOR_NAME = "packlab.datagen"


@dataclass(frozen=True, slots=True)
class DifficultySpec:
    """The published scenario parameters of one difficulty level (inclusive ranges)."""

    name: str
    buffer_size: int
    n_objects: tuple[int, int]
    n_layers: tuple[int, int]
    height_ratio: tuple[float, float]  # stack height / container height
    base_sizes_mm: tuple[tuple[int, int, int], ...]  # container (X, Y, Z) before jitter

    def __post_init__(self) -> None:
        where = f"difficulty {self.name!r}"
        if self.buffer_size < 1:
            raise ConfigError(f"{where}: buffer_size = {self.buffer_size}: must be at least 1")
        for label, (lo, hi) in (("n_objects", self.n_objects), ("n_layers", self.n_layers)):
            if not 1 <= lo <= hi:
                raise ConfigError(f"{where}: {label} = {(lo, hi)}: need 1 <= low <= high")
        if self.n_objects[0] < self.n_layers[1]:
            raise ConfigError(
                f"{where}: fewer objects {self.n_objects} than layers {self.n_layers}"
            )
        low, high = self.height_ratio
        if not 0.0 < low <= high <= 1.0:
            raise ConfigError(
                f"{where}: height_ratio = {self.height_ratio}: need 0 < low <= high <= 1"
            )
        if not self.base_sizes_mm:
            raise ConfigError(f"{where}: base_sizes_mm is empty")


def _cm3(x: float, y: float, z: float) -> tuple[int, int, int]:
    return (round(x * 10), round(y * 10), round(z * 10))


#: The paper's three levels. Container sizes are given in cm there.
DIFFICULTIES: dict[str, DifficultySpec] = {
    "easy": DifficultySpec(
        "easy",
        buffer_size=3,
        n_objects=(4, 8),
        n_layers=(1, 2),
        height_ratio=(0.45, 0.70),
        base_sizes_mm=(_cm3(50, 50, 40), _cm3(60, 50, 45), _cm3(60, 60, 50), _cm3(80, 60, 55)),
    ),
    "medium": DifficultySpec(
        "medium",
        buffer_size=5,
        n_objects=(9, 18),
        n_layers=(2, 3),
        height_ratio=(0.45, 0.70),
        base_sizes_mm=(_cm3(80, 80, 60), _cm3(100, 80, 70), _cm3(100, 100, 80), _cm3(120, 100, 90)),
    ),
    "hard": DifficultySpec(
        "hard",
        buffer_size=10,
        n_objects=(19, 32),
        n_layers=(3, 4),
        height_ratio=(0.84, 0.96),
        base_sizes_mm=(
            _cm3(120, 120, 90),
            _cm3(140, 120, 100),
            _cm3(140, 140, 100),
            _cm3(160, 120, 110),
        ),
    ),
}


def difficulty_spec(name: str) -> DifficultySpec:
    """The spec of a difficulty by name; ``ConfigError`` naming the choices otherwise."""
    try:
        return DIFFICULTIES[name]
    except KeyError:
        raise ConfigError(
            f"difficulty = {name!r}: unknown; choose from {', '.join(DIFFICULTIES)}"
        ) from None


@dataclass(frozen=True, slots=True)
class ContainerLimits:
    """Jitter and clamps applied to a container base size (shared by all difficulties)."""

    jitter_xy_mm: int = 100  # +-10 cm, in whole cells (multiples of cell_xy_mm)
    jitter_z_mm: int = 100  # +-10 cm, in whole cm
    jitter_z_step_mm: int = 10
    clamp_xy_mm: tuple[int, int] = (500, 1700)  # [50, 170] cm
    clamp_z_mm: tuple[int, int] = (350, 1200)  # [35, 120] cm


@dataclass(frozen=True, slots=True)
class ObjectLimits:
    """Shape limits of every generated object."""

    min_side_mm: int = 75  # 7.5 cm = 3 grid cells
    max_aspect: float = 3.0  # long over short side of the footprint
    layer_height_mm: tuple[int, int] = (80, 560)  # 8-56 cm
    height_step_mm: int = 10  # layer heights in whole cm
    rotated_fraction: float = 0.25  # objects presented with rotation 1 in the plan


#: Corners of the floor a first placement may be anchored at: (x at max?, y at max?).
CORNERS: dict[str, tuple[bool, bool]] = {
    "x0y0": (False, False),
    "x1y0": (True, False),
    "x0y1": (False, True),
    "x1y1": (True, True),
}


@dataclass(frozen=True, slots=True)
class AnchorConfig:
    """Where the first placement goes: a corner with ``corner_prob``, else any floor object."""

    corner_prob: float = 0.8
    corners: tuple[str, ...] = tuple(CORNERS)

    def __post_init__(self) -> None:
        if not 0.0 <= self.corner_prob <= 1.0:
            raise ConfigError(f"anchor.corner_prob = {self.corner_prob!r}: must be in [0, 1]")
        bad = [c for c in self.corners if c not in CORNERS]
        if bad or not self.corners:
            raise ConfigError(
                f"anchor.corners = {self.corners!r}: choose from {', '.join(CORNERS)}"
            )


@dataclass(frozen=True, slots=True)
class ClearanceConfig:
    """How much smaller than its slot of the layout an ``off-grid`` box is (inclusive ranges,
    whole mm, drawn uniformly per box and side from the case's clearance stream): ``xy_mm`` off
    each of the footprint's sides, ``z_mm`` off its height."""

    xy_mm: tuple[int, int] = (2, 12)
    z_mm: tuple[int, int] = (0, 4)

    def __post_init__(self) -> None:
        for name, (lo, hi) in (("xy_mm", self.xy_mm), ("z_mm", self.z_mm)):
            if not 0 <= lo <= hi:
                raise ConfigError(f"clearance.{name} = {(lo, hi)!r}: need 0 <= low <= high")


@dataclass(frozen=True, slots=True)
class CaseConfig:
    """Everything that decides what case a case seed turns into (besides the difficulty)."""

    #: Layout family (``packlab.datagen.layout``): "layered" is the paper's, "stepped" the opt-in
    #: richer family (regions of a layer split at different heights), "random" independently
    #: drawn boxes with no perfect layout (``packlab.datagen.random_family``), "cut" the stack
    #: cuboid cut recursively (``packlab.datagen.cut_family``), "rs" i.i.d. boxes of 64 types
    #: (``packlab.datagen.rs_family``, no perfect layout).
    layout: LayoutFamily = "layered"
    #: Arrival order (``packlab.datagen.removal``): "removal" (reverse removal, the default) or
    #: "layers" (layer by layer, shuffled within a layer); for cut layouts "removal",
    #: "base-height" or "support" (``packlab.datagen.cut_order``). Random and rs cases arrive in
    #: draw order.
    order: ArrivalOrder = "removal"
    #: Stepped family only: chance that a region of a layer is split into two sub-layers.
    step_prob: float = 0.6
    anchor: AnchorConfig = field(default_factory=AnchorConfig)
    container: ContainerLimits = field(default_factory=ContainerLimits)
    objects: ObjectLimits = field(default_factory=ObjectLimits)
    cell_xy_mm: int = DEFAULT_CELL_XY_MM
    cell_z_mm: int = DEFAULT_CELL_Z_MM
    #: Distinct colour ids given to objects (``type_id`` only picks a colour).
    n_types: int = 8
    #: Box sizes of the layout families (``CaseSizes``): ``grid`` fills the layout exactly,
    #: ``off-grid`` makes every box ``clearance`` smaller than its slot (sides off the grid).
    sizes: CaseSizes = "grid"
    clearance: ClearanceConfig = field(default_factory=ClearanceConfig)

    def __post_init__(self) -> None:
        require_choice(self.layout, LayoutFamily, "layout")
        require_choice(self.order, ArrivalOrder, "order")
        if self.layout == "random" and self.order != "removal":
            raise ConfigError(
                f"order = {self.order!r}: the random layout has no layers; its objects arrive "
                "in draw order (leave order at removal)"
            )
        if self.layout == "rs" and self.order != "removal":
            raise ConfigError(
                f"order = {self.order!r}: the rs layout has no layout; its objects arrive in "
                "draw order (leave order at removal)"
            )
        if self.order in CUT_ORDERS and self.layout != "cut":
            raise ConfigError(
                f"order = {self.order!r}: an order of cut layouts (Zhao et al.'s CUT sets), not "
                f"of layout {self.layout!r}; use removal or layers"
            )
        if self.order == "layers" and self.layout == "cut":
            raise ConfigError(
                "order = 'layers': cut layouts have no layers; use base-height (by base height, "
                "shuffled within one), support or removal"
            )
        if not 0.0 <= self.step_prob <= 1.0:
            raise ConfigError(f"step_prob = {self.step_prob!r}: must be in [0, 1]")
        if self.objects.min_side_mm % self.cell_xy_mm:
            raise ConfigError(
                f"objects.min_side_mm = {self.objects.min_side_mm}: not a multiple of the grid"
            )
        if self.n_types < 1:
            raise ConfigError(f"n_types = {self.n_types}: must be at least 1")
        require_choice(self.sizes, CaseSizes, "sizes")
        if self.sizes == "off-grid" and self.layout in NO_LAYOUT_FAMILIES:
            raise ConfigError(
                f"sizes = 'off-grid': layout {self.layout!r} has no layout whose slots the boxes "
                "could be made smaller than; use layered, stepped or cut"
            )
        if self.sizes == "off-grid" and self.clearance.xy_mm[1] >= self.cell_xy_mm:
            raise ConfigError(
                f"clearance.xy_mm = {self.clearance.xy_mm!r}: must stay under the "
                f"{self.cell_xy_mm} mm cell (a box keeps the cells of its slot)"
            )
        if self.sizes == "off-grid" and self.clearance.z_mm[1] >= self.objects.layer_height_mm[0]:
            raise ConfigError(
                f"clearance.z_mm = {self.clearance.z_mm!r}: must stay under the lowest layer "
                f"height ({self.objects.layer_height_mm[0]} mm)"
            )

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        if self.order == "removal":  # configs saved before the field existed stay equal
            del out["order"]
        if self.sizes == "grid":  # likewise: grid configs keep the bytes they always had
            del out["sizes"], out["clearance"]
        return out


@dataclass(frozen=True, slots=True)
class ValidationConfig:
    """Replay validation: backend, the run seed of the shuffle, and when a replay is accepted."""

    #: What replay validation runs each plan on: physics (the default) or exact Eq. 2 (fast).
    backend: PhysicsBackend = "mujoco"
    run_seed: int = 0
    min_overall: float = 0.99
    #: Fresh case seeds tried for one dataset slot before the slot is reported as failed.
    max_attempts: int = 20

    def __post_init__(self) -> None:
        require_choice(self.backend, PhysicsBackend, "validation")
        if not 0.0 <= self.min_overall <= 1.0:
            raise ConfigError(f"min_overall = {self.min_overall!r}: must be in [0, 1]")
        if self.max_attempts < 1:
            raise ConfigError(f"max_attempts = {self.max_attempts}: must be at least 1")


@dataclass(frozen=True, slots=True)
class Recipe:
    """A named, reproducible dataset: difficulties, episode counts and seed."""

    name: str
    difficulties: tuple[str, ...]
    episodes: tuple[int, ...]
    seed: int
    description: str = ""


#: Named datasets; ``packlab generate --recipe NAME`` reproduces one in one flag.
RECIPES: dict[str, Recipe] = {
    "packdata-20k": Recipe(
        "packdata-20k",
        ("easy", "medium", "hard"),
        (9000, 7000, 4000),
        seed=20250,
        description="PackData-20K: 9000 easy, 7000 medium, 4000 hard validated trajectories",
    ),
    "packdata-mini": Recipe(
        "packdata-mini",
        ("easy", "medium", "hard"),
        (18, 14, 8),
        seed=20250,
        description="A 40-episode slice with the 20K mix, for a quick try",
    ),
}


#: Size limits checked on creation: a typo such as --episodes 100000000000 must be an error,
#: not a plan that exhausts memory. The user seed is stored as an int64 Parquet column.
MAX_EPISODES_PER_DIFFICULTY = 1_000_000
MAX_USER_SEED = 2**63 - 1


@dataclass(frozen=True, slots=True)
class DatasetConfig:
    """Everything that decides a dataset's *contents* (how it is run is ``engine.RunOptions``).

    Saved as ``generator_config`` in ``meta/info.json``; a rerun into the same directory must
    match it exactly, which is what makes resuming safe.
    """

    difficulties: tuple[str, ...]
    episodes: tuple[int, ...]
    #: The user seed (training seed space, datagen/seeds.py). None: the recipe's seed, else 0;
    #: resolved on creation, so a made config always holds an int.
    seed: int | None = None
    case: CaseConfig = field(default_factory=CaseConfig)
    validation: ValidationConfig = field(default_factory=ValidationConfig)
    shard_size: int = 100
    image_size: int = 224
    #: SFT export: one multi-turn conversation per episode (``sft/<shard>.parquet``), or none.
    sft: SFTExport = "episode"
    #: Steps per SFT conversation (0: whole episodes); longer episodes are cut into consecutive
    #: windows, every step a target in exactly one.
    sft_window: int = 0
    recipe: str | None = None
    #: The policy whose actions the trajectories hold. "oracle": the layout's own plan (the
    #: replay that validated the case). Any other registered policy (e.g. "plan", "sdf") is run
    #: closed loop on each validated case, on the validation backend, and its trajectory is
    #: written whatever it scores: labels of that teacher on the states it reaches itself.
    teacher: str = "oracle"
    #: How the rows' observations name a box's sides (``packlab.core.choices.SideNames``): longer
    #: first, as a robot's perception does, or as the catalogue does (the reference's protocol,
    #: l after the side a box lies along x in its perfect layout). Sizes and ground-truth
    #: actions are written in that frame. Always saved; a dataset without it used the catalogue's.
    sides: SideNames = DEFAULT_SIDES

    def __post_init__(self) -> None:
        if self.seed is None:
            recipe = RECIPES.get(self.recipe) if self.recipe is not None else None
            object.__setattr__(self, "seed", recipe.seed if recipe is not None else 0)
        if not self.difficulties:
            raise ConfigError("difficulty: give at least one of " + ", ".join(DIFFICULTIES))
        for name in self.difficulties:
            difficulty_spec(name)
        if len(set(self.difficulties)) != len(self.difficulties):
            raise ConfigError(
                f"difficulty = {','.join(self.difficulties)}: a difficulty is repeated"
            )
        if len(self.episodes) != len(self.difficulties):
            raise ConfigError(
                f"episodes = {','.join(map(str, self.episodes))}: give one count per difficulty "
                f"({len(self.difficulties)})"
            )
        for name, n in zip(self.difficulties, self.episodes):
            if (
                isinstance(n, bool)
                or not isinstance(n, int)
                or not 0 <= n <= MAX_EPISODES_PER_DIFFICULTY
            ):
                raise ConfigError(
                    f"episodes for {name} = {n!r}: must be a whole number >= 0 "
                    f"and <= {MAX_EPISODES_PER_DIFFICULTY}"
                )
        if (
            isinstance(self.seed, bool)
            or not isinstance(self.seed, int)
            or not 0 <= self.seed <= MAX_USER_SEED
        ):
            raise ConfigError(
                f"seed = {self.seed!r}: must be a whole number >= 0 and <= {MAX_USER_SEED}"
            )
        if self.shard_size < 1:
            raise ConfigError(f"shard_size = {self.shard_size}: must be at least 1")
        if not 16 <= self.image_size <= 4096:
            raise ConfigError(f"image_size = {self.image_size}: must be in [16, 4096] px")
        require_choice(self.sft, SFTExport, "sft")
        if self.sft_window < 0:
            raise ConfigError(f"sft_window = {self.sft_window}: must be >= 0 (0: whole episodes)")
        require_choice(self.sides, SideNames, "sides")
        if not self.teacher.strip():
            raise ConfigError("teacher = '': name a registered policy, e.g. oracle or plan")
        if self.case.layout in NO_LAYOUT_FAMILIES and self.teacher == "oracle":
            raise ConfigError(
                f"teacher = 'oracle': the {self.case.layout} layout has no perfect layout to "
                "replay; "
                "name another policy (e.g. --teacher plan or a heuristic such as sdf)"
            )
        if self.recipe is not None and self.recipe not in RECIPES:
            raise ConfigError(
                f"recipe = {self.recipe!r}: unknown; choose from {', '.join(RECIPES)}"
            )

    @property
    def total_episodes(self) -> int:
        return sum(self.episodes)

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["case"] = self.case.to_dict()
        if self.teacher == "oracle":  # datasets made before the field existed stay resumable
            del out["teacher"]
        return out

    @classmethod
    def from_recipe(cls, name: str, **overrides: Any) -> DatasetConfig:
        """The config of a named recipe; ``overrides`` (e.g. ``seed``) replace its fields."""
        if name not in RECIPES:
            raise ConfigError(f"recipe = {name!r}: unknown; choose from {', '.join(RECIPES)}")
        r = RECIPES[name]
        fields: dict[str, Any] = {
            "difficulties": r.difficulties,
            "episodes": r.episodes,
            "seed": r.seed,
            "recipe": name,
        }
        fields.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**fields)


@dataclass(frozen=True, slots=True)
class RunOptions:
    """How a dataset is produced (never what it contains)."""

    out: str
    workers: int = 0  # 0: one per CPU core; 1: in this process (process executor)
    executor: Executor = "process"  # where shards run (packlab.executors)
    progress: bool = True

    def __post_init__(self) -> None:
        require_choice(self.executor, Executor, "executor")
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 0:
            raise ConfigError(f"workers = {self.workers}: must be >= 0 (0 = one per core)")

    @property
    def n_workers(self) -> int:
        return self.workers or os.cpu_count() or 1
