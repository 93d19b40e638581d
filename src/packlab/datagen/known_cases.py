"""The content fingerprints of every evaluation case packlab knows: the training guard's list.

Two sources, read once per process on first use (``functools.cache``):

* every registered bundled suite (:data:`packlab.bench.suites.SUITES`), loaded through
  ``load_suite`` so its checksum is verified first;
* the public reference's PackLab-Bench. Its cases are not bundled (only a test fixture holds
  them), so the package ships their fingerprints alone: ``data/guard/reference-packlab-bench.txt``
  (``sha256 case-id`` lines).

A fingerprint is :func:`packlab.cases.fingerprint.case_fingerprint` (container and box sizes in
arrival order, side names sorted): names, ids, seeds and origins do not enter it.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cache
from importlib import resources
from pathlib import Path
from types import MappingProxyType

from packlab.cases.fingerprint import case_fingerprint

#: The reference benchmark's fingerprints, inside the installed package.
REFERENCE_FILE = ("data", "guard", "reference-packlab-bench.txt")
#: How refusals name the reference benchmark.
REFERENCE_NAME = "reference PackLab-Bench"


def reference_file() -> Path:
    return Path(str(resources.files("packlab").joinpath(*REFERENCE_FILE)))


def read_reference(path: Path) -> dict[str, str]:
    """fingerprint -> case id of a ``sha256 case-id`` file (``#`` lines are comments)."""
    out: dict[str, str] = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.strip() and not line.startswith("#"):
            digest, case_id = line.split(maxsplit=1)
            out[digest] = case_id
    return out


@cache
def known_cases() -> Mapping[str, str]:
    """fingerprint -> "SUITE case 'ID'" for every known evaluation case (read once)."""
    # Imported here: bench.suites imports datagen, which must stay importable without it.
    from packlab.bench.suites import SUITES, load_suite

    known = {d: f"{REFERENCE_NAME} case {i!r}" for d, i in read_reference(reference_file()).items()}
    for name in SUITES:
        for case in load_suite(name):
            known[case_fingerprint(case)] = f"{name} case {case.episode_id!r}"
    return MappingProxyType(known)


@cache
def known_fingerprints() -> frozenset[str]:
    """The fingerprints alone (for a membership test where the name is not needed)."""
    return frozenset(known_cases())


def suite_match(fingerprint: str) -> str | None:
    """Which known evaluation case has this fingerprint ("SUITE case 'ID'"), or None."""
    return known_cases().get(fingerprint)


__all__ = [
    "REFERENCE_NAME",
    "known_cases",
    "known_fingerprints",
    "read_reference",
    "reference_file",
    "suite_match",
]
