"""``packlab generate``: make a PackData dataset (sharded, parallel, resumable)."""

from __future__ import annotations

import argparse
import importlib
import sys

from packlab.bench.options import policy_names
from packlab.cli.options import add_field, config_kwargs
from packlab.core.choices import did_you_mean
from packlab.core.errors import ConfigError
from packlab.datagen.config import (
    RECIPES,
    AnchorConfig,
    CaseConfig,
    DatasetConfig,
    RunOptions,
    ValidationConfig,
)

#: What the command does (the data engine), imported when it runs.
RUN_MODULE = "packlab.cli.generate_run"


def _names(text: str) -> tuple[str, ...]:
    return tuple(t.strip() for t in text.split(",") if t.strip())


def _counts(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(t) for t in text.split(","))
    except ValueError:
        raise ConfigError(
            f"episodes = {text!r}: expected whole numbers separated by commas"
        ) from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Generate validated packing trajectories into a dataset directory. Rerun the "
        "same command to resume an interrupted run."
    )
    _add_dataset_options(p)
    _add_case_options(p)
    _add_output_options(p)
    _add_run_options(p)
    p.set_defaults(func=run)


def _add_dataset_options(p: argparse.ArgumentParser) -> None:
    """Which dataset: recipe, difficulties, episode counts, seed, output directory."""
    add_field(
        p,
        DatasetConfig,
        "recipe",
        "--recipe",
        choices=sorted(RECIPES),
        help="a named dataset (e.g. packdata-20k); sets difficulties, episodes and seed "
        "unless given",
    )
    add_field(
        p,
        DatasetConfig,
        "difficulties",
        "--difficulty",
        parse=_names,
        help="comma-separated difficulties, e.g. easy,medium,hard",
    )
    add_field(
        p,
        DatasetConfig,
        "episodes",
        "--episodes",
        parse=_counts,
        help="comma-separated episode counts, one per difficulty",
    )
    add_field(
        p,
        DatasetConfig,
        "seed",
        "--seed",
        help="user seed (training seed space; see datagen/seeds.py); default: the recipe's, else 0",
    )
    add_field(
        p,
        RunOptions,
        "out",
        "--out",
        required=True,
        help="dataset directory (created; an existing one is resumed)",
    )


def _add_case_options(p: argparse.ArgumentParser) -> None:
    """How cases are made and validated."""
    add_field(
        p,
        CaseConfig,
        "layout",
        "--layout",
        help="layout family (cut: the stack cut recursively, Zhao et al.'s CUT; random: drawn "
        "boxes, rs: i.i.d. boxes of 64 types, Zhao et al.'s RS; random and rs have no perfect "
        "layout, are not validated and need --teacher other than oracle); default {default}",
    )
    add_field(
        p,
        CaseConfig,
        "order",
        "--order",
        help="arrival order: removal (reverse removal) or layers (layer by layer, shuffled "
        "within a layer); for --layout cut: removal, base-height (by base height, shuffled "
        "within one; CUT-1) or support (drawn among the boxes whose footprint's surface "
        "stands at their base; CUT-2); random and rs cases arrive in draw order; "
        "default {default}",
    )
    add_field(
        p,
        CaseConfig,
        "sizes",
        "--sizes",
        help="grid: boxes fill their layout exactly (sides on the 2.5 cm grid); off-grid: "
        "cartons, each box 2-12 mm smaller across and 0-4 mm lower than its slot (layered, "
        "stepped and cut layouts; replays are kept at --min-overall times the boxes' fill of "
        "their slots); default {default}",
    )
    add_field(
        p,
        AnchorConfig,
        "corner_prob",
        "--corner-prob",
        help="chance that the first placement is anchored at a corner; default {default}",
    )
    add_field(
        p, ValidationConfig, "backend", "--validation", help="replay backend; default {default}"
    )
    add_field(
        p,
        ValidationConfig,
        "min_overall",
        "--min-overall",
        help="keep replays scoring at least this; default {default}",
    )
    add_field(
        p,
        ValidationConfig,
        "max_attempts",
        "--max-attempts",
        help="case seeds tried per episode slot; default {default}",
    )


