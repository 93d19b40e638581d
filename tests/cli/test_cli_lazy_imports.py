"""``packlab --help`` and ``packlab bench --help`` import no heavy module (issue: CLI startup).

Building the top-level parser imports no subcommand's module; a subcommand's parser is built
from light modules (argument definitions), and the modules that do the work are imported when
the command runs. Each check runs in a fresh interpreter and reads ``sys.modules``; nothing is
timed here (``benchmarks/maintainers/cli_startup.py`` times it).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

#: Modules (and their submodules) that a help text must not import: engines, plotting, data
#: formats, model runtimes, and packlab's own physics and bench runner.
HEAVY = (
    "mujoco",
    "matplotlib",
    "scipy",
    "pyarrow",
    "plotly",
    "onnxruntime",
    "torch",
    "packlab.sim.physics",
    "packlab.bench.runner",
)

_PROBE = """
import contextlib, io, json, sys
from packlab.cli.main import build_parser, main
argv = json.loads(sys.argv[1])
if argv is None:
    build_parser()
else:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
        main(argv)
print(json.dumps(sorted(sys.modules)))
"""


def _modules_after(argv: list[str] | None) -> set[str]:
    """The modules loaded by a fresh interpreter that builds the parser (``argv`` None) or runs
    ``packlab ARGV``."""
    done = subprocess.run(
        [sys.executable, "-c", _PROBE, json.dumps(argv)],
        capture_output=True,
        text=True,
        check=True,
    )
    return set(json.loads(done.stdout.splitlines()[-1]))


def _heavy(modules: set[str]) -> list[str]:
    return sorted(m for m in modules if any(m == h or m.startswith(h + ".") for h in HEAVY))


@pytest.mark.parametrize(
    "argv",
    [None, ["--help"], ["bench", "--help"], ["bench", "report", "--help"]],
    ids=["build_parser", "help", "bench-help", "bench-report-help"],
)
def test_help_imports_no_heavy_module(argv):
    assert _heavy(_modules_after(argv)) == []


#: Commands whose flags need nothing heavy either (``train``'s configs load the planner, scipy).
LIGHT_COMMANDS = ("cases", "generate", "inspect-data", "export", "serve", "viz")


@pytest.mark.parametrize("command", LIGHT_COMMANDS)
def test_command_help_imports_no_heavy_module(command):
    assert _heavy(_modules_after([command, "--help"])) == []


def test_top_level_help_imports_no_subcommand_module():
    loaded = _modules_after(["--help"])
    parser = ("packlab.cli.main", "packlab.cli.parser")  # the top-level parser and its class
    commands = [m for m in loaded if m.startswith("packlab.cli.") and m not in parser]
    assert commands == []
    assert "numpy" not in loaded


def test_bench_help_imports_no_numpy():
    assert "numpy" not in _modules_after(["bench", "--help"])
