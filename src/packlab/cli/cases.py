"""``packlab cases``: check a case source, or convert it between packlab's JSONL and the
reference layout."""

from __future__ import annotations

import argparse
import importlib

#: What the commands do (loading, checking and writing cases), imported when one runs.
RUN_MODULE = "packlab.cli.cases_run"

#: Export formats: packlab's own JSONL, or the reference's benchmark layout.
EXPORT_FORMATS = ("reference", "jsonl")

_SOURCE_HELP = (
    "a bundled suite name, a case file (JSON, JSONL, parquet) or a reference benchmark directory "
    "(<dir>/<difficulty>/test.parquet)"
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = "Check a case source, or write its cases in another layout."
    sub = p.add_subparsers(dest="cases_command", required=True, metavar="{validate,export}")
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


def run_validate(args: argparse.Namespace) -> int:
    """``packlab cases validate SRC``."""
    return int(importlib.import_module(RUN_MODULE).run_validate(args))


def run_export(args: argparse.Namespace) -> int:
    """``packlab cases export SRC --format F --out OUT``."""
    return int(importlib.import_module(RUN_MODULE).run_export(args))
