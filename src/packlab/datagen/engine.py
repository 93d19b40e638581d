"""The data engine: dataset config -> shards of validated episodes on disk, in parallel, resumable.

Work is cut into shards of ``shard_size`` consecutive slots of one difficulty. A shard is a pure
function of (config, difficulty, shard index): slot ``i`` tries the case seeds
``case_seed(seed, "train", difficulty, i, attempt)`` for attempt = 0, 1, ... until one passes
replay validation, so the output never depends on the number of workers, the backend or the
order shards finish in. Each finished shard leaves a marker (``meta/shards/<shard>.json``,
written after all its files); a rerun of the same command skips marked shards and redoes the
rest, so killing a run loses at most the shards in flight.

Executors (``packlab.executors``, ``RunOptions.executor``): ``process`` (default; a local process
pool, one shard per item; in this process with one worker) and ``ray`` (one Ray task per shard;
the output directory must be on storage every Ray node can write).
"""

from __future__ import annotations

import json
import os
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from packlab.core.choices import UNRECORDED_SIDES
from packlab.core.errors import ConfigError
from packlab.core.records import (
    PACKDATA_FORMAT,
    DatasetCounts,
    DatasetInfo,
    DifficultyCounts,
    FilesInfo,
    GeneratorInfo,
    ImageInfo,
)
from packlab.datagen import format as fmt
from packlab.datagen.config import GENERATOR_NAME, GENERATOR_VERSION, DatasetConfig, RunOptions
from packlab.datagen.generator import SlotOutcome, fill_slot
from packlab.datagen.seeds import id_prefix
from packlab.datagen.sft_export import sft_table
from packlab.datagen.validate import replay
from packlab.executors import Context, Lost, WorkerLost, progress_bar, run_items
from packlab.vlm.prompt.render import PROMPT_VERSION

#: The seed domain of training data (see packlab.datagen.seeds): disjoint from the bench's.
TRAIN_DOMAIN = "train"

#: Called once per finished slot with (kept?, rejected attempts) for progress reporting.
Report = Callable[[bool, int], None]


@dataclass(frozen=True, slots=True)
class ShardSpec:
    """Slots ``start .. start + count - 1`` of one difficulty."""

    difficulty: str
    index: int
    start: int
    count: int

    @property
    def name(self) -> str:
        return fmt.shard_name(self.difficulty, self.index)


