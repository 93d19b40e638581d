"""What ``packlab inspect-data`` does (:mod:`packlab.cli.inspect_data` defines its flags and
imports this module when it runs)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from packlab.core.errors import ConfigError
from packlab.core.records import to_builtins
from packlab.datagen.format import read_info
from packlab.datagen.stats import collect, dataset_cases, format_report, save_histograms


def run(args: argparse.Namespace) -> int:
    root = Path(args.dir)
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise ConfigError(f"dir = {str(root)!r}: no meta/info.json; not a finished packlab dataset")
    info = read_info(root)  # typed, its format_version checked
    dists = collect(dataset_cases(root))
    if args.json:
        as_json = json.loads(json.dumps(to_builtins(info), sort_keys=True))  # the file's key order
        print(
            json.dumps(
                {"info": as_json, "distributions": {k: d.summary() for k, d in dists.items()}},
                indent=1,
            )
        )
    else:
        print(format_report(info, dists))
    if args.plots:
        for path in save_histograms(dists, args.plots):
            print(f"wrote {path}")
    return 0
