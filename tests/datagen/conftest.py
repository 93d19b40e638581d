"""Fixtures of the data-engine tests: a small dataset made once per session on the fast path."""

from __future__ import annotations

from pathlib import Path

import pytest
from datagen_helpers import make_dataset


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("packdata") / "tiny"
    make_dataset(out)
    return out
