"""A case's content fingerprint: what the case *is*, whatever it is called.

The training guard (:mod:`packlab.datagen.guard`) and the labelled states
(:mod:`packlab.vlm.candidate.states`) identify a case by this digest, not by its id, seed or
origin, because those are names: a suite case renamed, reseeded, exported through ``packlab
cases export`` (JSONL or the reference's parquet layout) and read back, or with each box's
sides named the other way round (``--sides`` catalogue vs longer first) is the same packing
problem and must give the same fingerprint.

The digest covers the container's size and every box's size in arrival order; each (l, w) pair
is sorted (the side names carry no content) and h is kept (it is the up axis). Left out: ids,
seed, difficulty, buffer size, object ids and type ids, the plan and the origin.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable

from packlab.core.types import Case

#: Bumped if the canonical text below ever changes (recorded beside digests in cards).
FINGERPRINT_VERSION = 1


def _footprint(size: tuple[int, int, int]) -> str:
    l, w, h = size
    return f"{min(l, w)},{max(l, w)},{h}"


def case_fingerprint(case: Case) -> str:
    """The sha256 hex digest of the case's content (see the module docstring)."""
    boxes = ";".join(_footprint(b.size_mm) for b in case.objects)
    text = f"v{FINGERPRINT_VERSION}|{_footprint(case.container.size_mm)}|{boxes}"
    return hashlib.sha256(text.encode("ascii")).hexdigest()


def set_fingerprint(fingerprints: Iterable[str]) -> str:
    """One digest for a set of cases, independent of their order and names (the sorted
    fingerprints, one a line): what a model card records for its selection set."""
    text = "\n".join(sorted(fingerprints))
    return hashlib.sha256(text.encode("ascii")).hexdigest()


__all__ = ["FINGERPRINT_VERSION", "case_fingerprint", "set_fingerprint"]
