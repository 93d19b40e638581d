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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``packlab inspect-data DIR``."""
    return int(importlib.import_module(RUN_MODULE).run(args))
