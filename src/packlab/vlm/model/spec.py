"""Model specs: ``tiny:<family>:<size>`` (a random-weight model built offline) or a local
checkpoint directory. Imports torch/transformers: only the vlm extra may import this module."""

from __future__ import annotations

from packlab.core.errors import ConfigError
from packlab.vlm.model.checkpoint import VLM, load_model
from packlab.vlm.model.tiny import build_tiny_model

#: The prefix of a tiny-model spec.
TINY_PREFIX = "tiny:"


def make_model(spec: str, seed: int = 0) -> VLM:
    """``tiny:<family>:<size>`` builds a random-weight model; anything else is a checkpoint dir."""
    if spec.startswith(TINY_PREFIX):
        parts = spec.split(":")
        if len(parts) != 3:
            raise ConfigError(
                f"model = {spec!r}: expected tiny:<family>:<size>, e.g. tiny:qwen3_5:small"
            )
        return build_tiny_model(parts[1], parts[2], seed=seed)
    return load_model(spec)
