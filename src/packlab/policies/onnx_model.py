"""A learned policy's network as an ONNX file, played with ONNX Runtime (core install, no torch).

A model directory that can play without torch holds, beside its training checkpoint, one or
more ``<name>.onnx`` graphs and ``onnx.json`` (:class:`OnnxCard`): the format version, which
graphs it holds with their input and output names, the opset, the torch version that exported
them and the sha256 of the checkpoint files they were exported from, so a checkpoint retrained
after its export is caught (:func:`stale_sources`) instead of playing the old weights.

Exporters (``packlab export onnx``, the vlm and rl extras) write the card with
:func:`write_card`; policies open graphs with :func:`open_graph`, which raises a
:class:`~packlab.core.errors.ConfigError` naming the directory, file and field for every way
this can fail: no ONNX Runtime, no card, another format version, a graph missing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import json
import platform
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from packlab.core.errors import ConfigError
from packlab.core.fileio import file_sha256, write_atomically

#: The version of ``onnx.json`` and of the graphs' input/output contract. Bump it when either
#: changes; a directory of another version is refused with the command that re-exports it.
ONNX_FORMAT = "packlab-onnx-1"
CARD_FILE = "onnx.json"
ORT_HINT = "ONNX Runtime is not installed (it is a core dependency): pip install onnxruntime"


@dataclass(frozen=True, slots=True)
class GraphSpec:
    """One exported graph: its file (relative to the model directory) and its I/O names."""

    file: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class OnnxCard:
    """What ``onnx.json`` says (module docstring)."""

    kind: str  # "pointer" (the candidate-mode VLM) or "rl-agent"
    graphs: dict[str, GraphSpec]
    sources: dict[str, str]  # checkpoint file (relative) -> sha256 when exported
    opset: int
    exported_with: str  # e.g. "torch 2.13.0"
    extra: dict[str, Any] = field(default_factory=dict)  # kind-specific settings
    format: str = ONNX_FORMAT


def write_card(directory: Path, card: OnnxCard) -> Path:
    """Write ``directory/onnx.json`` atomically (after the graphs, so a card never names a graph
    that is not there yet)."""
    for spec in card.graphs.values():
        if not (directory / spec.file).is_file():
            raise ConfigError(f"{directory / spec.file}: graph file missing; export it first")
    text = json.dumps(asdict(card), indent=1, sort_keys=True) + "\n"
    return write_atomically(directory / CARD_FILE, lambda fh: fh.write(text.encode()))


def has_onnx(directory: Path) -> bool:
    return (Path(directory) / CARD_FILE).is_file()


def export_hint(directory: Path) -> str:
    return f"run: packlab export onnx {directory} (needs the extra it was trained with)"


def read_card(directory: Path, kind: str) -> OnnxCard:
    """The card of ``directory``, checked for format version and kind."""
    path = Path(directory) / CARD_FILE
    try:
        raw = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{directory}: no {CARD_FILE} (no ONNX export); {export_hint(directory)}")
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: not a readable ONNX card ({exc}); {export_hint(directory)}")
    if not isinstance(raw, dict) or raw.get("format") != ONNX_FORMAT:
        got = raw.get("format") if isinstance(raw, dict) else raw
        raise ConfigError(
            f"{path}: field 'format' = {got!r}: this packlab reads {ONNX_FORMAT!r}; "
            f"{export_hint(directory)}"
        )
    if raw.get("kind") != kind:
        raise ConfigError(f"{path}: field 'kind' = {raw.get('kind')!r}: expected {kind!r}")
    try:
        graphs = {
            name: GraphSpec(g["file"], tuple(g["inputs"]), tuple(g["outputs"]))
            for name, g in raw["graphs"].items()
        }
        return OnnxCard(
            kind=raw["kind"],
            graphs=graphs,
            sources=dict(raw.get("sources", {})),
            opset=int(raw["opset"]),
            exported_with=str(raw.get("exported_with", "")),
            extra=dict(raw.get("extra", {})),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"{path}: malformed ONNX card ({exc!r}); {export_hint(directory)}")


def stale_sources(directory: Path, card: OnnxCard) -> list[str]:
    """Checkpoint files whose content changed since the export (absent files are not stale:
    a directory may ship only its ONNX graphs)."""
    stale = []
    for rel, digest in card.sources.items():
        path = Path(directory) / rel
        if path.is_file() and file_sha256(path) != digest:
            stale.append(rel)
    return stale


# -- denormals ----------------------------------------------------------------------------------
#
# Denormal floats are flushed to zero while a graph runs, for speed: a causal mask's large
# negative logits make softmax produce denormals (ONNX Runtime's exp clamps its input near
# -88, just above float32's underflow), which x86 handles in microcode. The pointer LM's
# softmax took 21 of its ~35 ms a decision with them and 3 ms without, its scores
# bit-identical. The flags (MXCSR's flush-to-zero and denormals-are-zero) are the calling
# thread's floating-point state, so they are set around each run and the caller's state is put
# back after it: left set, they would change every float the program computes after the first
# model loads, MuJoCo's physics included (the test suite's property tests noticed). ONNX
# Runtime's own option (``session.set_denormal_as_zero``) sets them on the thread that creates
# the first such session, for good, so it is not used for that thread. Done through the C
# library's ``fegetenv``/``fesetenv``, whose ``fenv_t`` holds MXCSR at byte 28 on x86-64 glibc;
# anywhere else nothing is changed (slower there, same results).

_FENV_SIZE = 32
_MXCSR_OFFSET = 28
_FLUSH_BITS = 0x8040  # MXCSR: flush to zero (bit 15), denormals are zero (bit 6)


def _load_libm() -> Any:
    if not (sys.platform.startswith("linux") and platform.machine() == "x86_64"):
        return None
    name = ctypes.util.find_library("m")
    return ctypes.CDLL(name) if name else None


_LIBM = _load_libm()


def _fp_env() -> Any:
    """This thread's floating-point environment (a ``fenv_t``), or None where unsupported."""
    if _LIBM is None:
        return None
    env = ctypes.create_string_buffer(_FENV_SIZE)
    return env if _LIBM.fegetenv(env) == 0 else None


