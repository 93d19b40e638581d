"""The argument parser every ``packlab`` command uses: argparse with one-line errors and a
nearest-name hint.

argparse (3.11) answers a bad flag with its usage block and then the error, and a misspelt
choice (``packlab bnech``, ``--backend mujco``) with the whole list but no suggestion. A user
reads the last line first, so the error is that one line, naming the closest choice when there
is one and pointing to ``--help`` for the rest. Subparsers inherit the class (argparse builds
them with ``type(parent)``), so every command and subcommand behaves the same.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any, NoReturn

from packlab.core.choices import did_you_mean
from packlab.core.errors import EXIT_USAGE


class PacklabParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose errors are one line on stderr, exit code 2."""

    def _check_value(self, action: argparse.Action, value: Any) -> None:
        choices = action.choices
        if choices is not None and value not in choices:
            names = list(choices)  # a subcommand map lists its names
            raise argparse.ArgumentError(
                action,
                f"invalid choice: {value!r}{did_you_mean(value, names)}; "
                f"choose from {', '.join(map(str, names))}",
            )

    def error(self, message: str) -> NoReturn:
        # One line: the usage block before it would push the reason off a short terminal.
        print(f"{self.prog}: error: {message} (see {self.prog} --help)", file=sys.stderr)
        sys.exit(EXIT_USAGE)


__all__ = ["PacklabParser", "did_you_mean"]
