"""``packlab inspect-data``: counts, distributions and rejection reasons of a dataset."""

from __future__ import annotations

import argparse
import importlib

#: What the command does (reading the dataset, histograms), imported when it runs.
RUN_MODULE = "packlab.cli.inspect_data_run"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", help="dataset directory (holds meta/info.json)")
    p.add_argument("--plots", metavar="DIR", help="also write PNG histograms into DIR")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument(
        "--tokenizer",
        metavar="CHECKPOINT_DIR",
        help="count the SFT export's tokens with this checkpoint's tokenizer and image "
        "processor; default: the project's own tokenizer, Qwen3.5 images (needs the vlm extra)",
    )
    p.add_argument(
        "--token-sample",
        type=int,
        default=200,
        metavar="N",
        help="conversations tokenized, a seeded sample of whole episodes (0: no token "
        "figures); default 200",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``packlab inspect-data DIR``."""
    return int(importlib.import_module(RUN_MODULE).run(args))
