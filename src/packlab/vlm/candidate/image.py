"""The heightmap as an image for the pointer model's vision tower (``map`` = image, both, blank).

:func:`heightmap_image` draws the heightmap (cells, int mm) as one small grayscale image: each
cell's height in 255ths of the rim height (clipped at the rim), y down the rows and x along the
columns as in the text map; every cell is a square of whole pixels, and the pixels outside the
container (the padding of a non-square or small container) are rim-high walls, so no box could
go there. A container with more cells per side than the image has pixels is max-pooled first.
:func:`patchify` turns images into the Qwen-VL ``pixel_values`` and ``image_grid_thw``, exactly as
transformers' Qwen2-VL image processor does after its resize (a test checks it), but without PIL
or a resize, so that encoding a step costs well under a millisecond. It normalises with the
checkpoint's own per-channel mean and std (its image processor's ``image_mean`` and
``image_std``: CLIP's for Qwen2.5-VL, 0.5 for the Qwen3 families), carried by
:class:`.encoding.ImageGrid`; :data:`QWEN3_MEAN` and :data:`QWEN3_STD` only where a model names
none.

Image side: :data:`TOKENS_PER_SIDE` merged tokens per side (a model card's ``image_tokens``
sets another count, ``packlab train candidate --image-tokens``), each ``patch_size *
spatial_merge_size`` pixels (16 * 2 = 32 for Qwen3-VL), so 4 -> a 128 x 128 image, 8 x 8 = 64
patches merged to 16 visual tokens. Why 16: the bench's largest containers have about 57 cells
per side, which then get 2 pixels per cell and about 7 x 7 cells per patch (8 x 8 patches,
finer than the text map's 8 x 8 blocks), and the prompt gets shorter than with the digit map;
64 tokens (256 px) measured about 30 % slower per training step on one CPU thread (1.36 s
against 1.1 s, batch 16) and 40 ms against 36 ms per decision, near the 50 ms budget
(docs/vlm.md). Torch-free (numpy).
"""

from __future__ import annotations

import numpy as np

from packlab.core.types import Container

#: Merged visual tokens per image side (module docstring): 4 x 4 = 16 tokens per image.
TOKENS_PER_SIDE = 4
#: Pixel values of the image (uint8): 0 is the floor, 255 the rim (and the walls outside).
FULL = 255
#: Qwen3-VL's normalisation per RGB channel: the fallback for a model whose checkpoint names
#: none, and what every pointer model saved before the normalisation was recorded was trained
#: with.
QWEN3_MEAN = (0.5, 0.5, 0.5)
QWEN3_STD = (0.5, 0.5, 0.5)


def image_side(patch_size: int, merge_size: int, per_side: int = TOKENS_PER_SIDE) -> int:
    """Pixels per side of the fixed-size image for a vision tower, ``per_side`` merged tokens
    per side (:data:`TOKENS_PER_SIDE` unless a model card names its own, ``image_tokens``)."""
    if per_side < 1:
        raise ValueError(f"image tokens per side = {per_side}: must be >= 1")
    return per_side * patch_size * merge_size


def visual_tokens(side: int, patch_size: int, merge_size: int) -> int:
    """Number of ``<|image_pad|>`` tokens one ``side`` x ``side`` image becomes."""
    per_side = side // (patch_size * merge_size)
    return per_side * per_side