@dataclass(frozen=True, slots=True)
class ShardStats:
    """What one shard produced; its JSON is the shard's completion marker."""

    shard: str
    difficulty: str
    slots: int
    episodes: int
    steps: int
    attempts: int
    rejections: dict[str, int] = field(default_factory=dict)
    failed_slots: tuple[int, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["failed_slots"] = list(self.failed_slots)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ShardStats:
        return cls(**{**d, "failed_slots": tuple(d.get("failed_slots", ()))})


def plan_shards(cfg: DatasetConfig) -> list[ShardSpec]:
    """Every shard of the dataset, in a fixed order (difficulty, then index)."""
    shards = []
    for difficulty, n in zip(cfg.difficulties, cfg.episodes):
        for index, start in enumerate(range(0, n, cfg.shard_size)):
            shards.append(ShardSpec(difficulty, index, start, min(cfg.shard_size, n - start)))
    return shards


# -- one slot, one shard ----------------------------------------------------------------------


def produce_slot(cfg: DatasetConfig, difficulty: str, slot: int) -> SlotOutcome:
    """The slot's first validated case in the training seed space, with the trajectory of the
    dataset's teacher on it (the validating replay itself when the teacher is the oracle). A
    ``random``-family case is not validated (it has no plan); its teacher's run is the episode."""
    assert cfg.seed is not None, "DatasetConfig resolves its seed on creation"
    outcome = fill_slot(
        cfg.seed, TRAIN_DOMAIN, difficulty, slot, cfg.case, cfg.validation,
        id_prefix(TRAIN_DOMAIN, cfg.seed), sides=cfg.sides,
    )  # fmt: skip
    if cfg.teacher == "oracle" or outcome.case is None:
        return outcome
    v = cfg.validation
    taught = replay(outcome.case, v.backend, v.run_seed, teacher=cfg.teacher, sides=cfg.sides)
    return replace(outcome, trajectory=taught)


def run_shard(
    cfg: DatasetConfig, spec: ShardSpec, root: Path, report: Report | None = None
) -> ShardStats:
    """Produce one shard's files under ``root`` and, last, its marker; returns its stats."""
    root = Path(root)
    step_rows: list[dict[str, Any]] = []
    episode_rows: list[dict[str, Any]] = []
    rejections: Counter[str] = Counter()
    failed: list[int] = []
    attempts = 0
    images = fmt.ShardImages(root, spec.difficulty, spec.name)
    for slot in range(spec.start, spec.start + spec.count):
        outcome = produce_slot(cfg, spec.difficulty, slot)
        trajectory, rejected = outcome.trajectory, outcome.rejected
        rejections.update(rejected)
        attempts += len(rejected) + (trajectory is not None)
        if trajectory is None:
            failed.append(slot)
        else:
            rows = fmt.step_rows(trajectory, spec.name)
            container = trajectory.case.container
            for row, seen in zip(rows, trajectory.steps):
                images.write(
                    row["image"], fmt.encode_png(seen.heightmap, container, cfg.image_size)
                )
            step_rows += rows
            episode_rows.append(fmt.episode_row(trajectory))
        if report is not None:
            report(trajectory is not None, len(rejected))
    images.commit()
    fmt.write_parquet(root / fmt.STEPS_DIR / f"{spec.name}.parquet", fmt.steps_table(step_rows))
    fmt.write_parquet(
        root / fmt.EPISODES_DIR / f"{spec.name}.parquet", fmt.episodes_table(episode_rows)
    )
    if cfg.sft != "none":
        fmt.write_parquet(
            root / fmt.SFT_DIR / f"{spec.name}.parquet",
            sft_table(step_rows, root, "hf", cfg.sft_window),
        )
    stats = ShardStats(
        spec.name,
        spec.difficulty,
        spec.count,
        len(episode_rows),
        len(step_rows),
        attempts,
        dict(sorted(rejections.items())),
        tuple(failed),
    )
    fmt.atomic_write_json(root / fmt.SHARDS_DIR / f"{spec.name}.json", stats.to_dict())
    return stats


# -- the output directory ---------------------------------------------------------------------


def _config_json(cfg: DatasetConfig) -> dict[str, Any]:
    # A JSON round trip turns tuples into lists, so stored and fresh configs compare equal.
    return json.loads(json.dumps(cfg.to_dict()))


def prepare_output(cfg: DatasetConfig, out: str | os.PathLike[str]) -> Path:
    """Create or reopen the dataset directory; fail with one line before any work starts."""
    root = Path(out)
    if root.exists() and not root.is_dir():
        raise ConfigError(
            f"out = {str(root)!r}: exists and is not a directory; give a directory "
            "(an existing dataset directory is resumed)"
        )
    try:
        root.mkdir(parents=True, exist_ok=True)
        probe = root / ".packlab-write-probe.tmp"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise ConfigError(
            f"out = {str(root)!r}: cannot write there ({exc.strerror or exc})"
        ) from None
    config_path = root / fmt.META_DIR / "config.json"
    wanted = _config_json(cfg)
    if config_path.exists():
        stored = json.loads(config_path.read_text())
        # Datasets made before the field existed named sides as the catalogue does: they
        # resume only under those names, never mixed with rows named otherwise.
        if isinstance(stored, dict):
            stored.setdefault("sides", UNRECORDED_SIDES)
        if stored != wanted:
            diff = sorted(k for k in set(stored) | set(wanted) if stored.get(k) != wanted.get(k))
            raise ConfigError(
                f"out = {str(root)!r}: holds a dataset made with a different config "
                f"({', '.join(diff)} "
                "differ); rerun with the same options to resume, or choose another --out"
            )
    elif any(p.name != ".packlab-write-probe.tmp" for p in root.iterdir()):
        raise ConfigError(
            f"out = {str(root)!r}: exists and is not an empty directory or a packlab dataset"
        )
    else:
        fmt.atomic_write_json(config_path, wanted)
    fmt.remove_stale_temporaries(root)
    return root


def finished_shards(root: Path) -> dict[str, ShardStats]:
    """Stats of every shard whose marker exists (the shard is complete)."""
    out = {}
    for path in sorted((root / fmt.SHARDS_DIR).glob("*.json")):
        out[path.stem] = ShardStats.from_dict(json.loads(path.read_text()))
    return out


def dataset_info(cfg: DatasetConfig, shards: list[ShardStats]) -> DatasetInfo:
    """``meta/info.json``: what the directory holds and how it was made (deterministic)."""
    per: dict[str, DifficultyCounts] = {}
    for d in cfg.difficulties:
        mine = [s for s in shards if s.difficulty == d]
        rej: Counter[str] = Counter()
        for s in mine:
            rej.update(s.rejections)
        attempts = sum(s.attempts for s in mine)
        episodes = sum(s.episodes for s in mine)
        per[d] = DifficultyCounts(
            requested=cfg.episodes[cfg.difficulties.index(d)],
            episodes=episodes,
            steps=sum(s.steps for s in mine),
            attempts=attempts,
            rejected=sum(rej.values()),
            acceptance_rate=round(episodes / attempts, 6) if attempts else None,
            rejections=dict(sorted(rej.items())),
            failed_slots=tuple(sorted(slot for s in mine for slot in s.failed_slots)),
        )
    total_rej: Counter[str] = Counter()
    for v in per.values():
        total_rej.update(v.rejections)
    return DatasetInfo(
        format_version=PACKDATA_FORMAT,
        name=cfg.recipe or "packdata-custom",
        generator=GeneratorInfo(
            name=GENERATOR_NAME, version=GENERATOR_VERSION, seed_domain=TRAIN_DOMAIN
        ),
        generator_config=_config_json(cfg),
        validation_backend=cfg.validation.backend,
        prompt_version=PROMPT_VERSION,
        counts=DatasetCounts(
            episodes=sum(v.episodes for v in per.values()),
            steps=sum(v.steps for v in per.values()),
            shards=len(shards),
            by_difficulty=per,
        ),
        rejections=dict(sorted(total_rej.items())),
        image=ImageInfo(
            size=cfg.image_size,
            format="png",
            mode="P",
            axes="x=columns left->right, y=rows top->bottom, cell (0,0) top-left",
            colour="absolute height, floor to rim",
        ),
        files=FilesInfo(
            steps=f"{fmt.STEPS_DIR}/*.parquet",
            episodes=f"{fmt.EPISODES_DIR}/*.parquet",
            sft=f"{fmt.SFT_DIR}/*.parquet" if cfg.sft != "none" else None,
            sft_mode=cfg.sft if not cfg.sft_window else f"{cfg.sft}, window {cfg.sft_window}",
            images=f"{fmt.IMAGES_DIR}/<difficulty>/<shard>/<episode_id>/<step>.png",
        ),
    )


def write_info(cfg: DatasetConfig, root: Path) -> DatasetInfo:
    wanted = {s.name for s in plan_shards(cfg)}
    shards = [s for name, s in finished_shards(root).items() if name in wanted]
    info = dataset_info(cfg, shards)
    fmt.write_info(root, info)
    fmt.atomic_write_bytes(root / "README.md", fmt.dataset_card(info).encode())
    return info


# -- running shards ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ShardWork:
    """The engine's work function for ``packlab.executors``: a shard -> its files under ``root``
    and its stats. Each finished slot reports ``(kept, rejected attempts)`` for the progress bar."""

    cfg: DatasetConfig
    root: Path

    def __call__(self, spec: ShardSpec, ctx: Context) -> ShardStats:
        def report(kept: bool, rejected: int) -> None:
            ctx.report((kept, rejected))

        return run_shard(self.cfg, spec, self.root, report)


def _lost_shard(spec: ShardSpec, lost: Lost) -> ShardStats:
    raise WorkerLost(
        f"the worker making shard {spec.name} was lost ({lost.kind}: {lost.detail}); "
        "finished shards are kept: rerun the same command to resume"
    )


class _Progress:
    """Slots done on a progress bar, with rejections in the postfix (``open`` it once the
    executor's workers have started)."""

    def __init__(self) -> None:
        self.bar: Any = None
        self.rejected = 0

    def open(self, total: int, initial: int, enabled: bool) -> None:
        self.bar = progress_bar(total, initial, "generate", enabled)

    def __call__(self, payload: tuple[bool, int]) -> None:
        _, rejected = payload
        self.rejected += rejected
        self.bar.set_postfix(rejected=self.rejected, refresh=False)
        self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def shard_order(pending: list[ShardSpec]) -> list[ShardSpec]:
    """Longest first (hard, then medium, then easy) so the last tasks are short: better balance."""
    weight = {"hard": 0, "medium": 1, "easy": 2}
    return sorted(pending, key=lambda s: (weight.get(s.difficulty, 3), s.difficulty, s.index))


def generate_dataset(cfg: DatasetConfig, options: RunOptions) -> DatasetInfo:
    """Make (or finish) the dataset of ``cfg`` in ``options.out``; returns its ``info.json``."""
    root = prepare_output(cfg, options.out)
    shards = plan_shards(cfg)
    done = finished_shards(root)
    pending = shard_order([s for s in shards if s.name not in done])
    total = sum(s.count for s in shards)
    workers = min(options.n_workers, max(len(pending), 1))
    progress = _Progress()
    # Interrupted or failed: leaving the block stops the workers. Shards in flight have no marker
    # and are redone by the next run; their staged files are removed then.
    with run_items(
        ShardWork(cfg, root),
        pending,
        executor=options.executor,
        workers=workers,
        on_report=progress,
        on_lost=_lost_shard,
    ) as results:
        progress.open(total, total - sum(s.count for s in pending), options.progress)
        try:
            for _ in results:
                pass  # each shard's files and marker are on disk once it is yielded
        finally:
            progress.close()
    return write_info(cfg, root)
