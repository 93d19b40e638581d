"""packlab: simulate, generate data for, benchmark and train closed-loop bin-packing policies.

One subcommand per module in ``packlab.cli``.
Each subcommand module exposes ``register(subparsers)``, which adds its parser and sets
``func`` (called with the parsed namespace, returning an exit code).
"""

from __future__ import annotations

import argparse
import importlib
import sys

#: Subcommand modules, in help order.
COMMANDS = ("bench", "generate", "inspect_data", "train", "serve", "viz")


from packlab.errors import PacklabError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="packlab", description=__doc__.splitlines()[0])  # the first line
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        module_name = f"packlab.cli.{name}"
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:  # a command not built yet; anything else is a bug
            if exc.name == module_name:
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (PacklabError, FileNotFoundError, NotADirectoryError, PermissionError) as exc:
        print(f"packlab {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"packlab {args.command}: interrupted; rerun the same command to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
