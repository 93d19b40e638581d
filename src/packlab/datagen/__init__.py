"""The layout-first data engine: scenario sampling, layout partition, reverse removal, replay
validation and dataset curation (issue 3; DESIGN.md sections 3, 4 and 6).

Entry points: :func:`generate_cases` (frozen suites for the bench), :func:`build_case` (one case
from a case seed) and ``packlab.datagen.engine.generate_dataset`` (PackData on disk).
"""

from packlab.datagen.config import (
    DIFFICULTIES,
    RECIPES,
    CaseConfig,
    DatasetConfig,
    ValidationConfig,
)
from packlab.datagen.generator import build_case, generate_cases

__all__ = [
    "DIFFICULTIES",
    "RECIPES",
    "CaseConfig",
    "DatasetConfig",
    "ValidationConfig",
    "build_case",
    "generate_cases",
]
