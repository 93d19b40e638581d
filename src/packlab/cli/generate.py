"""``packlab generate``: make a PackData dataset (sharded, parallel, resumable)."""

from __future__ import annotations

import argparse
import sys

from packlab.core.errors import ConfigError
from packlab.datagen.config import (
    LAYOUT_FAMILIES,
    RECIPES,
    SFT_MODES,
    VALIDATION_BACKENDS,
    AnchorConfig,
    CaseConfig,
    DatasetConfig,
    ValidationConfig,
)
from packlab.datagen.engine import EXEC_BACKENDS, RunOptions, generate_dataset


def _names(text: str | None) -> tuple[str, ...] | None:
    return None if text is None else tuple(t.strip() for t in text.split(",") if t.strip())


def _counts(text: str | None) -> tuple[int, ...] | None:
    if text is None:
        return None
    try:
        return tuple(int(t) for t in text.split(","))
    except ValueError:
        raise ConfigError(f"episodes = {text!r}: expected whole numbers separated by commas") from None


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "generate", help="generate a PackData dataset",
        description="Generate validated packing trajectories into a dataset directory. Rerun the "
                    "same command to resume an interrupted run.",
    )
    p.add_argument("--recipe", choices=sorted(RECIPES), help="a named dataset (e.g. packdata-20k); "
                   "sets difficulties, episodes and seed unless given")
    p.add_argument("--difficulty", help="comma-separated difficulties, e.g. easy,medium,hard")
    p.add_argument("--episodes", help="comma-separated episode counts, one per difficulty")
    p.add_argument("--seed", type=int, help="user seed (training seed space; see datagen/seeds.py)")
    p.add_argument("--out", required=True, help="dataset directory (created; an existing one is resumed)")
    p.add_argument("--layout", choices=LAYOUT_FAMILIES, default="layered", help="layout family")
    p.add_argument("--corner-prob", type=float, default=AnchorConfig().corner_prob,
                   help="chance that the first placement is anchored at a corner")
    p.add_argument("--validation", choices=VALIDATION_BACKENDS, default="mujoco", help="replay backend")
    p.add_argument("--min-overall", type=float, default=0.99, help="keep replays scoring at least this")
    p.add_argument("--max-attempts", type=int, default=20, help="case seeds tried per episode slot")
    p.add_argument("--shard-size", type=int, default=100, help="episodes per shard (unit of resume)")
    p.add_argument("--image-size", type=int, default=224, help="heightmap image side in pixels")
    p.add_argument("--sft", choices=SFT_MODES, default="per_step", help="SFT export granularity")
    p.add_argument("--workers", type=int, default=0, help="parallel workers (0 = one per core)")
    p.add_argument("--backend", choices=EXEC_BACKENDS, default="process", help="where shards run")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=run)


def config_from_args(args: argparse.Namespace) -> DatasetConfig:
    """The DatasetConfig the flags describe (raises ConfigError with one line if they do not)."""
    fields = {
        "difficulties": _names(args.difficulty),
        "episodes": _counts(args.episodes),
        "seed": args.seed,
        "case": CaseConfig(layout=args.layout, anchor=AnchorConfig(corner_prob=args.corner_prob)),
        "validation": ValidationConfig(backend=args.validation, min_overall=args.min_overall,
                                    max_attempts=args.max_attempts),
        "shard_size": args.shard_size,
        "image_size": args.image_size,
        "sft": args.sft,
    }
    if args.recipe:
        return DatasetConfig.from_recipe(args.recipe, **fields)
    missing = [flag for flag, key in (("--difficulty", "difficulties"), ("--episodes", "episodes"))
               if fields[key] is None]
    if missing:
        raise ConfigError(f"give {' and '.join(missing)} (or --recipe)")
    if fields["seed"] is None:
        fields["seed"] = 0
    return DatasetConfig(**fields)


def run(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    if not args.out.strip():
        raise ConfigError("out = '': give a dataset directory")
    options = RunOptions(out=args.out, workers=args.workers, backend=args.backend, progress=not args.no_progress)
    info = generate_dataset(cfg, options)
    counts = info["counts"]
    print(f"{args.out}: {counts['episodes']} episodes, {counts['steps']} steps")
    for name, d in counts["by_difficulty"].items():
        rej = ", ".join(f"{k}={v}" for k, v in d["rejections"].items()) or "none"
        failed = f", {len(d['failed_slots'])} slots failed" if d["failed_slots"] else ""
        print(f"  {name:<7} {d['episodes']}/{d['requested']} episodes, {d['steps']} steps, "
              f"rejections: {rej}{failed}")
    return 0 if not any(d["failed_slots"] for d in counts["by_difficulty"].values()) else 1


if __name__ == "__main__":  # pragma: no cover
    from packlab.cli.main import main

    sys.exit(main(["generate", *sys.argv[1:]]))
