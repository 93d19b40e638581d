"""Where a pointer model's torch work runs (``device``) and at what precision (``dtype``): the
names a config takes and their torch-free checks. Resolving them against the machine (is there
a GPU, does it do bf16) needs torch: :mod:`.device`. Torch-free.
"""

from __future__ import annotations

import re

from packlab.core.choices import AutocastDType, require_choice
from packlab.core.errors import ConfigError

#: ``auto`` (a GPU when torch sees one, else the CPU), ``cpu``, ``cuda`` or ``cuda:<index>``.
DEVICE_PATTERN = re.compile(r"auto|cpu|cuda(:\d+)?")


def check_device(owner: str, device: str) -> None:
    """Refuse a device name torch would not take (``owner``: the config's class name)."""
    if not isinstance(device, str) or not DEVICE_PATTERN.fullmatch(device):
        raise ConfigError(f"{owner}.device = {device!r}: expected auto, cpu, cuda or cuda:<index>")


def check_dtype(owner: str, dtype: str, device: str) -> None:
    """Refuse an unknown dtype, and bf16 on the CPU (it autocasts on CUDA only). Whether an
    ``auto`` or CUDA device does bf16 is known only with torch (:func:`.device.placement`)."""
    require_choice(dtype, AutocastDType, f"{owner}.dtype")
    if dtype == "bf16" and device == "cpu":
        raise ConfigError(
            f"{owner}.dtype = 'bf16': device 'cpu' has no bf16 autocast here; use fp32 or a "
            f"CUDA device"
        )
