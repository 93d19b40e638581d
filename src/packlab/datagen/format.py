"""The PackData directory format (DESIGN.md section 6): schemas, rows, atomic writers, SFT export.

Layout of a dataset directory (every path inside is relative, so the directory can be moved)::

    README.md                       dataset card; its YAML header names the two parquet configs
    meta/config.json                the DatasetConfig, written first; a resume must match it
    meta/info.json                  format version, generator config, counts, rejection stats
    meta/shards/<shard>.json        one marker per finished shard (its stats); written last
    data/episodes/<shard>.parquet   one row per kept episode (case, metrics, provenance)
    data/steps/<shard>.parquet      one row per step (shown buffer, action, heightmap, image path)
    images/<difficulty>/<shard>/<episode_id>/<step>.png   heightmap before each step
    sft/<shard>.parquet             one conversation per episode (packlab.datagen.sft_export)

``<shard>`` is ``<difficulty>-<index:05d>``. Files speak centimetres as the case format does,
except heightmaps, which keep the core's exact integer millimetres (``heightmap_mm``). Every file
is written to a temporary name and renamed into place, and a shard's marker is written only
after all its files, so a killed run never leaves a half-written file that looks complete.
Nothing time- or machine-dependent is written, so the same config gives byte-identical files.
"""

from __future__ import annotations

import io
import json
import os
import shutil
from collections.abc import Sequence
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from packlab.cases import case_to_dict
from packlab.core.fileio import write_atomically
from packlab.core.records import PACKDATA_FORMAT, DatasetInfo, dataset_info_from_json, to_builtins
from packlab.core.types import Action, Container, ShownItem
from packlab.datagen.validate import Trajectory
from packlab.sim.raster import heightmap_to_image
from packlab.vlm.prompt.render import action_text

#: Bump when a file's layout or a column's meaning changes (stated once, beside the record
#: types: packlab.core.records.PACKDATA_FORMAT, ``format_version`` of meta/info.json).
FORMAT_VERSION = PACKDATA_FORMAT

STEPS_DIR = "data/steps"
EPISODES_DIR = "data/episodes"
IMAGES_DIR = "images"
SFT_DIR = "sft"
META_DIR = "meta"
SHARDS_DIR = "meta/shards"
INFO_FILE = "meta/info.json"

_SHOWN = pa.struct(
    [
        (
            "object_id",
            pa.int32(),
        ),  # index in the shown buffer (what an action's object_id refers to)
        ("internal_id", pa.int32()),
        # (l, w, h) as the observation names them (generator_config ``sides``); the action's
        # rotation refers to these
        ("size_cm", pa.list_(pa.float64())),
        ("size_cells", pa.list_(pa.int32())),  # (l, w) xy cells, h z cells
        ("type_id", pa.int32()),
    ]
)
_ACTION = pa.struct(
    [("object_id", pa.int32()), ("x", pa.int32()), ("y", pa.int32()), ("rotation", pa.int32())]
)

STEP_SCHEMA = pa.schema(
    [
        ("episode_id", pa.string()),
        ("difficulty", pa.string()),
        ("step_index", pa.int32()),
        ("n_steps", pa.int32()),
        ("remaining", pa.int32()),  # objects not yet processed, shown ones included
        ("container_size_cm", pa.list_(pa.float64())),
        ("grid_cell_size_cm", pa.list_(pa.float64())),  # (xy, z)
        (
            "heightmap_mm",
            pa.list_(pa.list_(pa.int32())),
        ),  # [x][y], the observed surface before the step
        ("image", pa.string()),  # PNG of heightmap_mm, relative to the dataset root
        ("shown", pa.list_(_SHOWN)),  # the buffer in the order shown at this step
        ("action", _ACTION),
        ("action_text", pa.string()),  # the exact assistant target (vlm.prompt.render.action_text)
        ("internal_id", pa.int32()),  # the object placed
        ("drop_mm", pa.list_(pa.int32())),  # footprint min corner (x, y) and Eq. 2 height z, mm
    ]
)

