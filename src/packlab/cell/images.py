"""Depth images as a cell sends them, decoded to arrays in mm.

Three encodings, each in base64, each in mm (times ``scale_mm`` for the integer ones), 0 where
the sensor has no depth (what depth cameras write for a missing pixel):

- ``f32``: little-endian float32, row-major (height, width);
- ``u16``: little-endian uint16, row-major (height, width);
- ``png16``: a 16-bit greyscale PNG (its size is its shape).

A NaN, an infinity, a negative depth or one beyond ``MAX_DEPTH_MM`` is refused (``f32``): the
sender, not the service, knows whether it means "missing". Decoded, missing pixels are NaN
(packlab's ``DepthImage`` convention).
"""

from __future__ import annotations

import base64
import binascii
import io
import warnings
from typing import Any, Literal

import numpy as np
from PIL import Image

from packlab.cell.errors import CellInputError
from packlab.cell.limits import MAX_DEPTH_MM, MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE

Encoding = Literal["f32", "u16", "png16"]
ENCODINGS: tuple[Encoding, ...] = ("f32", "u16", "png16")
_DTYPES: dict[str, np.dtype[Any]] = {"f32": np.dtype("<f4"), "u16": np.dtype("<u2")}
#: PIL's modes of a 16-bit greyscale PNG (it reads most as "I", 32-bit ints holding 16 bits).
_PNG16_MODES = ("I;16", "I;16B", "I;16L", "I")


def check_shape(field: str, shape: tuple[int, ...] | list[int] | None) -> tuple[int, int]:
    """(height, width) when ``shape`` is two sides within the limits, else a CellInputError."""
    if shape is None or len(shape) != 2:
        raise CellInputError(field, shape, "need [height, width]")
    h, w = (int(v) for v in shape)
    if not (1 <= h <= MAX_IMAGE_SIDE and 1 <= w <= MAX_IMAGE_SIDE):
        raise CellInputError(field, list(shape), f"each side must be 1 to {MAX_IMAGE_SIDE} pixels")
    if h * w > MAX_IMAGE_PIXELS:
        raise CellInputError(field, list(shape), f"more than {MAX_IMAGE_PIXELS} pixels")
    return h, w


def decode_base64(field: str, data: str) -> bytes:
    try:
        return base64.b64decode(data, validate=True)
    except (binascii.Error, ValueError) as exc:
        raise CellInputError(field, data, f"malformed base64 ({exc})") from None


def decode_depth(
    field: str,
    encoding: Encoding,
    data: str,
    shape: tuple[int, int] | list[int] | None,
    scale_mm: float = 1.0,
) -> np.ndarray:
    """The depth image in mm, (height, width) float64, NaN where missing. ``field`` names the
    image in errors (``container_image``)."""
    raw = decode_base64(f"{field}.data", data)
    if encoding == "png16":
        counts = _png16(field, raw, shape)
    elif encoding in _DTYPES:
        h, w = check_shape(f"{field}.shape", shape)
        dtype = _DTYPES[encoding]
        if len(raw) != h * w * dtype.itemsize:
            raise CellInputError(
                f"{field}.data",
                f"{len(raw)} bytes",
                f"need {h * w * dtype.itemsize} bytes for shape [{h}, {w}] of {encoding}",
            )
        counts = np.frombuffer(raw, dtype=dtype).reshape(h, w)
    else:
        raise CellInputError(f"{field}.encoding", encoding, f"choose from {', '.join(ENCODINGS)}")
    scale = 1.0 if encoding == "f32" else float(scale_mm)
    _check_values(field, counts, scale)
    depth = counts.astype(np.float64)
    if scale != 1.0:
        depth *= scale
    depth[counts == 0] = np.nan
    return depth


def _png16(field: str, raw: bytes, shape: tuple[int, int] | list[int] | None) -> np.ndarray:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            image = Image.open(io.BytesIO(raw), formats=["PNG"])  # reads the header only
            w, h = image.size
            check_shape(f"{field}.data", [h, w])  # before the pixels are decompressed
            if shape is not None and [int(v) for v in shape] != [h, w]:
                raise CellInputError(f"{field}.shape", list(shape), f"the PNG is [{h}, {w}]")
            if image.mode not in _PNG16_MODES:
                raise CellInputError(
                    f"{field}.data", f"PNG mode {image.mode}", "need a 16-bit greyscale PNG"
                )
            counts = np.asarray(image, dtype=np.int64)
    except CellInputError:
        raise
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise CellInputError(f"{field}.data", f"{len(raw)} bytes", f"not a PNG ({exc})") from None
    if counts.shape != (h, w) or counts.min(initial=0) < 0 or counts.max(initial=0) > 65535:
        raise CellInputError(f"{field}.data", f"PNG mode {image.mode}", "need 16-bit values")
    return counts


def _check_values(field: str, counts: np.ndarray, scale: float) -> None:
    """Refuse NaN, infinite, negative or too-far depths, naming the first such pixel. One pass
    of two comparisons: NaN fails both, so it needs no test of its own."""
    ok = counts >= 0
    ok &= counts <= MAX_DEPTH_MM / scale
    if ok.all():
        return
    bad = ~ok
    v, u = (int(i) for i in np.argwhere(bad)[0])
    value = float(counts[v, u]) * scale
    reason = (
        "NaN or infinite; send 0 for a pixel without depth"
        if not np.isfinite(value)
        else "negative depth"
        if value < 0
        else f"beyond {MAX_DEPTH_MM:g} mm"
    )
    raise CellInputError(f"{field}.data[{v}, {u}]", value, f"{reason} ({int(bad.sum())} such)")


def encode_depth(depth_mm: np.ndarray, encoding: Encoding = "f32") -> dict[str, object]:
    """The wire form of a depth array in mm (NaN or negative: missing, sent as 0): the fields
    ``encoding``, ``shape`` and ``data`` of a request's image."""
    depth = np.asarray(depth_mm, dtype=np.float64)
    if depth.ndim != 2:
        raise ValueError(f"depth image of shape {depth.shape}: need (height, width)")
    clean = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0)
    shape = [int(depth.shape[0]), int(depth.shape[1])]
    if encoding == "f32":
        raw = clean.astype("<f4").tobytes()
    elif encoding == "u16":
        raw = np.clip(np.rint(clean), 0, 65535).astype("<u2").tobytes()
    elif encoding == "png16":
        buffer = io.BytesIO()
        counts = np.clip(np.rint(clean), 0, 65535).astype(np.uint16)
        Image.fromarray(counts).save(buffer, format="PNG")
        raw = buffer.getvalue()
    else:
        raise ValueError(f"encoding = {encoding!r}: choose from {', '.join(ENCODINGS)}")
    return {"encoding": encoding, "shape": shape, "data": base64.b64encode(raw).decode("ascii")}


__all__ = ["ENCODINGS", "Encoding", "check_shape", "decode_base64", "decode_depth", "encode_depth"]
