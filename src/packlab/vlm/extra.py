"""The one door into the vlm extra (torch, transformers, tokenizers, accelerate, peft,
safetensors) from code that the core install imports.

Modules that need the extra import torch at their top (``packlab.vlm.data.encoding``,
``packlab.vlm.model.*``, ``packlab.vlm.infer.generate``, ``packlab.vlm.infer.runtime``,
``packlab.vlm.train.sft``, ``packlab.vlm.serve.model_answers``). Torch-free modules that must
reach them when asked (the ``vlm`` policy on its first reset, ``packlab serve``, ``packlab train
sft``) load them by name through :func:`import_torch_side` at that moment, so that importing
them (the policy registry, the CLI parser) never imports torch.
"""

from __future__ import annotations

import importlib
from types import ModuleType

VLM_EXTRA_HINT = (
    "the vlm extra is not installed: pip install torch==2.13.0 (CPU wheel, first), "
    "then pip install -e '.[vlm]'"
)
#: Top-level packages of the vlm extra (a ModuleNotFoundError naming one means "install it").
EXTRA_PACKAGES = frozenset(
    {"torch", "transformers", "tokenizers", "accelerate", "peft", "safetensors"}
)


def import_torch_side(module: str) -> ModuleType:
    """Import ``module`` (a packlab module that needs the vlm extra) now.

    Raises ModuleNotFoundError as the import does; :func:`missing_extra` tells whether it is the
    extra that is missing.
    """
    return importlib.import_module(module)


def missing_extra(exc: ModuleNotFoundError) -> bool:
    """Whether ``exc`` says that a package of the vlm extra is not installed."""
    return (exc.name or "").split(".")[0] in EXTRA_PACKAGES