def _add_output_options(p: argparse.ArgumentParser) -> None:
    """Shard size, image size and SFT export."""
    add_field(
        p,
        DatasetConfig,
        "shard_size",
        "--shard-size",
        help="episodes per shard (unit of resume); default {default}",
    )
    add_field(
        p,
        DatasetConfig,
        "image_size",
        "--image-size",
        help="heightmap image side in pixels; default {default}",
    )
    add_field(
        p,
        DatasetConfig,
        "sft",
        "--sft",
        help="SFT export: one conversation per episode, or none; default {default}",
    )
    add_field(
        p,
        DatasetConfig,
        "sft_window",
        "--sft-window",
        help="steps per SFT conversation, longer episodes cut into windows (0: whole); "
        "default {default}",
    )
    add_field(
        p,
        DatasetConfig,
        "teacher",
        "--teacher",
        help="policy whose actions the trajectories hold (e.g. plan, sdf); the oracle replays "
        "each layout's own plan; default {default}",
    )
    add_field(
        p,
        DatasetConfig,
        "sides",
        "--sides",
        help="how the rows name a box's sides (sizes and ground-truth actions alike): longer "
        "side first, as a robot's perception does, or as the catalogue does (catalogue: the "
        "reference paper's protocol, l the side a box lies along x in its perfect layout); "
        "default {default}",
    )


def _add_run_options(p: argparse.ArgumentParser) -> None:
    """Workers, executor and the progress bar."""
    add_field(
        p,
        RunOptions,
        "workers",
        "--workers",
        help="parallel workers (0 = one per core; 1 = in this process); default {default}",
    )
    add_field(
        p,
        RunOptions,
        "executor",
        "--executor",
        help="where shards run: a local process pool or Ray (needs the ray extra; the "
        "output directory must be on storage every Ray node can write); "
        "default {default}",
    )
    add_field(p, RunOptions, "progress", "--no-progress", help="no progress bar on stderr")


def config_from_args(args: argparse.Namespace) -> DatasetConfig:
    """The DatasetConfig the flags describe (raises ConfigError with one line if they do not)."""
    fields = config_kwargs(args, "generate", DatasetConfig)
    anchor = AnchorConfig(**config_kwargs(args, "generate", AnchorConfig))
    fields["case"] = CaseConfig(**config_kwargs(args, "generate", CaseConfig), anchor=anchor)
    fields["validation"] = ValidationConfig(**config_kwargs(args, "generate", ValidationConfig))
    recipe = fields.pop("recipe", None)
    if recipe:
        return _something_to_do(DatasetConfig.from_recipe(recipe, **fields))
    missing = [
        flag
        for flag, key in (("--difficulty", "difficulties"), ("--episodes", "episodes"))
        if key not in fields
    ]
    if missing:
        raise ConfigError(f"give {' and '.join(missing)} (or --recipe)")
    return _something_to_do(DatasetConfig(**fields))


def _something_to_do(config: DatasetConfig) -> DatasetConfig:
    """A dataset of zero episodes is a typo (refused rather than exiting 0 with an empty
    directory); a count of 0 for one difficulty among others stays allowed."""
    if config.total_episodes == 0:
        counts = ",".join(map(str, config.episodes))
        raise ConfigError(f"episodes = {counts!r}: nothing to generate; give at least one episode")
    return config


def check_teacher(name: str) -> None:
    """The teacher is a registered policy (names from the registry's entry points; no policy
    imported), with the nearest name when misspelt."""
    known = policy_names()
    if name not in known:
        raise ConfigError(
            f"teacher = {name!r}: not a registered policy{did_you_mean(name, known)}; "
            f"available: {', '.join(known)}"
        )


def options_from_args(args: argparse.Namespace) -> RunOptions:
    """How the dataset is produced (out, workers, executor, progress)."""
    return RunOptions(**config_kwargs(args, "generate", RunOptions))


def run(args: argparse.Namespace) -> int:
    """``packlab generate``: exit code 1 when some episode slots failed."""
    # The flags checked before the data engine is imported or the directory made.
    check_teacher(config_from_args(args).teacher)
    options_from_args(args)
    if not args.out.strip():
        raise ConfigError("out = '': give a dataset directory")
    return int(importlib.import_module(RUN_MODULE).run(args))


if __name__ == "__main__":  # pragma: no cover
    from packlab.cli.main import main

    sys.exit(main(["generate", *sys.argv[1:]]))
