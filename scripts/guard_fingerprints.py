"""Write the training guard's fingerprints of the bundled suites (packlab.cases.known).

Usage: python scripts/guard_fingerprints.py [--check]

Run it after adding or rebuilding a bundled suite (``scripts/make_bench_suite.py``); the test
command fails while the shipped file and the suites disagree. ``--check`` only compares (exit 1
when they differ).
"""

from __future__ import annotations

import sys

from packlab.bench.suites import SUITES, load_suite
from packlab.cases.fingerprint import case_fingerprint
from packlab.cases.known import suites_file

HEADER = (
    "# Content fingerprints (packlab.cases.fingerprint) of every case of every bundled suite,\n"
    "# one 'sha256 suite case-id' a line; written by scripts/guard_fingerprints.py.\n"
    "# The training guard refuses any case with one of these.\n"
)


def expected() -> str:
    lines = [
        f"{case_fingerprint(case)} {name} {case.episode_id}"
        for name in SUITES
        for case in load_suite(name)
    ]
    return HEADER + "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    want, path = expected(), suites_file()
    if "--check" in argv:
        same = path.is_file() and path.read_text(encoding="utf-8") == want
        print(f"{path}: {'up to date' if same else 'differs from the bundled suites'}")
        return 0 if same else 1
    path.write_text(want, encoding="utf-8")
    print(f"wrote {path} ({want.count(chr(10)) - HEADER.count(chr(10))} cases)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
