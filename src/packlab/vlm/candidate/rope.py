"""Qwen-VL's multimodal rotary position ids (M-RoPE) of one prompt, in numpy.

The rule, as transformers' ``Qwen3VLModel.get_rope_index`` applies it (a test checks equality):
every position has three ids (time, row, column). A run of text tokens counts up from the
current position in all three; a run of image tokens (the merged visual tokens of one image of
``t x h x w`` patches) gets ``start + frame``, ``start + row`` and ``start + column`` over its
``t x (h / merge) x (w / merge)`` grid, and the text after it resumes at
``start + max(h, w) / merge``. Without an image the three ids are all ``0 .. T-1`` (what the text
stack uses when given no position ids).

The ONNX runtime computes them here and feeds them to the text graph, so the graph holds no
data-dependent Python. Torch-free.
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np

from packlab.vlm.candidate.encoding import ImageGrid


def rope_positions(ids: np.ndarray, image_token: int, grid: ImageGrid | None) -> np.ndarray:
    """(3, 1, T) int64 position ids of one prompt's token ids (module docstring); every run of
    ``image_token`` is one image of ``grid``."""
    ids = np.asarray(ids)
    length = len(ids)
    if grid is None or image_token < 0:
        return np.broadcast_to(np.arange(length, dtype=np.int64), (3, 1, length)).copy()
    is_image = ids == image_token
    cuts = [0, *(np.flatnonzero(np.diff(is_image.astype(np.int8))) + 1).tolist(), length]
    out = np.empty((3, length), dtype=np.int64)
    pos = 0
    for a, b in pairwise(cuts):
        if not is_image[a]:
            out[:, a:b] = pos + np.arange(b - a, dtype=np.int64)
            pos += b - a
            continue
        frames, rows, cols = grid.thw
        gh, gw = rows // grid.merge, cols // grid.merge
        if b - a != frames * gh * gw:
            raise ValueError(f"{b - a} image tokens in a run; one image has {frames * gh * gw}")
        t, h, w = np.meshgrid(np.arange(frames), np.arange(gh), np.arange(gw), indexing="ij")
        out[:, a:b] = pos + np.stack([t.ravel(), h.ravel(), w.ravel()])
        pos += max(rows, cols) // grid.merge
    return out[:, None, :]
