"""pyproject.toml pins every dependency to a range the code is tested with.

An open upper bound lets a fresh install take a release nobody has run the tests on (transformers
was `>=5.0` while it announced removing an argument the VLM passed). Every requirement of the core
and of each extra needs a lower and an upper bound, and the installed release must be inside it,
so the test run itself is the evidence for the range.
"""

from __future__ import annotations

import tomllib
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pytest
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
REQUIREMENTS = [
    (group, Requirement(spec))
    for group, specs in [
        ("core", PROJECT["dependencies"]),
        *PROJECT["optional-dependencies"].items(),
    ]
    for spec in specs
]


@pytest.mark.parametrize(("group", "req"), REQUIREMENTS, ids=lambda x: str(x))
def test_bounded_on_both_sides(group, req):
    operators = {spec.operator for spec in req.specifier}
    assert operators & {">=", ">", "==", "~="}, f"{group}: {req} has no lower bound"
    assert operators & {"<", "<=", "==", "~="}, f"{group}: {req} has no upper bound"


@pytest.mark.parametrize(("group", "req"), REQUIREMENTS, ids=lambda x: str(x))
def test_installed_release_is_inside_the_range(group, req):
    try:
        installed = version(req.name)
    except PackageNotFoundError:
        pytest.skip(f"{req.name} is not installed (the {group} extra)")
    assert req.specifier.contains(installed, prereleases=True), (
        f"{group}: installed {req.name} {installed} is outside {req}"
    )
