"""The seed space: how (user seed, domain, difficulty, slot, attempt) becomes a case seed.

A case is a pure function of ``(case seed, difficulty, CaseConfig)``; the case seed is the only
randomness it sees. Case seeds are split into disjoint *domains* so that no training episode can
ever be a bench case, whatever user seeds the two sides pick:

    case_seed = domain_tag * 2**50 + (50-bit hash of SeedSequence(user_seed, spawn_key))

with ``spawn_key = (domain_tag, difficulty_tag, slot, attempt)``. Domain tags: 0 is left to
hand-made cases (small seeds such as test fixtures), 1 is the bench (``generate_cases``'
default), 2 is training data (``packlab generate``). Bench seeds therefore lie in
[2**50, 2**51), training seeds in [2**51, 3 * 2**50): disjoint by construction, not by luck.
Seeds stay below 2**53 so they survive any JSON reader as exact integers. Within a domain, two
slots share a seed with probability about n**2 / 2**51 (2e-7 for 20 000 cases).
"""

from __future__ import annotations

import numpy as np

from packlab.core.errors import ConfigError

#: Domain tags of the seed space (see the module docstring).
DOMAINS: dict[str, int] = {"manual": 0, "bench": 1, "train": 2}
#: Stable per-difficulty tags: the spawn key must not depend on dict order or spelling changes.
DIFFICULTY_TAGS: dict[str, int] = {"easy": 1, "medium": 2, "hard": 3}

_HASH_BITS = 50


def domain_tag(domain: str) -> int:
    try:
        return DOMAINS[domain]
    except KeyError:
        raise ConfigError(
            f"seed domain = {domain!r}: unknown; choose from {', '.join(DOMAINS)}"
        ) from None


def id_prefix(domain: str, user_seed: int) -> str:
    """The episode id prefix of generated cases: ``{domain}-s{user_seed}-`` (e.g.
    ``train-s4402-easy-00000``), so that two user seeds never share an id and states matched to
    cases by id cannot mix sets. The bench domain keeps ``bench-``: its cases are the frozen
    suite files, whose ids are part of published records (``scripts/make_bench_suite.py
    --check`` rebuilds them byte for byte)."""
    domain_tag(domain)
    return "bench-" if domain == "bench" else f"{domain}-s{int(user_seed)}-"


def case_seed(user_seed: int, domain: str, difficulty: str, slot: int, attempt: int = 0) -> int:
    """The case seed of one dataset or suite slot (``attempt`` > 0 after rejected tries)."""
    if user_seed < 0:
        raise ConfigError(f"seed = {user_seed}: must not be negative")
    tag = domain_tag(domain)
    key = (tag, DIFFICULTY_TAGS.get(difficulty, 0), int(slot), int(attempt))
    state = np.random.SeedSequence(int(user_seed), spawn_key=key).generate_state(2, np.uint32)
    digest = (int(state[0]) << 32 | int(state[1])) & ((1 << _HASH_BITS) - 1)
    return (tag << _HASH_BITS) | digest


def seed_domain(seed: int) -> str:
    """Which domain a case seed belongs to (inverse of the tag in ``case_seed``)."""
    tag = int(seed) >> _HASH_BITS
    for name, value in DOMAINS.items():
        if value == tag:
            return name
    return "unknown"


def case_streams(seed: int, n: int) -> list[np.random.Generator]:
    """``n`` independent generators for the stages of building one case.

    Separate streams per stage (scenario, layout, presentation, order) mean that changing one
    stage's settings, e.g. the anchor, leaves the draws of the others, e.g. the layout, alone.
    """
    return [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(n)]
