"""Size limits on a case, checked when the case is loaded (never in the middle of a run).

A case file is input from anywhere; these bounds keep one bad or hostile case from exhausting
memory or time in the middle of a run. Each is far above anything the paper, the reference or
packlab's generator makes (containers <= 170 cm, <= 32 objects, buffer <= 10).
"""

from __future__ import annotations

#: Each container side (X, Y and height), in cm: 10 m. The physics engine works in metres with
#: a fixed time step tuned for boxes of centimetres to a metre or two; far beyond this the
#: settle thresholds stop meaning anything, and a 1e300 cm container is plainly a broken file.
MAX_CONTAINER_SIDE_CM = 1000
#: Heightmap cells (X cells x Y cells): 400 x 400, a 10 m x 10 m floor on the default 2.5 cm
#: grid. Every step keeps a heightmap (int32) in the policy's history, so the worst case of this
#: and MAX_OBJECTS is 1000 x 160,000 x 4 bytes = 640 MB; a finer grid must shrink the container.
MAX_HEIGHTMAP_CELLS = 160_000
#: Objects per case. Episodes run one decision per object; the hard level has <= 32.
MAX_OBJECTS = 1000
#: Visible objects (k). Candidate search is k x 2 rotations x cells per step, and a VLM prompt
#: lists every shown object; the hard level uses 10.
MAX_BUFFER_SIZE = 64
#: Characters of a string ``internal_id`` (``"obj_00000"`` has 9) and of a case id.
MAX_ID_CHARS = 64
MAX_CASE_ID_CHARS = 200
#: Seeds, row indices and integer object ids must fit a signed 64-bit integer: parquet columns
#: and numpy hold them as int64.
INT64_BOUND = 2**63
#: ``gt_index``, ``type_id`` and ``layer_index`` are int32 columns in PackData shards.
INT32_BOUND = 2**31

__all__ = [
    "INT32_BOUND",
    "INT64_BOUND",
    "MAX_BUFFER_SIZE",
    "MAX_CASE_ID_CHARS",
    "MAX_CONTAINER_SIDE_CM",
    "MAX_HEIGHTMAP_CELLS",
    "MAX_ID_CHARS",
    "MAX_OBJECTS",
]
