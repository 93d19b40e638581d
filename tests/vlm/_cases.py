"""Cases for the inference-policy tests: tests/conftest.py's ``make_layered_case`` (tests/vlm has
its own conftest.py, which shadows the module name ``conftest`` here, so it is loaded by path)."""

from __future__ import annotations

import importlib.util
from pathlib import Path


def _load_make_layered_case():
    spec = importlib.util.spec_from_file_location(
        "packlab_tests_root_conftest", Path(__file__).resolve().parents[1] / "conftest.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.make_layered_case


make_layered_case = _load_make_layered_case()


def small_case(seed: int = 3):
    """6 objects in an 8 x 6 cell container, buffer 2: a bench-like episode in miniature."""
    return make_layered_case(
        seed, cells=(8, 6), layer_heights_mm=(100, 60), buffer_size=2, pieces=3
    )
