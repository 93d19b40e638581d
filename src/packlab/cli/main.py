"""packlab: simulate, generate data for, benchmark and train closed-loop bin-packing policies.

One subcommand per module in ``packlab.cli`` (:data:`COMMANDS`). Each module exposes
``add_arguments(parser)``, which fills the command's parser (description, options) and sets
``func`` (called with the parsed namespace, returning an exit code). A command's module is
imported only when the command is chosen, so ``packlab --help`` loads none of them; a module
keeps to argument definitions and imports the modules that do the work when ``func`` runs.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import sys
from typing import Any, cast

from packlab.cli.parser import PacklabParser
from packlab.core.errors import EXIT_ABORTED, EXIT_USAGE, PacklabError, RunAborted
from packlab.core.stop import (
    descendants,
    describe_stop,
    end_descendants,
    exit_code_of,
    stop_handlers,
)

#: The subcommands in help order: name -> (module in ``packlab.cli``, its line in ``--help``).
COMMANDS: dict[str, tuple[str, str]] = {
    "bench": ("bench", "run PackLab-Bench (or any case file) and print a Table-2-style table"),
    "policies": ("policies", "list the policies a bench can run, with their options and defaults"),
    "cases": ("cases", "validate case files, or export them to the reference layout or JSONL"),
    "generate": ("generate", "generate a PackData dataset"),
    "inspect-data": ("inspect_data", "summarise a PackData dataset directory"),
    "train": ("train", "train models (sft: supervised fine-tuning of the VLM)"),
    "export": ("export", "export SFT data for trainers, or a learned policy to ONNX"),
    "serve": ("serve", "serve a packing VLM over an OpenAI-compatible API (test server, vLLM)"),
    "cell": ("cell", "serve packlab to a robot cell: depth images in, a placement out"),
    "viz": ("viz", "draw recorded episodes, or view them in Rerun"),
}


class _CommandParsers(dict[str, argparse.ArgumentParser]):
    """Command name -> parser, the parser filled by its module the first time it is looked up.

    argparse looks up only the chosen command (the command list in ``--help`` and the check of
    a name read names and help lines), so ``packlab bench ...`` imports bench's module alone;
    ``items()`` and ``values()`` fill every parser (tests walk the whole tree).
    """

    def __init__(self) -> None:
        super().__init__()
        self.pending: dict[str, str] = {}  # command -> module that has not filled it yet

    def __getitem__(self, name: str) -> argparse.ArgumentParser:
        parser = super().__getitem__(name)
        if name in self.pending:
            importlib.import_module(self.pending[name]).add_arguments(parser)
            del self.pending[name]
        return parser

    def get(self, name: str, default: Any = None) -> Any:  # type: ignore[override]
        try:
            return self[name]
        except KeyError:
            return default

    def values(self) -> list[argparse.ArgumentParser]:  # type: ignore[override]
        return [self[name] for name in self]

    def items(self) -> list[tuple[str, argparse.ArgumentParser]]:  # type: ignore[override]
        return [(name, self[name]) for name in self]


class _LazySubParsers(argparse._SubParsersAction):
    """``add_subparsers`` whose parsers get their options when chosen (:class:`_CommandParsers`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.commands = _CommandParsers()
        self._name_parser_map = self.choices = self.commands

    def add_command(self, name: str, module: str, help: str) -> None:
        self.add_parser(name, help=help)
        self.commands.pending[name] = module


def build_parser() -> argparse.ArgumentParser:
    """The ``packlab`` parser; a command's options are added when it is parsed (or looked up)."""
    parser = PacklabParser(prog="packlab", description=__doc__.splitlines()[0])
    sub = cast(
        _LazySubParsers,
        parser.add_subparsers(dest="command", required=True, action=_LazySubParsers),
    )
    for name, (module, help) in COMMANDS.items():
        module_name = f"packlab.cli.{module}"
        if importlib.util.find_spec(module_name) is None:  # a command not built yet
            continue
        sub.add_command(name, module_name, help)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand; returns its exit code (packlab.core.errors.EXIT_*), never a traceback for
    bad input: a PacklabError or an OSError about a path (missing, a directory, not writable)
    is one line ``packlab <cmd>: error: ...`` and exit code 2; a stopped run (RunAborted) 3."""
    parser = build_parser()
    args = parser.parse_args(argv)  # argparse's own errors: one line, exit code 2 (cli.parser)
    before = set(descendants(os.getpid()))  # a caller's own processes, never ours to end
    try:
        # SIGTERM too (a scheduler's stop): the command's cleanup runs as for Ctrl-C (core.stop).
        with stop_handlers():
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
    except KeyboardInterrupt as exc:
        end_descendants(keep=before)  # what the command's own cleanup did not reach
        how = describe_stop(exc)
        print(
            f"packlab {args.command}: {how}; rerun the same command to resume",
            file=sys.stderr,
        )
        return exit_code_of(exc)  # EXIT_INTERRUPTED for SIGINT, EXIT_TERMINATED for SIGTERM


def _os_error_line(exc: OSError) -> str:
    """``'runs/x': Is a directory`` rather than ``[Errno 21] Is a directory: 'runs/x'``."""
    where = repr(str(exc.filename))
    if exc.filename2 is not None:
        where += f" -> {str(exc.filename2)!r}"
    return f"{where}: {exc.strerror or exc}"


if __name__ == "__main__":
    sys.exit(main())
