"""README's test command, as .ci/run reads it, installs torch's CPU wheel.

An unqualified ``pip install torch==X`` on Linux takes PyPI's CUDA build (gigabytes); the command
must name PyTorch's CPU index, keep pip's retries short (CI machines may not reach that index and
serve a local wheel instead), and pin a torch that the extras' ranges in pyproject.toml admit.
"""

from __future__ import annotations

import re
import subprocess
import tomllib
from pathlib import Path

from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
CPU_INDEX = "https://download.pytorch.org/whl/cpu"


def ci_test_command() -> str:
    """The test command exactly as .ci/run extracts it from README.md (its own shell line)."""
    script = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    extract = re.search(r"^test_command=\$\((.+)\)$", script, re.MULTILINE)
    assert extract, ".ci/run no longer sets test_command=$(...)"
    done = subprocess.run(
        ["bash", "-c", extract.group(1)], cwd=ROOT, capture_output=True, text=True, check=True
    )
    return done.stdout.strip()


def test_the_ci_command_installs_the_cpu_wheel_first():
    command = ci_test_command()
    torch_install, *rest = command.split(" && ")
    assert re.search(rf"--(extra-)?index-url {re.escape(CPU_INDEX)}\b", torch_install)
    assert re.search(r"--retries [01]\b", torch_install)
    assert rest and "pytest" in rest[-1]


def test_the_pinned_torch_is_inside_the_extras_ranges():
    pin = re.search(r"\btorch==(\S+)", ci_test_command())
    assert pin, "the README's test command pins no torch"
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"][
        "optional-dependencies"
    ]
    ranges = [
        Requirement(spec).specifier
        for name in ("vlm", "rl")
        for spec in extras[name]
        if Requirement(spec).name == "torch"
    ]
    assert len(ranges) == 2
    assert all(pin.group(1) in spec for spec in ranges), (pin.group(1), ranges)
