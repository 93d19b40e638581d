"""The content fingerprints of every evaluation case packlab knows: the training guard's list.

Two files shipped in the package, read once per process on first use (``functools.cache``),
both ``sha256 case`` lines (``#`` lines are comments):

* ``data/guard/bundled-suites.txt``: every case of every bundled suite, written by
  ``python scripts/guard_fingerprints.py`` from the suites themselves; a test checks the file
  against them, so a suite added or rebuilt without it fails the test command;
* ``data/guard/reference-packlab-bench.txt``: the public reference's PackLab-Bench, whose cases
  are not bundled (only a test fixture holds them).

Shipping the fingerprints rather than loading the suites keeps this module at the cases layer
(the trainers of ``vlm`` and ``rl`` use it, and they sit below the bench) and makes the first
check fast. A fingerprint is :func:`packlab.cases.fingerprint.case_fingerprint` (container and
box sizes in arrival order, side names sorted): names, ids, seeds and origins do not enter it.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cache
from importlib import resources
from pathlib import Path
from types import MappingProxyType

#: The reference benchmark's fingerprints, inside the installed package.
REFERENCE_FILE = ("data", "guard", "reference-packlab-bench.txt")
#: The bundled suites' fingerprints (``sha256 SUITE CASE-ID`` lines).
SUITES_FILE = ("data", "guard", "bundled-suites.txt")
#: How refusals name the reference benchmark.
REFERENCE_NAME = "reference PackLab-Bench"

#: What to do instead, appended to every refusal of a known case.
INSTEAD = (
    "train and tune on generated cases instead (packlab generate, or "
    "generate_cases(..., domain='train')); bench suites are for evaluation only"
)


def reference_file() -> Path:
    return Path(str(resources.files("packlab").joinpath(*REFERENCE_FILE)))


def suites_file() -> Path:
    return Path(str(resources.files("packlab").joinpath(*SUITES_FILE)))


def _lines(path: Path) -> list[list[str]]:
    text = path.read_text(encoding="utf-8")
    return [line.split() for line in text.splitlines() if line.strip() and line[0] != "#"]


def read_reference(path: Path) -> dict[str, str]:
    """fingerprint -> case id of a ``sha256 case-id`` file."""
    return {digest: case_id for digest, case_id in _lines(path)}


def read_suites(path: Path) -> dict[str, str]:
    """fingerprint -> "SUITE case 'ID'" of a ``sha256 suite case-id`` file."""
    return {digest: f"{suite} case {case_id!r}" for digest, suite, case_id in _lines(path)}


@cache
def known_cases() -> Mapping[str, str]:
    """fingerprint -> "SUITE case 'ID'" for every known evaluation case (read once)."""
    known = {d: f"{REFERENCE_NAME} case {i!r}" for d, i in read_reference(reference_file()).items()}
    known.update(read_suites(suites_file()))
    return MappingProxyType(known)


def suite_match(fingerprint: str) -> str | None:
    """Which known evaluation case has this fingerprint ("SUITE case 'ID'"), or None."""
    return known_cases().get(fingerprint)


__all__ = [
    "INSTEAD",
    "REFERENCE_NAME",
    "known_cases",
    "read_reference",
    "read_suites",
    "reference_file",
    "suite_match",
    "suites_file",
]
