"""``packlab policies``: every policy a bench can run, with its options and their defaults."""

from __future__ import annotations

import argparse
import importlib

#: What the command does (the registry, each policy's factory), imported when it runs: the
#: flags alone load no policy family, so ``packlab policies --help`` stays instant.
RUN_MODULE = "packlab.cli.policies_run"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = (
        "List every policy that packlab bench --policies can run: the built-ins and those "
        "that installed packages declare in the packlab.policies entry-point group. Each comes "
        "with a line on what it does, its options (--policy-arg NAME:KEY=VALUE) with their "
        "defaults, and what it needs installed. Writing your own: docs/own-policy.md."
    )
    p.add_argument(
        "name",
        nargs="?",
        metavar="NAME",
        help="describe this policy alone, one option a line (default: list them all)",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print JSON (format packlab-policies-1) instead of text",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``packlab policies [NAME] [--json]``."""
    return int(importlib.import_module(RUN_MODULE).run(args))
