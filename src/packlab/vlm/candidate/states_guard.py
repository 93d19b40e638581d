"""The training-data guard for labelled states: every row checked by its case's content.

A states file names its cases by id, and ids are names: a file collected on other cases (a
selection set, a stale run) with the same ids would pass an id check. So every row carries its
case's content fingerprint (``case_sha256``, format ``packlab-states-3``) and a trainer refuses:

* a row without one (a file written before the field existed): collect the states again on
  their cases (``packlab train candidate`` or ``scripts/collect_states.py`` write the field);
* a row whose case is a bundled suite's or the reference benchmark's
  (:mod:`packlab.cases.known`);
* with the cases given: a row whose case id is not among them, or whose fingerprint is not that
  of the case with its id (stale or mismatched states).

Torch-free: the CLI (``train rl-imitate``, ``train candidate``) and the scripts call it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

from packlab.cases.fingerprint import case_fingerprint
from packlab.cases.known import INSTEAD, suite_match
from packlab.core.errors import ConfigError
from packlab.core.types import Case
from packlab.vlm.candidate.states import LabelledState, read_states

#: What to do with a states file written without case hashes (appended to that refusal).
ADD_HASH_HINT = (
    "collect the states again on their cases (packlab train candidate, or python "
    "scripts/collect_states.py CASES OUT.jsonl SOURCE): every row it writes carries its hash"
)


def state_refusal(
    state: LabelledState, prints: dict[str, str] | None, where: str, use: str
) -> str | None:
    """Why this row may not be used for ``use``, or None. ``prints``: case id -> fingerprint
    of the cases the states are said to come from (None: not given)."""
    name = f"{where}: state of case {state.case_id!r} (step {state.step})"
    if not state.case_sha256:
        return (
            f"{name} has no case_sha256 ({state.format}, before packlab-states-3); {ADD_HASH_HINT}"
        )
    match = suite_match(state.case_sha256)
    if match is not None:
        return f"{name} is a state of {match} (by its case_sha256), refused for {use}; {INSTEAD}"
    if prints is None:
        return None
    if state.case_id not in prints:
        return f"{name}: the case is not among the given cases, refused for {use}"
    if prints[state.case_id] != state.case_sha256:
        return (
            f"{name}: case_sha256 {state.case_sha256[:12]}... is not that of the given case "
            f"{state.case_id!r} ({prints[state.case_id][:12]}...): stale or mismatched states, "
            f"refused for {use}; pass the cases they were collected on, or collect again"
        )
    return None


def case_prints(cases: Iterable[Case]) -> dict[str, str]:
    return {c.episode_id: case_fingerprint(c) for c in cases}


def _checked(path: Path, prints: dict[str, str] | None, use: str) -> list[LabelledState]:
    out = list(read_states(path))
    for state in out:
        reason = state_refusal(state, prints, str(path), use)
        if reason is not None:
            raise ConfigError(reason)
    return out


def checked_states(
    path: Path, cases: Sequence[Case] | None = None, use: str = "training"
) -> list[LabelledState]:
    """The states of one file, or ``ConfigError`` (one line) at the first refused row."""
    return _checked(path, case_prints(cases) if cases is not None else None, use)


def require_training_states(
    paths: Iterable[str | Path], cases: Sequence[Case] | None = None, use: str = "training"
) -> None:
    """Check every row of every file (files that do not exist yet are skipped: a run that
    collects them writes them with their hashes)."""
    prints = case_prints(cases) if cases is not None else None
    for p in paths:
        if Path(p).is_file():
            _checked(Path(p), prints, use)


__all__ = [
    "ADD_HASH_HINT",
    "case_prints",
    "checked_states",
    "require_training_states",
    "state_refusal",
]
