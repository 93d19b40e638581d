"""Shared fixtures (the case generator lives in layered_cases.py so tests can import it)."""

from __future__ import annotations

import pytest
from layered_cases import make_layered_case

from packlab.core.types import Case


@pytest.fixture
def layered_case() -> Case:
    return make_layered_case(1)