EPISODE_SCHEMA = pa.schema(
    [
        ("episode_id", pa.string()),
        ("difficulty", pa.string()),
        ("case_seed", pa.int64()),
        ("user_seed", pa.int64()),
        ("slot", pa.int32()),
        ("attempt", pa.int32()),
        ("layout", pa.string()),
        ("anchor", pa.string()),
        ("first_cell", pa.list_(pa.int32())),
        ("container_size_cm", pa.list_(pa.float64())),
        ("buffer_size", pa.int32()),
        ("n_objects", pa.int32()),
        ("n_layers", pa.int32()),
        ("stack_height_cm", pa.float64()),
        ("layer_heights_cm", pa.list_(pa.float64())),
        ("n_rotated", pa.int32()),
        ("backend", pa.string()),
        ("run_seed", pa.int64()),
        ("success_ratio", pa.float64()),
        ("compactness", pa.float64()),
        ("overall", pa.float64()),
        ("max_height_mm", pa.int32()),
        ("settle_steps", pa.int64()),
        (
            "case_json",
            pa.string(),
        ),  # the case in the reference format (packlab.cases.case_from_dict)
    ]
)


def shard_name(difficulty: str, index: int) -> str:
    return f"{difficulty}-{index:05d}"


# -- atomic files -----------------------------------------------------------------------------


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically, with the mode a plain ``open`` gives (see fileio)."""
    write_atomically(path, lambda fh: fh.write(data))


def atomic_write_json(path: Path, obj: Any) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=1, sort_keys=True) + "\n").encode())


def write_info(root: Path, info: DatasetInfo) -> Path:
    """Write ``meta/info.json`` (sorted keys, as always)."""
    path = Path(root) / INFO_FILE
    atomic_write_json(path, to_builtins(info))
    return path


def read_info(root: str | os.PathLike[str]) -> DatasetInfo:
    """A dataset's ``meta/info.json`` as a typed record, its ``format_version`` checked: an
    unknown one, or a field missing or of the wrong type, is a RecordFormatError naming it."""
    path = Path(root) / INFO_FILE
    return dataset_info_from_json(path.read_bytes(), str(path))


def write_parquet(path: Path, table: pa.Table) -> None:
    """Write a table as one Parquet file, atomically."""
    buf = io.BytesIO()
    pq.write_table(table, buf, compression="zstd")
    atomic_write_bytes(path, buf.getvalue())


def remove_stale_temporaries(root: Path) -> int:
    """Delete temporary files and staging directories a killed run left behind (they are never
    read); returns how many."""
    n = 0
    for p in sorted(root.rglob(".*.tmp"), key=lambda p: len(p.parts)):
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()
        else:
            continue
        n += 1
    return n


class ShardImages:
    """A shard's images, written into a hidden staging directory and renamed into place at once.

    Per-file atomic renames would cost a temporary file per image (the engine writes hundreds of
    thousands); one directory rename per shard gives the same guarantee: a shard's images
    either all appear under their final names or none do.
    """

    def __init__(self, root: Path, difficulty: str, shard: str) -> None:
        self.prefix = image_dir(difficulty, shard)
        self.final = root / self.prefix
        self.stage = self.final.with_name(f".{shard}.tmp")
        if self.stage.exists():
            shutil.rmtree(self.stage)

    def write(self, rel_path: str, data: bytes) -> None:
        """``rel_path`` is the image's dataset-relative path (it must lie in this shard)."""
        target = self.stage / PurePosixPath(rel_path).relative_to(self.prefix)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)

    def commit(self) -> None:
        self.stage.mkdir(
            parents=True, exist_ok=True
        )  # an all-rejected shard still gets its directory
        if self.final.exists():  # left by a run killed after this rename but before the marker
            shutil.rmtree(self.final)
        os.replace(self.stage, self.final)


# -- rows -------------------------------------------------------------------------------------


def _cm(mm: float) -> float:
    return float(mm) / 10.0


def image_dir(difficulty: str, shard: str) -> str:
    """Relative directory (POSIX separators) of a shard's images."""
    return f"{IMAGES_DIR}/{difficulty}/{shard}"


def image_path(difficulty: str, shard: str, episode_id: str, step_index: int) -> str:
    """Relative path (POSIX separators) of a step's heightmap image."""
    return f"{image_dir(difficulty, shard)}/{episode_id}/{step_index:03d}.png"


def encode_png(heightmap: Any, container: Container, size: int) -> bytes:
    """The heightmap image (packlab.sim.raster, palette mode) as PNG bytes."""
    buf = io.BytesIO()
    heightmap_to_image(heightmap, container, size, mode="P").save(buf, format="PNG")
    return buf.getvalue()


