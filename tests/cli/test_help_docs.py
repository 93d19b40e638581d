"""Every docs/ page a help text names exists (``packlab export onnx --help`` once pointed to a
docs/onnx.md nobody had written)."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from packlab.cli.main import build_parser

ROOT = Path(__file__).resolve().parents[2]
DOCS_PATH = re.compile(r"docs/[\w./-]*\w")


def _texts(parser: argparse.ArgumentParser) -> list[str]:
    """The description and every option's help of ``parser`` and of its subcommands."""
    texts = [parser.description or ""]
    for action in parser._actions:
        texts.append(action.help or "")
        if isinstance(action, argparse._SubParsersAction):
            texts += [c.help or "" for c in action._choices_actions]
            for sub in dict(action.choices.items()).values():  # fills lazy parsers
                texts += _texts(sub)
    return texts


def test_every_docs_path_in_a_help_text_exists():
    named = {m for text in _texts(build_parser()) for m in DOCS_PATH.findall(text)}
    assert "docs/onnx.md" in named  # the walk reaches nested subcommands
    assert sorted(p for p in named if not (ROOT / p).exists()) == []
