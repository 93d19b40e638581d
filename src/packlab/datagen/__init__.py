"""The layout-first data engine: scenario sampling, layout partition, reverse removal, replay
validation and dataset curation (DESIGN.md sections 3, 4 and 6).

Entry points: :func:`generate_cases` (frozen suites for the bench), :func:`build_case` (one case
from a case seed) and ``packlab.datagen.engine.generate_dataset`` (PackData on disk).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from packlab.core.lazy import lazy_attributes

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

__getattr__ = lazy_attributes(__name__, _HOMES)


__all__ = [
    "DIFFICULTIES",
    "RECIPES",
    "CaseConfig",
    "DatasetConfig",
    "ValidationConfig",
    "build_case",
    "generate_cases",
]
