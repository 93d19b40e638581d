"""Model specs: ``tiny:<family>:<size>`` (a tiny random-weight model built offline),
``config:<path>`` (a random-weight model of a config.json, or of a directory's) or a local
checkpoint directory. Imports torch/transformers: only the vlm extra may import this module."""

from __future__ import annotations

from pathlib import Path

from packlab.core.choices import ModelDType
from packlab.core.errors import ConfigError
from packlab.vlm.model.checkpoint import VLM, family_of, load_model, torch_dtype
from packlab.vlm.model.tiny import build_config_model, build_tiny_model

#: The prefix of a tiny-model spec.
TINY_PREFIX = "tiny:"
#: The prefix of a random-weight model of a config.json.
CONFIG_PREFIX = "config:"


def make_model(spec: str, seed: int = 0, dtype: ModelDType = "fp32", device: str = "cpu") -> VLM:
    """Build or load the model of ``spec`` with its weights in ``dtype`` on ``device``.

    ``tiny:<family>:<size>`` and ``config:<path>`` build seeded random weights; anything else
    is a checkpoint directory. Raises ``ConfigError`` naming a bad spec or dtype.
    """
    torch_dtype(dtype)  # a bad dtype fails before anything is built or read
    if spec.startswith(TINY_PREFIX):
        vlm = _tiny(spec, seed, dtype)
    elif spec.startswith(CONFIG_PREFIX):
        vlm = _from_config(spec, seed, dtype)
    else:
        return _checkpoint(spec, dtype, device)
    # Random weights are drawn on the CPU, so that a seed gives the same model on any device.
    vlm.model.to(device)
    return vlm


def _tiny(spec: str, seed: int, dtype: ModelDType) -> VLM:
    parts = spec.split(":")
    if len(parts) != 3:
        raise ConfigError(
            f"model = {spec!r}: expected tiny:<family>:<size>, e.g. tiny:qwen3_5:small"
        )
    try:
        return build_tiny_model(parts[1], parts[2], seed=seed, dtype=dtype)
    except ConfigError:
        raise
    except ValueError as exc:  # an unknown family or size
        raise ConfigError(f"model = {spec!r}: {exc}") from None


def _from_config(spec: str, seed: int, dtype: ModelDType) -> VLM:
    path = spec.removeprefix(CONFIG_PREFIX)
    if not path:
        raise ConfigError(f"model = {spec!r}: expected config:<config.json or directory>")
    return build_config_model(path, seed=seed, dtype=dtype)


def _checkpoint(spec: str, dtype: ModelDType, device: str) -> VLM:
    if not (Path(spec) / "config.json").is_file():
        raise ConfigError(
            f"model = {spec!r}: expected tiny:<family>:<size>, config:<path> or a checkpoint "
            "directory (none with a config.json there)"
        )
    try:
        family_of(spec)  # checked first: an unsupported model is a user's mistake, not a crash
    except ValueError as exc:
        raise ConfigError(f"model = {spec!r}: {exc}") from None
    return load_model(spec, dtype=dtype, device=device)
