"""The torch side of the ``vlm`` policy (vlm extra): device and dtype, the models loaded in this
process, the generator each policy asks and the decode batcher the generators of one model share.

:class:`packlab.vlm.infer.policy.VLMPolicy` imports this module on its first load (through
:func:`packlab.vlm.extra.import_torch_side`), so that building and pickling the policy never
imports torch.
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from pathlib import Path
from typing import Any

import torch

from packlab.core.errors import ConfigError
from packlab.vlm.data.encoding import ProcessingConfig
from packlab.vlm.infer.batching import DecodeBatcher
from packlab.vlm.infer.generate import PrefixCachedGenerator
from packlab.vlm.model.checkpoint import VLM, load_model
from packlab.vlm.model.tiny import build_tiny_model

#: dtype names a policy takes (besides ``auto``).
DTYPES = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}

#: Models loaded in this process, most recent last: the bench runner builds a policy per
#: episode, and each must not reload the weights. Weights are only read at inference; the
#: per-episode state (cache, images) lives in each policy's generator.
_LOADED: OrderedDict[tuple, VLM] = OrderedDict()
_LOADED_MAX = 2
_LOADED_LOCK = threading.Lock()

#: The decode batcher of each loaded model in this process, per batch size limit: every
#: episode of the model shares it (packlab.vlm.infer.batching). Keyed by the model module
#: itself, weakly, so a model dropped from _LOADED takes its batchers with it.
_BATCHERS: weakref.WeakKeyDictionary[Any, dict[int, DecodeBatcher]] = weakref.WeakKeyDictionary()
_BATCHERS_LOCK = threading.Lock()


def set_threads(threads: int) -> None:
    """Torch's intra-op threads in this process."""
    torch.set_num_threads(threads)


def resolve_device(device: str) -> str:
    """``auto`` -> ``cuda`` when a GPU is visible, else ``cpu``; anything else as given."""
    if device != "auto":
        return device
    if torch.cuda.is_available():
        return "cuda"
    return "cpu"


def resolve_dtype(dtype: str, device: str) -> torch.dtype:
    """``auto`` -> bfloat16 on a GPU that has it, else float32; or one of :data:`DTYPES`."""
    if dtype == "auto":
        if device.startswith("cuda") and torch.cuda.is_bf16_supported():
            return torch.bfloat16
        return torch.float32
    if dtype not in DTYPES:
        raise ConfigError(f"dtype = {dtype!r}: expected auto, {', '.join(DTYPES)}")
    return DTYPES[dtype]


def dtype_name(dtype: torch.dtype) -> str:
    """``float32`` for ``torch.float32`` (for run records)."""
    return str(dtype).replace("torch.", "")


def _build_tiny(spec: str, device: str, dtype: torch.dtype, seed: int) -> VLM:
    parts = spec.split(":")
    if len(parts) != 3:
        raise ConfigError(f"model = {spec!r}: expected tiny:<family>:<size>")
    try:
        vlm = build_tiny_model(parts[1], parts[2], seed=seed)
    except ValueError as exc:
        raise ConfigError(f"model = {spec!r}: {exc}") from None
    vlm.model.to(device=device, dtype=dtype)
    return vlm


def load_vlm(spec: str, device: str, dtype: torch.dtype, seed: int) -> VLM:
    """Build (``tiny:F:S``) or load (a directory) a VLM, reusing one already loaded here."""
    tiny = spec.startswith("tiny:")
    stamp = None
    if not tiny:
        stamp = (Path(spec) / "config.json").stat().st_mtime_ns  # a retrained dir reloads
    key = (spec, device, str(dtype), seed if tiny else None, stamp)
    with _LOADED_LOCK:
        if key in _LOADED:
            _LOADED.move_to_end(key)
            return _LOADED[key]
        if tiny:
            vlm = _build_tiny(spec, device, dtype, seed)
        else:
            vlm = load_model(spec, dtype=dtype, device=device)
        _LOADED[key] = vlm
        while len(_LOADED) > _LOADED_MAX:
            _LOADED.popitem(last=False)
        return vlm


def make_generator(
    vlm: VLM,
    max_new_tokens: int,
    reuse_prefix: bool,
    image_size: int,
    max_length: int | None,
    template_kwargs: dict[str, Any],
) -> PrefixCachedGenerator:
    """A greedy, prefix-cached generator of ``vlm`` with the policy's processing settings."""
    config = ProcessingConfig(
        image_size=image_size, max_length=max_length, template_kwargs=template_kwargs
    )
    return PrefixCachedGenerator(vlm, config, max_new_tokens, reuse_prefix)


def attach_batcher(generator: PrefixCachedGenerator, mode: str, max_batch: int) -> None:
    """Have ``generator`` decode through its model's batcher in this process (``mode`` ``auto``
    or ``on``), or alone (``off``)."""
    if mode == "off":
        generator.batcher = None
        return
    model = generator.model
    with _BATCHERS_LOCK:
        per_size = _BATCHERS.setdefault(model, {})
        if max_batch not in per_size:
            batcher = per_size[max_batch] = DecodeBatcher(max_batch)
            # Its thread ends with the model (without waiting for it); at exit the daemon
            # thread just ends with the process.
            weakref.finalize(model, batcher.stop, 0.0).atexit = False
        generator.batcher = per_size[max_batch]
    generator.batch_mode = mode


def stop_batchers() -> None:
    """Stop every decode batcher of this process (their threads end; a later answer starts
    them again)."""
    with _BATCHERS_LOCK:
        batchers = [b for per_size in _BATCHERS.values() for b in per_size.values()]
    for batcher in batchers:
        batcher.stop()
