"""Labelled states on disk: what candidate-mode training reads (one JSONL line per step).

A state holds what the model is shown at one step (container, heightmap, shown boxes, the
proposer's listed placements) and the teacher's pick among the listed ones. Text is composed
from it at training time (:mod:`.compose`), so the file grows linearly with the number of steps:
no history is repeated and no prompt text is stored. The heightmap is stored as zlib-compressed
little-endian int32 millimetres in base64 (a hard state is about 0.3 KB).

``label`` is -1 when the teacher's action is not among the listed placements (the raw oracle;
the ``plan`` teacher adds its own pick to the list instead, ``teacher_added``); such states are
kept for counting and skipped by the trainer. ``soft`` is the teacher's preference over the
listed lines when it has one (:class:`packlab.policies.listed.TeacherLabel`), else empty.

Format ``packlab-states-2`` added ``soft`` and ``teacher_added``; files of format 1 read as
before (empty ``soft``, nothing added). Format ``packlab-states-3`` added ``case_sha256``, the
content fingerprint of the state's case (:func:`packlab.cases.fingerprint.case_fingerprint`), so
that a trainer can check a row against its case and against the bench suites by content, not
by the case id alone (:mod:`packlab.vlm.candidate.states_guard`); older files read with it
empty, and the trainers refuse them (collect such states again to give them the field).
"""

from __future__ import annotations

import base64
import zlib
from collections.abc import Iterable, Iterator
from pathlib import Path

import msgspec
import numpy as np

from packlab.core.errors import ConfigError
from packlab.core.types import Container, Observation, ShownItem
from packlab.policies.candidates import Candidate

STATES_FORMAT = "packlab-states-3"
#: Formats this reader accepts (older ones lack fields that have defaults).
READABLE_FORMATS = ("packlab-states-1", "packlab-states-2", STATES_FORMAT)
STATES_FILE = "states.jsonl"


class StoredShown(msgspec.Struct, frozen=True, array_like=True):
    shown_index: int
    # int | str as core.types.InternalId: reference files name objects by string.
    internal_id: int | str
    size_mm: tuple[int, int, int]
    size_cells: tuple[int, int, int]
    type_id: int


class StoredPlacement(msgspec.Struct, frozen=True, array_like=True):
    """:class:`packlab.policies.candidates.Candidate`, field for field."""

    index: int
    object_index: int
    rotation: int
    x: int
    y: int
    fx: int
    fy: int
    z_mm: int
    top_mm: int
    support_pct: int
    flush_pct: int
    void_mm: int


class LabelledState(msgspec.Struct, frozen=True, kw_only=True):
    format: str
    case_id: str
    difficulty: str
    step: int
    remaining: int
    container_mm: tuple[int, int, int]
    cell_xy_mm: int
    cell_z_mm: int
    heightmap: str  # base64(zlib(int32 LE)), shape = container cells
    shown: tuple[StoredShown, ...]
    listed: tuple[StoredPlacement, ...]
    teacher: str
    label: int  # index into listed; -1: the teacher's action is not listed
    source: str  # "teacher" or "student-r<round>" (who chose the actions that led here)
    soft: tuple[float, ...] = ()  # teacher's preference over listed (sums to 1); empty: label
    teacher_added: bool = False  # the last listed line is the teacher's pick, added to the list
    #: The case's content fingerprint (sha256 hex); empty in files of formats 1 and 2.
    case_sha256: str = ""


def encode_heightmap(heightmap: np.ndarray) -> str:
    raw = np.ascontiguousarray(heightmap, dtype="<i4").tobytes()
    return base64.b64encode(zlib.compress(raw, 6)).decode("ascii")


def decode_heightmap(text: str, cells: tuple[int, int]) -> np.ndarray:
    raw = zlib.decompress(base64.b64decode(text))
    return np.frombuffer(raw, dtype="<i4").reshape(cells).astype(np.int32)


