"""A config's ``device`` and ``dtype`` (:mod:`.precision`) against this machine: the torch
device the work runs on, and the autocast context of its forward passes.
Imports torch: only the vlm extra may import this module.
"""

from __future__ import annotations

import contextlib

import torch

from packlab.core.errors import ConfigError


def resolve_device(owner: str, device: str) -> str:
    """``auto`` -> ``cuda`` when torch sees a GPU, else ``cpu``; an explicit CUDA device must
    exist here (so a typo fails before any work, not at the first update)."""
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda"):
        index = torch.device(device).index or 0
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if index >= count:
            raise ConfigError(f"{owner}.device = {device!r}: torch sees {count} CUDA device(s)")
    return device


def bf16_supported(device: str) -> bool:
    """Whether ``device`` (resolved) runs bf16 natively: a CUDA device of compute capability 8
    or later (emulated bf16 would be slower than fp32)."""
    if not device.startswith("cuda"):
        return False
    return torch.cuda.get_device_capability(torch.device(device))[0] >= 8


def placement(owner: str, device: str, dtype: str) -> str:
    """The resolved device, after refusing bf16 where it does not run natively."""
    resolved = resolve_device(owner, device)
    if dtype == "bf16" and not bf16_supported(resolved):
        here = "" if resolved == device else f" ({resolved} here)"
        raise ConfigError(
            f"{owner}.dtype = 'bf16': device {device!r}{here} has no native bf16; use fp32"
        )
    return resolved


def autocast(device: str, dtype: str) -> contextlib.AbstractContextManager:
    """The forward passes' context: bf16 autocast for ``bf16`` (the parameters stay float32),
    nothing for fp32."""
    if dtype != "bf16":
        return contextlib.nullcontext()
    return torch.autocast(device_type=torch.device(device).type, dtype=torch.bfloat16)
