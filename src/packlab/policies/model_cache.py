"""Learned models loaded once per process and shared by the policies that play them.

The bench makes a fresh policy per episode (no state leaks between episodes), so a policy that
loaded its model in ``reset`` would open the same ONNX sessions, hash the same checkpoint files
and read the same tokenizer for every episode. :func:`load_once` keeps what a load returned,
keyed by the caller's settings, the directory and its files' stamps (name, mtime, size): a
re-export or retraining in between is loaded (and checked) anew. What is kept must hold no
per-episode state.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any, TypeVar, cast

T = TypeVar("T")

_LOADED: dict[tuple[Hashable, ...], Any] = {}


def directory_stamps(directory: Path) -> tuple[tuple[str, int, int], ...]:
    """(name, mtime ns, size) of each file in ``directory`` (empty when it does not exist)."""
    if not directory.is_dir():
        return ()
    stats = ((p.name, p.stat()) for p in directory.iterdir() if p.is_file())
    return tuple(sorted((name, st.st_mtime_ns, st.st_size) for name, st in stats))


def load_once(directory: Path, settings: tuple[Hashable, ...], load: Callable[[], T]) -> T:
    """``load()``'s result for ``directory`` under ``settings``, loaded at most once per process
    while the directory's files are unchanged."""
    directory = Path(directory)
    key = (directory.resolve(), settings, directory_stamps(directory))
    if key not in _LOADED:
        _LOADED[key] = load()
    return cast(T, _LOADED[key])  # stored by this function from a load returning T
