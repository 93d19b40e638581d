"""The rl extra: what it installs and the hint when it is missing (torch-free)."""

from __future__ import annotations

import importlib
from types import ModuleType

RL_EXTRA_HINT = (
    "the rl extra is not installed: pip install torch==2.13.0 --extra-index-url "
    "https://download.pytorch.org/whl/cpu (the CPU wheel, first), then pip install -e '.[rl]'"
)
#: Top-level packages of the rl extra (a ModuleNotFoundError naming one means "install it").
EXTRA_PACKAGES = frozenset({"torch", "stable_baselines3", "sb3_contrib"})


class RLExtraMissing(ImportError):
    """The rl extra is not installed (the message says how to install it)."""


def import_rl(module: str) -> ModuleType:
    """Import a packlab module that needs the rl extra, or raise :class:`RLExtraMissing`."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as e:
        if (e.name or "").split(".")[0] in EXTRA_PACKAGES:
            raise RLExtraMissing(RL_EXTRA_HINT) from None
        raise
