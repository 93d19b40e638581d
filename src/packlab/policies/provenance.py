"""What a model card records about how its model was made, so a reviewer can check it.

Paths in cards are names, not places: a path inside the run directory is kept relative to it;
any other path (a scratch ``runs/...`` file, a checkpoint elsewhere, a home directory) is
reduced to its last component, and the file's sha256 says which file it was. So no card names
an absolute or scratch path, and two runs on the same bytes record the same thing.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from packlab.cases.fingerprint import FINGERPRINT_VERSION, case_fingerprint, set_fingerprint
from packlab.core.fileio import file_sha256
from packlab.core.types import Case


def dir_sha256(path: str | os.PathLike[str]) -> str:
    """One digest of a directory's files: sha256 over sorted ``relative-path sha256`` lines."""
    root = Path(path)
    lines = [
        f"{p.relative_to(root).as_posix()} {file_sha256(p)}"
        for p in sorted(root.rglob("*"))
        if p.is_file()
    ]
    return hashlib.sha256("\n".join(lines).encode()).hexdigest()


def path_sha256(path: str | os.PathLike[str]) -> str:
    return dir_sha256(path) if Path(path).is_dir() else file_sha256(path)


def card_path(path: str | os.PathLike[str], run_dir: str | os.PathLike[str]) -> str:
    """``path`` as a card may name it: relative to ``run_dir`` when inside it, else its name."""
    p, base = Path(path).resolve(), Path(run_dir).resolve()
    try:
        return p.relative_to(base).as_posix()
    except ValueError:
        return p.name


def card_source(source: str, run_dir: str | os.PathLike[str]) -> str:
    """A cases source for a card: ``suite:NAME`` and ``recipe:NAME`` as they are, a path as
    :func:`card_path` gives it."""
    if source.startswith(("suite:", "recipe:")):
        return source
    return card_path(source, run_dir)


def git_state(cwd: str | os.PathLike[str] | None = None) -> tuple[str | None, bool | None]:
    """(commit, dirty) of the git checkout packlab runs from; (None, None) outside one or
    without git. Dirty: tracked files differ from the commit (untracked files do not count)."""
    where = Path(cwd) if cwd is not None else Path(__file__).resolve().parent
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            check=False,
            cwd=where,
            capture_output=True,
            text=True,
            timeout=10,
        )
        if head.returncode != 0:
            return None, None
        status = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            check=False, cwd=where, capture_output=True, text=True, timeout=30,
        )  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return None, None
    return head.stdout.strip(), bool(status.stdout.strip()) if status.returncode == 0 else None


def selection_record(cases: Sequence[Case], rule: str) -> dict[str, Any]:
    """The cases a model was chosen or monitored on: their content hash (order- and
    name-free), how many, and the rule that used them."""
    prints = [case_fingerprint(c) for c in cases]
    return {
        "sha256": set_fingerprint(prints),
        "n": len(prints),
        "rule": rule,
        "fingerprint_version": FINGERPRINT_VERSION,
    }


def init_record(
    init: str | os.PathLike[str] | None, run_dir: str | os.PathLike[str]
) -> dict[str, str] | None:
    """The checkpoint a run started from: its card name and sha256 (None: from scratch)."""
    if not init or not Path(init).exists():
        return None
    return {"path": card_path(init, run_dir), "sha256": path_sha256(init)}


def files_record(
    paths: Iterable[str | os.PathLike[str]], run_dir: str | os.PathLike[str]
) -> list[dict[str, str | None]]:
    """Each input file (e.g. labelled states) by card name and sha256 (None: a source that is
    not a file, e.g. a label an API caller gave)."""
    return [
        {"path": card_path(p, run_dir), "sha256": file_sha256(p) if Path(p).is_file() else None}
        for p in paths
    ]


def cases_record(source: str, sha256: str, run_dir: str | os.PathLike[str]) -> dict[str, str]:
    """The training cases: their source as a card names it and their ``cases_sha256``."""
    return {"source": card_source(source, run_dir), "sha256": sha256}


def provenance(
    run_dir: str | os.PathLike[str],
    seed: int,
    init: str | os.PathLike[str] | None = None,
    states: Iterable[str | os.PathLike[str]] = (),
    selection: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The card fields common to every trainer (see the module docstring for paths); the
    training time is each card's own field (``wall_time_s``, ``train_seconds``)."""
    commit, dirty = git_state()
    return {
        "seed": int(seed),
        "commit": commit,
        "dirty": dirty,
        "init": init_record(init, run_dir),
        "states": files_record(states, run_dir),
        "selection": selection,
    }


__all__ = [
    "card_path",
    "card_source",
    "cases_record",
    "dir_sha256",
    "file_sha256",
    "files_record",
    "git_state",
    "init_record",
    "path_sha256",
    "provenance",
    "selection_record",
]