def _shown_row(s: ShownItem) -> dict[str, Any]:
    return {
        "object_id": s.shown_index,
        "internal_id": s.internal_id,
        "size_cm": [_cm(v) for v in s.size_mm],
        "size_cells": list(s.size_cells),
        "type_id": s.type_id,
    }


def step_rows(trajectory: Trajectory, shard: str) -> list[dict[str, Any]]:
    """One row per step of a kept trajectory (every step valid, so every action is an Action)."""
    case = trajectory.case
    c = case.container
    drops = trajectory.drops
    rows = []
    for step, drop in zip(trajectory.steps, drops):
        action = step.action
        assert isinstance(action, Action), "kept trajectories hold only parsed actions"
        rows.append(
            {
                "episode_id": case.episode_id,
                "difficulty": case.difficulty,
                "step_index": step.step_index,
                "n_steps": len(trajectory.steps),
                "remaining": step.remaining,
                "container_size_cm": [_cm(v) for v in c.size_mm],
                "grid_cell_size_cm": [_cm(c.cell_xy_mm), _cm(c.cell_z_mm)],
                "heightmap_mm": step.heightmap,  # numpy; see steps_table
                "image": image_path(case.difficulty, shard, case.episode_id, step.step_index),
                "shown": [_shown_row(s) for s in step.shown],
                "action": action.to_dict(),
                "action_text": action_text(action),
                "internal_id": step.shown[action.object_id].internal_id,
                "drop_mm": list(drop) if drop is not None else None,
            }
        )
    return rows


def steps_table(rows: list[dict[str, Any]]) -> pa.Table:
    """Step rows -> a table of STEP_SCHEMA. Heightmaps go in straight from numpy: Python lists of
    every cell would cost more memory and time than everything else in a shard."""
    index = STEP_SCHEMA.get_field_index("heightmap_mm")
    plain = STEP_SCHEMA.remove(index)
    table = pa.Table.from_pylist(
        [{k: v for k, v in r.items() if k != "heightmap_mm"} for r in rows], schema=plain
    )
    maps = [np.asarray(r["heightmap_mm"], dtype=np.int32) for r in rows]
    nx = np.array([m.shape[0] for m in maps], dtype=np.int64)
    ny = np.repeat(np.array([m.shape[1] for m in maps], dtype=np.int64), nx)
    values = np.concatenate([m.ravel() for m in maps]) if maps else np.zeros(0, np.int32)
    inner = pa.ListArray.from_arrays(
        pa.array(np.r_[0, np.cumsum(ny)].astype(np.int32)), pa.array(values)
    )
    outer = pa.ListArray.from_arrays(pa.array(np.r_[0, np.cumsum(nx)].astype(np.int32)), inner)
    return table.add_column(index, STEP_SCHEMA.field(index), outer)


def episodes_table(rows: list[dict[str, Any]]) -> pa.Table:
    return pa.Table.from_pylist(rows, schema=EPISODE_SCHEMA)


def episode_row(trajectory: Trajectory) -> dict[str, Any]:
    case = trajectory.case
    g = case.generator
    m = trajectory.metrics
    return {
        "episode_id": case.episode_id,
        "difficulty": case.difficulty,
        "case_seed": case.seed,
        "user_seed": g.get("user_seed"),
        "slot": g.get("slot"),
        "attempt": g.get("attempt"),
        "layout": g.get("layout"),
        "anchor": g.get("anchor"),
        "first_cell": g.get("first_cell"),
        "container_size_cm": [_cm(v) for v in case.container.size_mm],
        "buffer_size": case.buffer_size,
        "n_objects": len(case.objects),
        "n_layers": g.get("n_layers"),
        "stack_height_cm": g.get("stack_height_cm"),
        "layer_heights_cm": g.get("layer_heights_cm"),
        "n_rotated": sum(p.rotation for p in case.gt_plan or ()),
        "backend": trajectory.backend,
        "run_seed": trajectory.run_seed,
        "success_ratio": m.success_ratio,
        "compactness": m.compactness,
        "overall": m.overall,
        "max_height_mm": m.max_height_mm,
        "settle_steps": m.settle_steps,
        "case_json": json.dumps(case_to_dict(case), separators=(",", ":"), sort_keys=True),
    }


