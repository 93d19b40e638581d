"""The command-line reference as Markdown, read from the parsers themselves.

The docs site's "Command line" page is this text (``docs/hooks/cli_reference.py`` puts it in at
build time), so the reference cannot drift from the flags: a new option is in the next build.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterator

from packlab.cli.main import build_parser

#: Help is wrapped at this width whatever the terminal of whoever builds the docs.
HELP_COLUMNS = 100


def _subcommands(parser: argparse.ArgumentParser) -> Iterator[tuple[str, argparse.ArgumentParser]]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            yield from action.choices.items()


def _walk(
    parser: argparse.ArgumentParser, path: tuple[str, ...]
) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    yield path, parser
    for name, child in _subcommands(parser):
        yield from _walk(child, (*path, name))


def cli_reference_markdown() -> str:
    """Every command and subcommand: a heading and its ``--help`` text."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(HELP_COLUMNS)
    try:
        parts = []
        for path, parser in _walk(build_parser(), ("packlab",)):
            level = "#" * min(len(path) + 1, 4)
            parts.append(
                f"{level} `{' '.join(path)}`\n\n```text\n{parser.format_help().rstrip()}\n```\n"
            )
        return "\n".join(parts)
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


__all__ = ["HELP_COLUMNS", "cli_reference_markdown"]
