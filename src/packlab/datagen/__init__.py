"""The layout-first data engine: scenario sampling, layout partition, reverse removal, replay
validation and dataset curation (issue 3; DESIGN.md sections 3, 4 and 6).

Entry points: :func:`generate_cases` (frozen suites for the bench), :func:`build_case` (one case
from a case seed) and ``packlab.datagen.engine.generate_dataset`` (PackData on disk).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from packlab.datagen.config import (
        DIFFICULTIES,
        RECIPES,
        CaseConfig,
        DatasetConfig,
        ValidationConfig,
    )
    from packlab.datagen.generator import build_case, generate_cases

#: Where each name below lives. They are imported on first use (PEP 562), so importing the light
#: ``packlab.datagen.config`` (``packlab generate --help``) loads no engine.
_HOMES = {
    "DIFFICULTIES": "packlab.datagen.config",
    "RECIPES": "packlab.datagen.config",
    "CaseConfig": "packlab.datagen.config",
    "DatasetConfig": "packlab.datagen.config",
    "ValidationConfig": "packlab.datagen.config",
    "build_case": "packlab.datagen.generator",
    "generate_cases": "packlab.datagen.generator",
}


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_HOMES[name]), name)


__all__ = [
    "DIFFICULTIES",
    "RECIPES",
    "CaseConfig",
    "DatasetConfig",
    "ValidationConfig",
    "build_case",
    "generate_cases",
]
