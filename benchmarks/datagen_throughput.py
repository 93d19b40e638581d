"""Data-engine throughput: episodes per second per core for each difficulty, with the physics
(mujoco) replay validation and everything written (PNG per step, parquet shards, SFT JSONL).

Each difficulty runs as one shard in this process (one core), exactly as a pool worker runs it;
the time spent in case making + replay is split from the time spent writing. The PackData-20K
wall time on ``--cores`` cores is extrapolated from the per-episode costs (the work is
embarrassingly parallel: shards share nothing). ``--parallel`` also measures a real process-pool
run on a mixed sample to check that extrapolation.

    python benchmarks/datagen_throughput.py --episodes 100
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from packlab.datagen import engine
from packlab.datagen.config import RECIPES, CaseConfig, DatasetConfig, ValidationConfig
from packlab.datagen.engine import RunOptions, ShardSpec, generate_dataset, run_shard


def _size(root: Path, sub: str) -> tuple[int, int]:
    """(apparent bytes, allocated bytes) of the files under root/sub."""
    files = [p for p in (root / sub).rglob("*") if p.is_file()]
    return sum(p.stat().st_size for p in files), sum(p.stat().st_blocks * 512 for p in files)


def measure(difficulty: str, n: int, args: argparse.Namespace, root: Path) -> dict:
    cfg = DatasetConfig(
        (difficulty,),
        (n,),
        seed=args.seed,
        shard_size=n,
        image_size=args.image_size,
        sft=args.sft,
        case=CaseConfig(layout=args.layout),
        validation=ValidationConfig(backend=args.validation),
    )
    spent = {"replay": 0.0}
    real = engine.produce_slot

    def timed(*a):
        t = time.perf_counter()
        try:
            return real(*a)
        finally:
            spent["replay"] += time.perf_counter() - t

    engine.produce_slot = timed
    try:
        wall0, cpu0 = time.perf_counter(), time.process_time()
        stats = run_shard(cfg, ShardSpec(difficulty, 0, 0, n), root)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    finally:
        engine.produce_slot = real
    sizes = {k: _size(root, k) for k in ("images", "data", "sft")}
    return {
        "difficulty": difficulty,
        "episodes": stats.episodes,
        "steps": stats.steps,
        "rejected": stats.attempts - stats.episodes,
        "wall": wall,
        "cpu": cpu,
        "replay": spent["replay"],
        "sizes": sizes,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=100, help="episodes per difficulty")
    ap.add_argument("--difficulties", default="easy,medium,hard")
    ap.add_argument("--seed", type=int, default=12345)
    ap.add_argument("--layout", default="layered")
    ap.add_argument("--validation", default="mujoco")
    ap.add_argument("--image-size", type=int, default=224)
    ap.add_argument("--sft", default="episode", choices=("episode", "none"))
    ap.add_argument("--cores", type=int, default=2, help="cores to extrapolate the recipe to")
    ap.add_argument("--recipe", default="packdata-20k")
    ap.add_argument(
        "--parallel",
        type=int,
        default=0,
        metavar="N",
        help="also time a real process-pool run of N mixed episodes on --cores workers",
    )
    args = ap.parse_args()
    recipe = RECIPES[args.recipe]
    counts = dict(zip(recipe.difficulties, recipe.episodes))

    rows = []
    with tempfile.TemporaryDirectory(prefix="packlab-bench-") as tmp:
        for d in args.difficulties.split(","):
            rows.append(measure(d, args.episodes, args, Path(tmp) / d))

        print(
            f"datagen throughput: {args.episodes} episodes per difficulty, "
            f"validation={args.validation}, "
            f"layout={args.layout}, images {args.image_size}px, sft={args.sft}, one core each "
            f"(os.cpu_count()={os.cpu_count()})"
        )
        print()
        print(
            "| difficulty | episodes | steps/ep | rejected | s/ep wall | s/ep cpu | replay share "
            "| ep/s/core | disk/ep (KiB, apparent) | disk/ep (KiB, allocated) |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|")
        total_core_s = total_app = total_alloc = 0.0
        for r in rows:
            n = max(r["episodes"], 1)
            app = sum(a for a, _ in r["sizes"].values()) / n
            alloc = sum(b for _, b in r["sizes"].values()) / n
            print(
                f"| {r['difficulty']} | {r['episodes']} | {r['steps'] / n:.1f} | {r['rejected']} | "
                f"{r['wall'] / n:.3f} | {r['cpu'] / n:.3f} | "
                f"{r['replay'] / max(r['wall'], 1e-9):.0%} | "
                f"{n / r['wall']:.2f} | {app / 1024:.1f} | {alloc / 1024:.1f} |"
            )
            k = counts.get(r["difficulty"], 0)
            total_core_s += k * r["wall"] / n
            total_app += k * app
            total_alloc += k * alloc
        print()
        by_part = {
            part: sum(
                r["sizes"][part][0] / max(r["episodes"], 1) * counts.get(r["difficulty"], 0)
                for r in rows
            )
            for part in ("images", "data", "sft")
        }
        print(
            f"{args.recipe} extrapolated: {total_core_s / 3600:.2f} core-hours -> "
            f"{total_core_s / args.cores / 60:.1f} min wall on {args.cores} cores "
            f"(perfect scaling); "
            f"disk {total_app / 2**30:.2f} GiB apparent, {total_alloc / 2**30:.2f} GiB allocated "
            f"(images {by_part['images'] / 2**30:.2f}, parquet {by_part['data'] / 2**30:.2f}, "
            f"sft {by_part['sft'] / 2**30:.2f} GiB apparent)"
        )

        if args.parallel:
            mix = [counts[d] for d in recipe.difficulties]
            share = [max(1, round(args.parallel * m / sum(mix))) for m in mix]
            cfg = DatasetConfig(
                recipe.difficulties,
                tuple(share),
                seed=args.seed + 1,
                shard_size=max(1, min(share) // 2),
                image_size=args.image_size,
                sft=args.sft,
                case=CaseConfig(layout=args.layout),
                validation=ValidationConfig(backend=args.validation),
            )
            t = time.perf_counter()
            generate_dataset(
                cfg, RunOptions(str(Path(tmp) / "parallel"), workers=args.cores, progress=False)
            )
            wall = time.perf_counter() - t
            per = {r["difficulty"]: r["wall"] / max(r["episodes"], 1) for r in rows}
            serial_estimate = sum(k * per.get(d, 0.0) for d, k in zip(recipe.difficulties, share))
            print(
                f"process pool, {sum(share)} mixed episodes on {args.cores} workers: "
                f"{wall:.1f} s wall (one-core estimate {serial_estimate:.1f} s "
                f"-> speed-up {serial_estimate / wall:.2f}x); "
                f"recipe at this rate: {wall / sum(share) * recipe_total(recipe) / 60:.1f} min"
            )


def recipe_total(recipe) -> int:
    return sum(recipe.episodes)


if __name__ == "__main__":
    main()
