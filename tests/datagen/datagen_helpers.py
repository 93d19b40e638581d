"""Helpers of the data-engine tests: a tiny dataset config on the fast (geometric) path."""

from __future__ import annotations

from pathlib import Path

from packlab.datagen.config import DatasetConfig, ValidationConfig
from packlab.datagen.engine import RunOptions, generate_dataset


def tiny_config(**overrides) -> DatasetConfig:
    """Three difficulties, a few episodes, geometric replay (instant) and small shards."""
    fields = {
        "difficulties": ("easy", "medium", "hard"),
        "episodes": (5, 3, 2),
        "seed": 7,
        "shard_size": 2,
        "image_size": 64,
        "validation": ValidationConfig(backend="geometric"),
    }
    fields.update(overrides)
    return DatasetConfig(**fields)


def make_dataset(out: Path, cfg: DatasetConfig | None = None, **options) -> dict:
    return generate_dataset(
        cfg or tiny_config(), RunOptions(str(out), workers=1, progress=False, **options)
    )


def tree_bytes(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` by relative path (for byte-identity checks)."""
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }
