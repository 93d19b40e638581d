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
COMMANDS = ("bench", "cases", "generate", "inspect_data", "train", "export", "serve", "viz")


from packlab.core.errors import EXIT_ABORTED, EXIT_INTERRUPTED, EXIT_USAGE, PacklabError, RunAborted


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="packlab", description=__doc__.splitlines()[0]
    )  # the first line
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
    """Run one subcommand; returns its exit code (packlab.core.errors.EXIT_*), never a traceback for
    bad input: a PacklabError or an OSError about a path (missing, a directory, not writable)
    is one line ``packlab <cmd>: error: ...`` and exit code 2; a stopped run (RunAborted) 3."""
    parser = build_parser()
    args = parser.parse_args(argv)  # argparse's own errors: usage + one line, exit code 2
    try:
        return int(args.func(args) or 0)
    except RunAborted as exc:
        print(f"packlab {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_ABORTED
    except PacklabError as exc:
        print(f"packlab {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as exc:
        if (
            exc.filename is None
        ):  # not about a path the user gave (e.g. a full disk): a real failure
            raise
        print(f"packlab {args.command}: error: {_os_error_line(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(
            f"packlab {args.command}: interrupted; rerun the same command to resume",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED


def _os_error_line(exc: OSError) -> str:
    """``'runs/x': Is a directory`` rather than ``[Errno 21] Is a directory: 'runs/x'``."""
    where = repr(str(exc.filename))
    if exc.filename2 is not None:
        where += f" -> {str(exc.filename2)!r}"
    return f"{where}: {exc.strerror or exc}"


if __name__ == "__main__":
    sys.exit(main())
