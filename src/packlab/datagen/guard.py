"""The one check that keeps bench cases out of training and tuning: by content, then by seed.

Every command or script that trains a model, labels states for one, or picks a default by a
score (``packlab train rl``, ``packlab train candidate``, ``packlab train sft`` on a PackData
directory, ``benchmarks/proposer_ceiling.py``, ``benchmarks/plan_sweep.py``,
``benchmarks/vlm_ablations.py``) passes its cases through :func:`require_training_cases`.

**Content** (:mod:`packlab.cases.known`): a case whose fingerprint (container and box
sizes in arrival order, each box's l/w sorted; :mod:`packlab.cases.fingerprint`) is that of a
bundled suite case or of the public reference's benchmark is refused, whatever its id, seed or
origin: renamed, reseeded, exported (JSONL or the reference layout) or with its sides named the
other way round, it is still that case. The known fingerprints ship with the package (read once
per process); the check is one sha256 and one set lookup per case (20 000 hard cases: 0.74 s,
``benchmarks/maintainers/guard_speed.py``).

**Seed**: the case's seed domain, a second line of defence for cases that are bench cases by
construction but were edited (e.g. one box changed):

Seed domains (``packlab.datagen.seeds``):

* ``train`` (what ``packlab generate`` and ``generate_cases(..., domain="train")`` write):
  accepted;
* ``bench`` (every registered suite): refused;
* ``manual`` (small seeds below 2**50: test fixtures, hand-made cases): accepted, so that
  tests and hand cases can drive a training loop, *except* a row read from a reference-layout
  file's ``test`` split, which is the public reference's own benchmark (its seeds, e.g.
  610000, are small): refused. A hand-made case must not be an evaluation case; the seed space
  cannot tell, so that rule rests on the person who made it;
* anything else (a seed no packlab domain produces, e.g. negative): refused.
"""

from __future__ import annotations

from collections.abc import Iterable

from packlab.cases import REFERENCE_SPLIT
from packlab.cases.fingerprint import case_fingerprint
from packlab.cases.known import INSTEAD, suite_match
from packlab.core.errors import ConfigError
from packlab.core.types import Case
from packlab.datagen.seeds import seed_domain

#: Seed domains whose cases may be trained or tuned on (see the module docstring).
TRAINING_DOMAINS = ("train", "manual")


def refusal(case: Case, source: str, use: str) -> str | None:
    """Why ``case`` may not be used for ``use`` ("training", "tuning"), or None if it may."""
    domain = seed_domain(case.seed)
    where = f"{source}: case {case.episode_id!r} (seed {case.seed})"
    match = suite_match(case_fingerprint(case))
    if domain == "bench":
        also = f" ({match})" if match else ""
        return f"{where} is in the bench seed domain, refused for {use}{also}; {INSTEAD}"
    if match is not None:
        return (
            f"{where} has the content of {match} (container and box sizes in arrival order), "
            f"refused for {use}; {INSTEAD}"
        )
    if domain not in TRAINING_DOMAINS:
        return f"{where} is in no packlab seed domain, refused for {use}; {INSTEAD}"
    if domain == "manual" and case.origin is not None and case.origin.split == REFERENCE_SPLIT:
        return (
            f"{where} is a reference benchmark row (split {REFERENCE_SPLIT!r}, hand-made seed), "
            f"refused for {use}; {INSTEAD}"
        )
    return None


def require_training_cases(cases: Iterable[Case], source: str, use: str = "training") -> list[Case]:
    """``cases`` as a list, or ``ConfigError`` naming the source, the first refused case's id
    and seed and what to do instead (one line). ``source`` is how the user named the cases (a
    suite, a path, a recipe)."""
    out = list(cases)
    for case in out:
        reason = refusal(case, source, use)
        if reason is not None:
            raise ConfigError(reason)
    return out


__all__ = ["INSTEAD", "TRAINING_DOMAINS", "refusal", "require_training_cases"]
