"""What ``packlab generate`` does (:mod:`packlab.cli.generate` defines its flags and imports this
module when it runs)."""

from __future__ import annotations

import argparse

from packlab.cli.generate import config_from_args, options_from_args
from packlab.core.errors import ConfigError
from packlab.datagen.engine import generate_dataset


def run(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    if not args.out.strip():
        raise ConfigError("out = '': give a dataset directory")
    options = options_from_args(args)
    info = generate_dataset(cfg, options)
    counts = info.counts
    print(f"{args.out}: {counts.episodes} episodes, {counts.steps} steps")
    for name, d in counts.by_difficulty.items():
        rej = ", ".join(f"{k}={v}" for k, v in d.rejections.items()) or "none"
        failed = f", {len(d.failed_slots)} slots failed" if d.failed_slots else ""
        print(
            f"  {name:<7} {d.episodes}/{d.requested} episodes, {d.steps} steps, "
            f"rejections: {rej}{failed}"
        )
    return 0 if not any(d.failed_slots for d in counts.by_difficulty.values()) else 1
