"""Chat messages (:mod:`packlab.vlm.prompt.render`, the Hugging Face multimodal format) <-> OpenAI
chat messages, both ways (stdlib and PIL only).

Client side (:func:`to_openai_messages`): text parts as ``{"type": "text", "text": ...}``,
images as PNG data URLs (``{"type": "image_url", "image_url": {"url":
"data:image/png;base64,..."}}``), messages without images as plain strings. Server side
(:func:`from_openai_messages`): the inverse, image data URLs decoded to PIL images (never
downloaded), a :class:`~packlab.vlm.serve.protocol.RequestError` naming the part that cannot be
used.
"""

from __future__ import annotations

import base64
import binascii
import io
from collections.abc import Callable, Sequence
from typing import Any

from PIL import Image

from packlab.vlm.serve.protocol import RequestError

#: Largest decoded image, in pixels (width x height).
MAX_IMAGE_PIXELS = 4096 * 4096


def png_data_url(image: Any) -> str:
    """A ``data:image/png;base64,...`` URL of a PIL image (or an RGB uint8 numpy array)."""
    if not isinstance(image, Image.Image):
        image = Image.fromarray(image)
    buf = io.BytesIO()
    image.save(buf, format="PNG")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def blank_png_data_url(size: int) -> str:
    """The data URL of an all-black ``size`` x ``size`` RGB image (the ``blank`` ablation)."""
    return png_data_url(Image.new("RGB", (size, size)))


def to_openai_messages(
    messages: Sequence[dict[str, Any]], image_url: Callable[[Any], str] = png_data_url
) -> list[dict[str, Any]]:
    """Hugging Face chat messages (:mod:`packlab.vlm.prompt.render`) -> OpenAI chat messages.

    Images become ``image_url`` parts through ``image_url(image)``; a message whose content is
    text only becomes a plain string (what every OpenAI-compatible server accepts for every role).
    """
    out = []
    for m in messages:
        content = m["content"]
        if isinstance(content, str):
            out.append({"role": m["role"], "content": content})
            continue
        if all(c.get("type") == "text" for c in content):
            out.append({"role": m["role"], "content": "".join(c["text"] for c in content)})
            continue
        parts = []
        for c in content:
            if c.get("type") == "text":
                parts.append({"type": "text", "text": c["text"]})
            elif c.get("type") == "image":
                parts.append({"type": "image_url", "image_url": {"url": image_url(c["image"])}})
            else:
                raise ValueError(f"unsupported content part type {c.get('type')!r}")
        out.append({"role": m["role"], "content": parts})
    return out


def decode_image_url(url: str, where: str) -> Any:
    """The RGB PIL image of a ``data:image/...;base64,...`` URL; RequestError saying what is
    wrong with it otherwise (no downloads: a test server must not fetch URLs)."""
    head, sep, data = url.partition(",")
    if not url.startswith("data:") or not sep or ";base64" not in head:
        raise RequestError(
            f"{where}: only data:image/...;base64, URLs are served (no downloads)", where
        )
    try:
        raw = base64.b64decode(data, validate=True)
    except (binascii.Error, ValueError):
        raise RequestError(f"{where}: the image data is not valid base64", where) from None
    try:
        with Image.open(io.BytesIO(raw)) as im:
            w, h = im.size
            if w * h > MAX_IMAGE_PIXELS:
                raise RequestError(
                    f"{where}: the image has {w} x {h} pixels; "
                    f"at most {MAX_IMAGE_PIXELS:,} are served",
                    where,
                )
            return im.convert("RGB")
    except RequestError:
        raise
    except Image.UnidentifiedImageError:
        raise RequestError(f"{where}: the data is not an image (PNG, JPEG, ...)", where) from None
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError):  # PIL's ways to refuse
        raise RequestError(
            f"{where}: the image does not decode (corrupt or truncated)", where
        ) from None


def from_openai_messages(messages: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """OpenAI chat messages -> the Hugging Face chat messages of :mod:`packlab.vlm.prompt.render`
    (image data URLs decoded to PIL images). The inverse of ``endpoint.to_openai_messages``.
    Raises RequestError naming the part that cannot be used."""
    out = []
    for i, m in enumerate(messages):
        content = m["content"]
        if isinstance(content, str):
            out.append({"role": m["role"], "content": [{"type": "text", "text": content}]})
            continue
        parts = []
        for j, c in enumerate(content):
            where = f"messages[{i}].content[{j}]"
            if c.get("type") == "text":
                parts.append({"type": "text", "text": c["text"]})
            elif c.get("type") == "image_url":
                url = c["image_url"]["url"] if isinstance(c["image_url"], dict) else c["image_url"]
                parts.append(
                    {"type": "image", "image": decode_image_url(url, f"{where}.image_url")}
                )
            else:
                raise RequestError(
                    f"{where}: unsupported content part type {c.get('type')!r}", where
                )
        out.append({"role": m["role"], "content": parts})
    return out
