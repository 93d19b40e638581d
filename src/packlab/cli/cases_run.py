"""What ``packlab cases validate``, ``cases export`` and ``cases fresh`` do
(:mod:`packlab.cli.cases` defines their flags and imports this module when one runs)."""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from packlab.bench.suites import build_suite, fresh_spec, resolve_cases
from packlab.cases import cases_sha256, save_cases, write_reference
from packlab.cli.options import config_kwargs
from packlab.core.errors import ConfigError
from packlab.datagen.config import ValidationConfig


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


def _new_out(path: str) -> Path:
    """``--out`` as a path that does not exist yet; checked before any loading or generating,
    so no work is wasted on a refused target and nothing already there is overwritten."""
    out = Path(path)
    if out.exists() or out.is_symlink():
        raise ConfigError(f"--out {out}: already exists; remove it or choose another path")
    return out


def run_export(args: argparse.Namespace) -> int:
    out = _new_out(args.out)
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


def run_fresh(args: argparse.Namespace) -> int:
    out = _new_out(args.out)
    spec = fresh_spec(args.suite, args.seed, args.per_level, sizes=args.sizes)
    # Progress per level on stderr; the file is written once every level is made, so a crash
    # leaves no partial file to mistake for a set (a rerun regenerates the same cases).
    validation = ValidationConfig(**config_kwargs(args, "cases fresh", ValidationConfig))
    cases = build_suite(spec, progress=True, validation=validation)
    save_cases(cases, out)
    levels = ", ".join(f"{d} {n}" for d, n in spec.counts)
    print(
        f"{len(cases)} cases made like {args.suite} (user seed {args.seed}, training domain; "
        f"{levels}{'; boxes off the grid' if spec.sizes == 'off-grid' else ''}; validated on "
        f"{validation.backend}) -> {out}; sha256 {cases_sha256(cases)}"
    )
    return 0
