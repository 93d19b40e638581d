"""``packlab cases``: check a case source, convert it between packlab's JSONL and the
reference layout, or generate a fresh set made like a bundled suite."""

from __future__ import annotations

import argparse
import importlib

from packlab.cli.options import add_field
from packlab.datagen.config import CaseConfig, ValidationConfig

#: What the commands do (loading, checking and writing cases), imported when one runs.
RUN_MODULE = "packlab.cli.cases_run"

#: Export formats: packlab's own JSONL, or the reference's benchmark layout.
EXPORT_FORMATS = ("reference", "jsonl")

_SOURCE_HELP = (
    "a bundled suite name, a case file (JSON, JSONL, parquet) or a reference benchmark directory "
    "(<dir>/<difficulty>/test.parquet)"
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Check a case source, write its cases in another layout, or make a fresh set like a suite."
    )
    sub = p.add_subparsers(dest="cases_command", required=True, metavar="{validate,export,fresh}")
    v = sub.add_parser(
        "validate",
        help="load every case (all checks and limits) and print counts",
        description="Load every case with all checks and limits applied and print counts "
        "per difficulty and the cases' checksum; exit 2 on the first bad case.",
    )
    v.add_argument("src", help=_SOURCE_HELP)
    v.set_defaults(func=run_validate)
    e = sub.add_parser(
        "export",
        help="write the cases in the reference layout or as packlab JSONL",
        description="Write the cases of SRC to OUT. --format reference: OUT ending in .parquet is "
        "one parquet file, .jsonl the same rows as JSON lines, anything else a "
        "reference benchmark directory (OUT/<difficulty>/test.parquet and "
        "OUT/metadata/manifest.json). --format jsonl: packlab's own JSONL. "
        "OUT must not exist.",
    )
    e.add_argument("src", help=_SOURCE_HELP)
    e.add_argument("--format", choices=EXPORT_FORMATS, required=True, help="layout to write")
    e.add_argument("--out", required=True, help="file or directory to create")
    e.set_defaults(func=run_export)
    f = sub.add_parser(
        "fresh",
        help="generate a fresh case set made like a bundled suite, from a training-domain seed",
        description="Generate cases made like SUITE (its layout family, arrival order and cases "
        "per level) from user seed --seed of the training seed domain, replay-validated like the "
        "suite, and write them to OUT as packlab JSONL: a set the suite never held, to check "
        "that a figure measured on the suite holds beyond its 60 cases. The same seed gives the "
        "same file. OUT must not exist.",
    )
    f.add_argument("suite", help="a bundled suite name, e.g. packlab-bench-v1")
    f.add_argument("--seed", type=int, required=True, help="user seed (training seed space)")
    f.add_argument("--out", required=True, help="JSONL file to create")
    f.add_argument(
        "--per-level",
        type=int,
        default=None,
        help="cases per difficulty; default: as many as the suite has",
    )
    add_field(
        f,
        CaseConfig,
        "sizes",
        "--sizes",
        help="grid: boxes fill the suite's layouts exactly (sides on the 2.5 cm grid); off-grid: "
        "cartons, each box 2-12 mm smaller across and 0-4 mm lower than its slot of the same "
        "layout (sides off the grid; the plan leaves the clearance empty); default {default}",
    )
    add_field(
        f,
        ValidationConfig,
        "backend",
        "--validation",
        help="replay backend that validates each case (the suites used mujoco); default {default}",
    )
    f.set_defaults(func=run_fresh)


def run_validate(args: argparse.Namespace) -> int:
    """``packlab cases validate SRC``."""
    return int(importlib.import_module(RUN_MODULE).run_validate(args))


def run_export(args: argparse.Namespace) -> int:
    """``packlab cases export SRC --format F --out OUT``."""
    return int(importlib.import_module(RUN_MODULE).run_export(args))


def run_fresh(args: argparse.Namespace) -> int:
    """``packlab cases fresh SUITE --seed N --out OUT``."""
    return int(importlib.import_module(RUN_MODULE).run_fresh(args))
