"""Give a labelled-states file written before ``packlab-states-3`` its rows' case hashes.

Usage:
    python scripts/states_add_case_hash.py --states OLD.jsonl --cases CASES [CASES ...] \
        --out NEW.jsonl

``CASES``: the case files (or recipes' outputs) the states were collected on; they must pass
the training guard. Each row gets the content fingerprint of the case with its id; a row whose
case id is in none of them, or that already carries another fingerprint, stops the script (the
states are not of these cases). The trainers refuse rows without the field
(:mod:`packlab.vlm.candidate.states_guard`), so this is how an old file becomes usable again.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import msgspec

from packlab.cases import load_cases
from packlab.core.errors import ConfigError
from packlab.datagen.guard import require_training_cases
from packlab.vlm.candidate.states import STATES_FORMAT, append_states, read_states
from packlab.vlm.candidate.states_guard import case_prints, require_training_states


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--states", required=True, type=Path)
    p.add_argument("--cases", nargs="+", required=True)
    p.add_argument("--out", required=True, type=Path)
    a = p.parse_args()
    if a.out.exists():
        raise SystemExit(f"{a.out}: exists; choose a new file")
    cases = [c for f in a.cases for c in require_training_cases(load_cases(f), f)]
    prints = case_prints(cases)
    rows = []
    for s in read_states(a.states):
        digest = prints.get(s.case_id)
        if digest is None:
            raise ConfigError(f"{a.states}: case {s.case_id!r} is in none of {a.cases}")
        if s.case_sha256 and s.case_sha256 != digest:
            raise ConfigError(f"{a.states}: case {s.case_id!r} carries another case's hash")
        rows.append(msgspec.structs.replace(s, format=STATES_FORMAT, case_sha256=digest))
    append_states(a.out, rows)
    require_training_states([a.out], cases)  # the file as written passes the trainers' check
    print(f"{a.out}: {len(rows):,} states with their case hashes")


if __name__ == "__main__":
    main()
