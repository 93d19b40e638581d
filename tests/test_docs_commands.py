"""Every command the README and the getting-started page show works.

Each ``packlab ...`` line of their bash blocks is parsed by packlab's own parser (so every
subcommand and flag exists), the cheap ones also run, scripts named exist and answer ``--help``,
and the Python blocks run as written.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from packlab.cli.main import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
#: Every page a user reads for how to run something (history pages record past commands).
PAGES = (
    "README.md",
    "CONTRIBUTING.md",
    *sorted(
        str(p.relative_to(ROOT))
        for folder in ("docs", "examples", "benchmarks")
        for p in (ROOT / folder).rglob("*.md")
        if "history" not in p.parts and p.parent.name not in ("learned", "rl", "vlm", "vlm-small")
    ),
)
#: Pages whose Python blocks run as written (the others show fragments).
RUNNABLE_PYTHON = ("README.md", "docs/getting-started.md")

#: Programs other than packlab that the pages show (system packages, linters, viewers).
OTHER_TOOLS = ("apt-get", "mypy", "ruff", "rerun", "git", "cd", "export", "vllm", "curl")

#: Commands that finish in seconds: they run in full, not only parse.
RUN_IN_FULL = (
    "packlab policies",
    "packlab bench --describe",
)


def blocks(page: str, language: str) -> list[str]:
    text = (ROOT / page).read_text(encoding="utf-8")
    return re.findall(rf"^```{language}\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL)


def command_lines(page: str) -> list[str]:
    """Shell lines of a page's bash blocks: continuation lines joined, comments dropped, and a
    block's ``NAME="..."`` variables put in where ``$NAME`` is used."""
    lines = []
    for block in blocks(page, "bash"):
        joined = re.sub(r"\\\n\s*", " ", block)
        variables: dict[str, str] = {}
        for line in joined.splitlines():
            line = line.split(" #", 1)[0].strip()
            assignment = re.fullmatch(r"([A-Z_][A-Z0-9_]*)=(.*)", line)
            if assignment:
                variables[assignment.group(1)] = " ".join(shlex.split(assignment.group(2)))
                continue
            for name, value in variables.items():
                line = line.replace(f"${name}", value)
            if line and not line.startswith("#"):
                lines.extend(part.strip() for part in line.split("&&"))
    return lines


def all_commands() -> list[tuple[str, str]]:
    return [(page, line) for page in PAGES for line in command_lines(page)]


def test_the_pages_show_commands():
    commands = [c for _, c in all_commands()]
    assert sum(c.startswith("packlab ") for c in commands) >= 10, commands


@pytest.mark.parametrize(("page", "line"), all_commands(), ids=lambda v: str(v)[:60])
def test_each_shown_command_parses_or_exists(page, line):
    words = shlex.split(line)
    while words and re.fullmatch(r"[A-Z_][A-Z0-9_]*=\S*", words[0]):  # ENV=value command ...
        words = words[1:]
    if words[0] in ("accelerate", "torchrun") and "packlab.cli.main" in words:
        # A launcher running packlab: its config file exists and packlab's part parses.
        if "--config_file" in words:
            config = words[words.index("--config_file") + 1]
            assert (ROOT / config).is_file(), f"{page}: `{line}` names a missing config"
        words = ["packlab", *words[words.index("packlab.cli.main") + 1 :]]
    if words[0] == "packlab":
        parser = build_parser()
        try:
            parser.parse_args(words[1:])
        except SystemExit as exc:  # a bad flag or subcommand exits 2 with one line
            pytest.fail(f"{page}: `{line}` does not parse (exit {exc.code})")
    elif words[0] in OTHER_TOOLS:
        pass  # another program's command line: packlab cannot check its flags
    elif words[:2] == ["python", "-m"] or words[0] in ("pip", "mkdocs"):
        if words[0] == "pip" and "-e" in words:
            target = words[words.index("-e") + 1].split("[")[0].strip("\"'")
            assert (ROOT / target).exists(), f"{page}: `{line}` installs a missing path"
    elif words[0] == "python" and words[1].endswith(".py"):
        script = ROOT / words[1]
        assert script.is_file(), f"{page}: `{line}` names a missing script"
        done = subprocess.run(
            [sys.executable, str(script), "--help"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=False,
        )
        assert done.returncode == 0, f"{page}: `{words[1]} --help` failed: {done.stderr[-500:]}"
    elif words[0] == "bash":
        assert (ROOT / words[1]).is_file(), f"{page}: `{line}` names a missing script"
    else:
        pytest.fail(f"{page}: `{line}`: no rule to check this command")


@pytest.mark.parametrize("line", RUN_IN_FULL)
def test_cheap_commands_run(line, capsys):
    shown = [c for _, c in all_commands()]
    assert any(c.startswith(line) for c in shown), f"{line} is no longer shown; drop it here"
    assert main(shlex.split(line)[1:]) == 0
    assert capsys.readouterr().out.strip()


@pytest.mark.physics
@pytest.mark.parametrize("page", RUNNABLE_PYTHON)
def test_python_blocks_run(page, tmp_path):
    for code in blocks(page, "python"):
        done = subprocess.run(
            [sys.executable, "-c", code],
            check=False,
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=300,
            env={**os.environ, "PYTHONHASHSEED": "0"},
        )
        assert done.returncode == 0, f"{page}:\n{code}\n{done.stderr[-2000:]}"