# -- SFT export -------------------------------------------------------------------------------


def shown_items(row_shown: Sequence[dict[str, Any]]) -> tuple[ShownItem, ...]:
    return tuple(
        ShownItem(
            shown_index=s["object_id"],
            internal_id=s["internal_id"],
            size_mm=tuple(round(v * 10) for v in s["size_cm"]),  # type: ignore[arg-type]
            size_cells=tuple(s["size_cells"]),
            type_id=s["type_id"],
        )  # type: ignore[arg-type]
        for s in row_shown
    )


def container_of(row: dict[str, Any]) -> Container:
    size = tuple(round(v * 10) for v in row["container_size_cm"])
    xy, z = (round(v * 10) for v in row["grid_cell_size_cm"])
    return Container(size, xy, z)  # type: ignore[arg-type]


# -- dataset card -----------------------------------------------------------------------------


def _case_settings_note(info: DatasetInfo) -> str:
    """A paragraph on the arrival order / layout family when not the defaults (else "", so the
    cards of datasets made before those options keep their bytes)."""
    raw_case = info.generator_config.get("case")
    case = raw_case if isinstance(raw_case, dict) else {}
    notes = []
    if case.get("layout") == "random":
        notes.append(
            "Cases of the random layout family: independently drawn boxes with no perfect\n"
            "layout, not validated; each episode is the teacher's closed-loop run.\n"
        )
    if case.get("layout") == "rs":
        notes.append(
            "Cases of the rs layout family: boxes drawn i.i.d. from 64 types (sides 2-5 units,\n"
            "Zhao et al. 2021's RS), no perfect layout, not validated; each episode is the\n"
            "teacher's closed-loop run.\n"
        )
    if case.get("layout") == "cut":
        notes.append(
            "Cases of the cut layout family: the stack cuboid cut recursively on the grid\n"
            "(Zhao et al. 2021's CUT), a perfect packing of mixed heights.\n"
        )
    if case.get("order", "removal") != "removal":
        notes.append(f"Arrival order: {case['order']} (see docs/datagen.md).\n")
    return "".join(notes) + ("\n" if notes else "")


def _sft_config(info: DatasetInfo) -> str:
    """The card's ``sft`` config (the export's conversations) when the dataset has one."""
    if info.files.sft is None or not info.files.sft.endswith(".parquet"):
        return ""
    return f'- config_name: sft\n  data_files: "{info.files.sft}"\n'


def dataset_card(info: DatasetInfo) -> str:
    """README.md of a dataset: the YAML header lets ``datasets.load_dataset(DIR, name)`` work."""
    counts = info.counts
    return (
        "---\n"
        "configs:\n"
        "- config_name: steps\n"
        "  default: true\n"
        f'  data_files: "{STEPS_DIR}/*.parquet"\n'
        "- config_name: episodes\n"
        f'  data_files: "{EPISODES_DIR}/*.parquet"\n'
        f"{_sft_config(info)}"
        "---\n\n"
        f"# {info.name}\n\n"
        "Closed-loop bin-packing trajectories made by packlab's layout-first data engine: perfect\n"
        "layouts, a placement order from reverse removal, each replayed through the closed loop\n"
        f"({info.validation_backend}) and kept only when every step is valid and\n"
        "Overall >= the threshold in meta/info.json.\n\n"
        f"{_case_settings_note(info)}"
        f"Episodes: {counts.episodes}; steps: {counts.steps}. Format {info.format_version}.\n\n"
        "```python\n"
        "import datasets\n"
        f'steps = datasets.load_dataset("parquet", data_files="{STEPS_DIR}/*.parquet", '
        'split="train")\n'
        "```\n\n"
        "The `sft` config holds one conversation per episode (`messages` and `images`, the PNGs\n"
        "embedded), which TRL's SFTTrainer reads as it is:\n"
        '`datasets.load_dataset(DIR, "sft", split="train")`.\n'
        "The `image` column of the steps names PNGs relative to this directory.\n"
        "Heightmap images: x along columns (left to right), y along rows (top to bottom), "
        "cell (0, 0)\n"
        "top-left; colour is absolute height from the floor to the container rim.\n"
    )
