"""``packlab cases``: check a case source, or convert it between packlab's JSONL and the
reference layout."""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from packlab.bench.suites import resolve_cases
from packlab.cases import save_cases, write_reference
from packlab.core.errors import ConfigError

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
    source = resolve_cases(args.src)
    cases = source.cases
    levels = Counter(c.difficulty or "(none)" for c in cases)
    objects = [len(c.objects) for c in cases]
    id_types = sorted({type(c.objects[0].internal_id).__name__ for c in cases})
    print(
        f"{source.origin}: {len(cases)} cases OK "
        f"({', '.join(f'{lvl} {n}' for lvl, n in levels.items())}); "
        f"objects {min(objects)}-{max(objects)}, {sum(objects)} in all; "
        f"gt_plan in {sum(c.gt_plan is not None for c in cases)}; "
        f"internal_id {'/'.join(id_types)}; "
        f"sha256 {source.sha256}"
    )
    return 0


def run_export(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if (
        out.exists() or out.is_symlink()
    ):  # checked before loading: no work wasted on a refused target
        raise ConfigError(f"--out {out}: already exists; remove it or choose another path")
    source = resolve_cases(args.src)
    if args.format == "reference":
        written = write_reference(source.cases, out)
    else:
        written = [save_cases(source.cases, out)]
    for path in written:
        print(f"wrote {path}", file=sys.stderr)
    print(
        f"{len(source.cases)} cases from {source.origin} -> {out} ({args.format}); "
        f"sha256 {source.sha256}"
    )
    return 0