@contextmanager
def _fp_env_kept() -> Iterator[Any]:
    """Whatever the block does to this thread's floating-point environment is undone; yields
    the environment it restores (None where unsupported)."""
    saved = _fp_env()
    try:
        yield saved
    finally:
        if saved is not None:
            _LIBM.fesetenv(saved)


@contextmanager
def denormals_flushed() -> Iterator[None]:
    """Flush denormal floats to zero on this thread inside the block; the thread's previous
    floating-point environment is restored after it, whatever happens inside."""
    with _fp_env_kept() as saved:
        if saved is not None:
            flushed = bytearray(saved.raw)
            at = slice(_MXCSR_OFFSET, _MXCSR_OFFSET + 4)
            mxcsr = int.from_bytes(flushed[at], "little") | _FLUSH_BITS
            flushed[at] = mxcsr.to_bytes(4, "little")
            _LIBM.fesetenv(ctypes.create_string_buffer(bytes(flushed), _FENV_SIZE))
        yield


@dataclass(frozen=True, slots=True)
class Session:
    """An ``onnxruntime.InferenceSession`` whose runs flush denormals (:func:`denormals_flushed`):
    ``run(outputs, feed)`` and ``get_inputs()`` as ORT's own."""

    session: Any

    def run(self, outputs: Sequence[str] | None, feed: dict[str, Any]) -> list[Any]:
        with denormals_flushed():
            return list(self.session.run(outputs, feed))

    def get_inputs(self) -> list[Any]:
        return list(self.session.get_inputs())


def new_session(path: Path, threads: int | None = 1) -> Session:
    """An ONNX Runtime session on CPU with ``threads`` intra-op threads (one per bench worker by
    default, as the torch path) whose runs flush denormals."""
    try:
        import onnxruntime as ort
    except ModuleNotFoundError:
        raise ConfigError(f"{path}: {ORT_HINT}") from None
    options = ort.SessionOptions()
    if threads is not None:
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
    options.log_severity_level = 3  # errors only: ORT's warnings about unused initialisers
    # For the session's own pool threads (threads > 1); the thread creating the first such
    # session would keep the flags for good, so its environment is restored right after.
    options.add_session_config_entry("session.set_denormal_as_zero", "1")
    with _fp_env_kept():
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    return Session(session)


@dataclass(slots=True)
class OnnxGraph:
    """An open graph: ``run(**inputs)`` returns its outputs by name."""

    spec: GraphSpec
    session: Any

    def run(self, **inputs: Any) -> dict[str, Any]:
        missing = sorted(set(self.spec.inputs) - set(inputs))
        if missing:
            raise ConfigError(f"{self.spec.file}: inputs {missing} not given")
        feed = {name: inputs[name] for name in self.spec.inputs}
        values = self.session.run(list(self.spec.outputs), feed)
        return dict(zip(self.spec.outputs, values, strict=True))


def open_graphs(
    directory: Path, kind: str, names: Sequence[str], threads: int | None = 1
) -> tuple[OnnxCard, dict[str, OnnxGraph]]:
    """The card and the named graphs of ``directory``, ready to run (module docstring)."""
    directory = Path(directory)
    card = read_card(directory, kind)
    stale = stale_sources(directory, card)
    if stale:
        raise ConfigError(
            f"{directory / CARD_FILE}: exported from other weights ({', '.join(stale)} changed "
            f"since); {export_hint(directory)}"
        )
    graphs = {}
    for name in names:
        spec = card.graphs.get(name)
        if spec is None:
            raise ConfigError(
                f"{directory / CARD_FILE}: field 'graphs' has no {name!r}; {export_hint(directory)}"
            )
        path = directory / spec.file
        if not path.is_file():
            raise ConfigError(f"{path}: ONNX graph missing; {export_hint(directory)}")
        graphs[name] = OnnxGraph(spec, new_session(path, threads))
    return card, graphs
