"""The documented limits of the cell service (docs/cell.md, "Limits").

Each bounds what one request may make the server hold or compute, far above what a packing
cell sends: a 1280 x 1024 depth camera sends 1.3 M pixels, 5.2 MB as float32.
"""

from __future__ import annotations

from packlab.cases.limits import MAX_BUFFER_SIZE, MAX_CONTAINER_SIDE_CM, MAX_HEIGHTMAP_CELLS

#: Pixels of one depth image (width x height): 4.2 M, a 2048 x 2048 sensor.
MAX_IMAGE_PIXELS = 2048 * 2048
#: Either side of one depth image, pixels.
MAX_IMAGE_SIDE = 8192
#: Characters of one image's base64 ``data``: a float32 image at MAX_IMAGE_PIXELS (16 MiB)
#: in base64 (4 characters per 3 bytes).
MAX_IMAGE_BASE64_CHARS = (4 * MAX_IMAGE_PIXELS * 4) // 3 + 4
#: Bytes of one request body: two images at the limit and the rest of the request.
MAX_BODY_BYTES = 2 * MAX_IMAGE_BASE64_CHARS + 1024 * 1024
#: Depth readings above this (mm) are refused: 100 m, beyond any cell's camera.
MAX_DEPTH_MM = 100_000.0
#: A camera's position in a frame, each axis (mm): 100 m.
MAX_TRANSLATION_MM = 100_000.0
#: Container sides (mm) and heightmap cells: the limits of a case file (packlab.cases.limits).
MAX_CONTAINER_SIDE_MM = MAX_CONTAINER_SIDE_CM * 10
MAX_CELLS = MAX_HEIGHTMAP_CELLS
#: Boxes in the buffer (detections, or segments of a buffer image): a case's buffer limit.
MAX_BOXES = MAX_BUFFER_SIZE
#: Sessions one server keeps open at once, and how long one may idle before it is closed.
DEFAULT_MAX_SESSIONS = 256
DEFAULT_IDLE_S = 3600.0

__all__ = [
    "DEFAULT_IDLE_S",
    "DEFAULT_MAX_SESSIONS",
    "MAX_BODY_BYTES",
    "MAX_BOXES",
    "MAX_CELLS",
    "MAX_CONTAINER_SIDE_MM",
    "MAX_DEPTH_MM",
    "MAX_IMAGE_BASE64_CHARS",
    "MAX_IMAGE_PIXELS",
    "MAX_IMAGE_SIDE",
    "MAX_TRANSLATION_MM",
]