def heightmap_image(heightmap: np.ndarray, container: Container, side: int) -> np.ndarray:
    """(side, side) uint8: row = y, column = x, value = height / rim height * 255 (clipped),
    rim-high outside the container."""
    hm = np.asarray(heightmap, dtype=np.int64)
    nx, ny = hm.shape
    block = -(-max(nx, ny) // side)  # cells per pixel when the container is larger than the image
    if block > 1:
        bx, by = -(-nx // block), -(-ny // block)
        padded = np.zeros((bx * block, by * block), dtype=np.int64)
        padded[:nx, :ny] = hm
        hm = padded.reshape(bx, block, by, block).max(axis=(1, 3))
        nx, ny = bx, by
    level = np.clip(hm * FULL // max(container.height_mm, 1), 0, FULL).astype(np.uint8)
    scale = side // max(nx, ny)
    cells = np.repeat(np.repeat(level.T, scale, axis=0), scale, axis=1)  # (y, x) pixels
    out = np.full((side, side), FULL, dtype=np.uint8)
    out[: cells.shape[0], : cells.shape[1]] = cells
    return out


def _cell_pixels(cells: int, start: int, length: int, block: int, scale: int) -> tuple[int, int]:
    """The first and one-past-last pixel of cells [start, start + length) along one axis, as
    :func:`heightmap_image` draws them (``block`` cells per pooled cell, ``scale`` pixels each)."""
    first = min(start, cells - 1) // block
    last = min(start + max(length, 1) - 1, cells - 1) // block
    return first * scale, (last + 1) * scale


def _token_span(
    cells: tuple[int, int], x: int, y: int, fx: int, fy: int, side: int, token_px: int
) -> tuple[int, int, int, int]:
    """(first row, last row, first column, last column) of the merged visual tokens whose
    pixels hold some cell of the footprint (:func:`footprint_tokens`)."""
    nx, ny = cells
    block = -(-max(nx, ny) // side)
    scale = side // max(-(-nx // block), -(-ny // block))
    x0, x1 = _cell_pixels(nx, x, fx, block, scale)
    y0, y1 = _cell_pixels(ny, y, fy, block, scale)
    return y0 // token_px, (y1 - 1) // token_px, x0 // token_px, (x1 - 1) // token_px


def footprint_tokens(
    cells: tuple[int, int], x: int, y: int, fx: int, fy: int, side: int, token_px: int
) -> np.ndarray:
    """Indices of the merged visual tokens (row-major: y rows, x columns, as :func:`patchify`
    orders them) whose pixels hold some cell of the footprint ``x .. x + fx - 1``, ``y .. y +
    fy - 1`` in an image of :func:`heightmap_image` (``cells``: the container's cells per side;
    ``token_px``: pixels per merged token side). Only the image's layout is used: where
    :func:`heightmap_image` draws each cell, never a height."""
    r0, r1, c0, c1 = _token_span(cells, x, y, fx, fy, side, token_px)
    per_side = side // token_px
    cols = np.arange(c0, c1 + 1)
    rows = np.arange(r0, r1 + 1)
    return (rows[:, None] * per_side + cols[None, :]).ravel().astype(np.int64)


def ring_tokens(
    cells: tuple[int, int], x: int, y: int, fx: int, fy: int, side: int, token_px: int
) -> np.ndarray:
    """Indices (row-major, ascending) of the one-token ring around :func:`footprint_tokens`:
    the tokens of the footprint's token rectangle grown by one token on every side (corners
    included), clipped to the image, less the footprint's own tokens. These hold what a box
    there would be flush with (neighbouring columns, the walls; the padding outside the
    container is drawn rim-high). Like :func:`footprint_tokens`, only the image's layout is
    used, never a height; empty when the footprint's tokens cover the whole image."""
    r0, r1, c0, c1 = _token_span(cells, x, y, fx, fy, side, token_px)
    per_side = side // token_px
    rows = np.arange(max(r0 - 1, 0), min(r1 + 1, per_side - 1) + 1)
    cols = np.arange(max(c0 - 1, 0), min(c1 + 1, per_side - 1) + 1)
    inside = ((rows >= r0) & (rows <= r1))[:, None] & ((cols >= c0) & (cols <= c1))[None, :]
    grid = rows[:, None] * per_side + cols[None, :]
    return grid[~inside].astype(np.int64)


def blank_image(side: int) -> np.ndarray:
    """The blank-image ablation's input: all zeros, whatever the state."""
    return np.zeros((side, side), dtype=np.uint8)


def _affine(mean: tuple[float, ...], std: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(scale, shift) per channel with ``(v / 255 - mean) / std == v * scale - shift``: one
    multiply-add, which for mean = std = 0.5 is ``v * (2 / 255) - 1`` bit for bit (the form
    every earlier model was trained and exported with)."""
    scale = [1.0 / (255.0 * s) for s in std]
    shift = [m / s for m, s in zip(mean, std, strict=True)]
    return np.asarray(scale, dtype=np.float32), np.asarray(shift, dtype=np.float32)


def patchify(
    images: np.ndarray,
    patch_size: int,
    merge_size: int,
    temporal_patch_size: int,
    mean: tuple[float, ...] = QWEN3_MEAN,
    std: tuple[float, ...] = QWEN3_STD,
) -> tuple[np.ndarray, np.ndarray]:
    """(B, H, W) uint8 grayscale images -> ``pixel_values`` (B * gh * gw, 3 * T * P * P) float32,
    normalised as the checkpoint's processor does ((v / 255 - mean[c]) / std[c] in channel c of
    the grey value copied to the 3 RGB channels, the same in the T temporal copies), and
    ``image_grid_thw`` (B, 3) int64 = (1, gh, gw)."""
    b, h, w = images.shape
    gh, gw, m, p = h // patch_size, w // patch_size, merge_size, patch_size
    scale, shift = _affine(mean, std)
    x = images.astype(np.float32)
    x = x.reshape(b, gh // m, m, p, gw // m, m, p).transpose(0, 1, 4, 2, 5, 3, 6)
    x = x.reshape(b, gh * gw, 1, 1, p * p)  # patches in merge order, then (channel, time, pixel)
    x = x * scale[:, None, None] - shift[:, None, None]  # (b, gh * gw, 3, 1, p * p)
    x = np.broadcast_to(x, (b, gh * gw, 3, temporal_patch_size, p * p))
    pixels = np.ascontiguousarray(x).reshape(b * gh * gw, 3 * temporal_patch_size * p * p)
    grid = np.tile(np.array([[1, gh, gw]], dtype=np.int64), (b, 1))
    return pixels, grid
