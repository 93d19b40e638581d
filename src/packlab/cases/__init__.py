"""Read and write case files: one JSON case, a JSONL suite, or the reference benchmark's files.

Files speak centimetres with the public PackLab reference field names (DESIGN.md section 3);
the library speaks integer millimetres. Every malformed input raises ``CaseFormatError`` naming
file, line (``FILE:LINE`` for JSON/JSONL) or row (``FILE (row N)``, 1-based, for parquet), field
and value, and every size is checked against the limits (``packlab.cases.limits``) *when the
case is loaded*, never in the middle of a run.

Two layouts are read, from any of the file kinds:

* packlab's own record: ``{episode_id, difficulty, seed, container_size_cm, grid_cell_size_cm,
  buffer_size, object_sequence, gt_plan, generator}`` (what ``case_to_dict`` writes);
* the reference's benchmark row: ``{data_source, prompt_template_id, ability, extra_info:
  {split, index, difficulty, generator, gt_plan, interaction_kwargs: {name, sample_id,
  container_size_cm, buffer_size, object_sequence, seed}}}``, as parquet (``extra_info`` a
  struct or JSON text) or as JSON lines. All of ``extra_info`` is read: ``sample_id`` is the
  case's id, ``difficulty`` its level, ``gt_plan`` its perfect layout, ``generator`` its
  provenance, ``split``/``index`` its ``CaseOrigin``.

A reference benchmark *directory* (``<dir>/<difficulty>/test.parquet``, as the reference's
``build_dataset.py`` writes it) is a case source too; its files load in the order
``REFERENCE_LEVEL_ORDER`` (easy, medium, hard), then any other level sorted by name.

Object ids (``internal_id``) are kept exactly as given, integers or strings (the reference
writes ``"obj_00000"``); records and answers carry them unchanged and JSON writes them back as
they came. A case's ids must all be of one type.

The modules, one job each:

* ``limits``: the size limits checked on load, and why each is what it is;
* ``layout``: the reference layout's names and level order;
* ``reader``: field access and validation with located errors (cm -> mm);
* ``records`` and ``contents``: one record -> ``Case`` (``case_from_dict``);
* ``serialize``: ``Case`` -> records and the suite checksum;
* ``load``: files and directories -> cases (``load_cases``);
* ``write``: cases -> files (``save_cases``, ``write_reference``).
"""

from __future__ import annotations

from packlab.cases.layout import (
    REFERENCE_FILE,
    REFERENCE_LEVEL_ORDER,
    REFERENCE_MANIFEST,
    REFERENCE_ROW_HEAD,
    REFERENCE_SPLIT,
    reference_level_files,
)
from packlab.cases.limits import (
    INT32_BOUND,
    INT64_BOUND,
    MAX_BUFFER_SIZE,
    MAX_CASE_ID_CHARS,
    MAX_CONTAINER_SIDE_CM,
    MAX_HEIGHTMAP_CELLS,
    MAX_ID_CHARS,
    MAX_OBJECTS,
)
from packlab.cases.load import load_cases
from packlab.cases.records import case_from_dict
from packlab.cases.serialize import case_lines, case_to_dict, case_to_reference_row, cases_sha256
from packlab.cases.write import save_cases, write_reference

__all__ = [
    "INT32_BOUND",
    "INT64_BOUND",
    "MAX_BUFFER_SIZE",
    "MAX_CASE_ID_CHARS",
    "MAX_CONTAINER_SIDE_CM",
    "MAX_HEIGHTMAP_CELLS",
    "MAX_ID_CHARS",
    "MAX_OBJECTS",
    "REFERENCE_FILE",
    "REFERENCE_LEVEL_ORDER",
    "REFERENCE_MANIFEST",
    "REFERENCE_ROW_HEAD",
    "REFERENCE_SPLIT",
    "case_from_dict",
    "case_lines",
    "case_to_dict",
    "case_to_reference_row",
    "cases_sha256",
    "load_cases",
    "reference_level_files",
    "save_cases",
    "write_reference",
]