def make_state(
    case_id: str,
    difficulty: str,
    observation: Observation,
    listed: Iterable[Candidate],
    teacher: str,
    label: int,
    source: str,
    soft: Iterable[float] = (),
    teacher_added: bool = False,
    case_sha256: str = "",
) -> LabelledState:
    c = observation.container
    return LabelledState(
        format=STATES_FORMAT,
        case_id=case_id,
        difficulty=difficulty,
        step=observation.step_index,
        remaining=observation.remaining_known(),
        container_mm=c.size_mm,
        cell_xy_mm=c.cell_xy_mm,
        cell_z_mm=c.cell_z_mm,
        heightmap=encode_heightmap(observation.heightmap),
        shown=tuple(
            StoredShown(s.shown_index, s.internal_id, s.size_mm, s.size_cells, s.type_id)
            for s in observation.shown
        ),
        listed=tuple(_as_struct(p) for p in listed),
        teacher=teacher,
        label=label,
        source=source,
        soft=tuple(float(v) for v in soft),
        teacher_added=teacher_added,
        case_sha256=case_sha256,
    )


def _as_struct(c: Candidate) -> StoredPlacement:
    return StoredPlacement(
        c.index, c.object_index, c.rotation, c.x, c.y, c.fx, c.fy,
        c.z_mm, c.top_mm, c.support_pct, c.flush_pct, c.void_mm,
    )  # fmt: skip


def observation_of(state: LabelledState) -> Observation:
    """The observation the state was recorded from (history left out: not stored)."""
    container = Container(state.container_mm, state.cell_xy_mm, state.cell_z_mm)
    return Observation(
        step_index=state.step,
        container=container,
        heightmap=decode_heightmap(state.heightmap, container.cells),
        shown=tuple(
            ShownItem(
                s.shown_index,
                s.internal_id,
                (s.size_mm[0], s.size_mm[1], s.size_mm[2]),
                (s.size_cells[0], s.size_cells[1], s.size_cells[2]),
                s.type_id,
            )
            for s in state.shown
        ),
        remaining=state.remaining,
    )


def listed_of(state: LabelledState) -> tuple[Candidate, ...]:
    return tuple(Candidate(*msgspec.structs.astuple(p)) for p in state.listed)


_ENCODER = msgspec.json.Encoder()
_DECODER = msgspec.json.Decoder(LabelledState)


def append_states(path: Path, states: Iterable[LabelledState]) -> int:
    """Append states to a JSONL file (one flush per call: a crash loses at most this call's)."""
    lines = [_ENCODER.encode(s) + b"\n" for s in states]
    with open(path, "ab") as f:
        f.writelines(lines)
    return len(lines)


def read_states(path: Path) -> Iterator[LabelledState]:
    """The states of a file, checked: a bad line is a ConfigError naming file, line and field.
    A last line cut short by a crash is skipped (the writer appends whole lines)."""
    with open(path, "rb") as f:
        lines = f.read().split(b"\n")
    for n, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            state = _DECODER.decode(line)
        except msgspec.ValidationError as exc:
            raise ConfigError(f"{path}:{n}: {exc}") from None
        except msgspec.DecodeError as exc:
            if n == len(lines):  # torn last line: the writer crashed mid-line
                return
            raise ConfigError(f"{path}:{n}: not a JSON state ({exc})") from None
        if state.format not in READABLE_FORMATS:
            expected = " or ".join(repr(f) for f in READABLE_FORMATS)
            raise ConfigError(f"{path}:{n}: format = {state.format!r}: expected {expected}")
        if state.soft and len(state.soft) != len(state.listed):
            raise ConfigError(
                f"{path}:{n}: soft has {len(state.soft)} values for {len(state.listed)} listed"
            )
        yield state


def shuffled(state: LabelledState, seed: int = 0) -> LabelledState:
    """The state with its listed placements in a random order (renumbered) and the label moved
    with its placement. The order is fixed by (seed, case, step), so it is reproducible. Why: in
    the proposer's order, index 0 alone matches most teachers' picks, so a model can score well
    by position without reading a line; shuffled, only a line's content tells them apart."""
    rng = np.random.default_rng([seed, zlib.crc32(state.case_id.encode()), state.step])
    order = rng.permutation(len(state.listed))
    listed = tuple(
        msgspec.structs.replace(state.listed[int(o)], index=n) for n, o in enumerate(order)
    )
    label = int(np.flatnonzero(order == state.label)[0]) if state.label >= 0 else -1
    soft = tuple(state.soft[int(o)] for o in order) if state.soft else ()
    return msgspec.structs.replace(state, listed=listed, label=label, soft=soft)
