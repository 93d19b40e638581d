"""``packlab export sft DATASET``: a dataset's SFT conversations in a trainer's format
(:mod:`packlab.datagen.sft_export`).

``packlab export onnx RUN_DIR``: a trained learned policy's networks as ONNX graphs, so it
plays on ONNX Runtime from the core install (no torch). Exporting needs the extra the model was
trained with (torch); the directory kind is read from its files:

- ``card.json`` (an RL agent, irbpp or tapnet): :mod:`packlab.rl.onnx_export` (rl extra);
- ``packlab_model.json`` with ``action_format`` = candidate (the pointer VLM):
  :mod:`packlab.vlm.candidate.onnx_export` (vlm extra).

Both write ``<name>.onnx`` graphs and ``onnx.json`` into the directory itself
(:mod:`packlab.policies.onnx_model`) and check, on generated states, that the ONNX graphs pick
the same placements as torch before the card is written.
"""

from __future__ import annotations

import argparse
import importlib
import json
from pathlib import Path
from typing import Any

from packlab.core.errors import ConfigError

#: Directory marker file -> the module whose ``export_onnx(directory, check_states)`` exports it.
EXPORTERS = (
    ("card.json", "packlab.rl.onnx_export", "rl"),
    ("packlab_model.json", "packlab.vlm.candidate.onnx_export", "vlm"),
)
#: What ``packlab export sft`` runs (imported when it does).
SFT_EXPORT_MODULE = "packlab.datagen.sft_export"
#: Generated observations on which the export compares torch's and ONNX's decisions.
DEFAULT_CHECK_STATES = 64
#: The pointer VLM's tie tolerance (``packlab.vlm.candidate.onnx_export.TIE_TOLERANCE``, which
#: imports torch; a test checks the two agree): torch scores closer than this are a tie.
TIE_TOLERANCE = 1e-4


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Write ONNX graphs and onnx.json beside a trained model's checkpoint "
        "(an RL agent directory or a candidate-mode VLM directory), after checking that "
        "ONNX Runtime picks the same placements as torch on generated states."
    )
    sub = p.add_subparsers(dest="format", required=True)
    onnx = sub.add_parser("onnx", help="ONNX Runtime graphs (docs/onnx.md)")
    onnx.add_argument("model_dir", type=Path, help="a model directory (RUN/best, RUN/final, ...)")
    onnx.add_argument(
        "--check-states",
        type=int,
        default=DEFAULT_CHECK_STATES,
        help="generated observations on which torch and ONNX must agree (0: skip the check)",
    )
    onnx.set_defaults(func=run_export)
    sft = sub.add_parser(
        "sft",
        help="a dataset's SFT conversations: hf (TRL, datasets) or verl (the reference's schema)",
        description="Rewrite the SFT export of a PackData directory from its step shards: one "
        "conversation per episode (or per window of --window steps), the loss on every answer.",
    )
    sft.add_argument("dataset", type=Path, help="a PackData dataset directory")
    sft.add_argument(
        "--format",
        dest="sft_format",
        default="hf",
        help="hf: messages + embedded images, read by datasets and TRL (DIR/sft); verl: the "
        "reference's verl schema, images by path (DIR/sft-verl); default %(default)s",
    )
    sft.add_argument(
        "--window",
        type=int,
        default=0,
        help="steps per conversation; longer episodes are cut into windows, every step a target "
        "once (0: whole episodes); default %(default)s",
    )
    sft.add_argument("--out", type=Path, default=None, help="output directory (see --format)")
    sft.set_defaults(func=run_export_sft)


def run_export_sft(args: argparse.Namespace) -> int:
    """``packlab export sft``: files in, files out (the step shards are only read)."""
    exporter = importlib.import_module(SFT_EXPORT_MODULE)
    if args.sft_format not in exporter.SFT_FORMATS:
        choices = ", ".join(exporter.SFT_FORMATS)
        raise ConfigError(f"format = {args.sft_format!r}: choose from {choices}")
    written = exporter.export_sft(args.dataset, args.sft_format, args.window, args.out)
    print(f"wrote {len(written)} file(s) under {written[0].parent}")
    return 0


def exporter_for(directory: Path) -> tuple[str, str]:
    """(module, extra) exporting ``directory``, or a ConfigError naming what is there."""
    if not directory.is_dir():
        raise ConfigError(f"model_dir = {str(directory)!r}: not a directory")
    for marker, module, extra in EXPORTERS:
        path = directory / marker
        if not path.is_file():
            continue
        if marker == "packlab_model.json":
            fmt = json.loads(path.read_text()).get("action_format")
            if fmt != "candidate":
                raise ConfigError(
                    f"{path}: field 'action_format' = {fmt!r}: only candidate-mode (pointer) "
                    f"models export to ONNX; text-answer VLMs play through transformers"
                )
        return module, extra
    raise ConfigError(
        f"model_dir = {str(directory)!r}: neither an RL agent (card.json) nor a "
        f"candidate-mode VLM (packlab_model.json)"
    )


def run_export(args: argparse.Namespace) -> int:
    if args.check_states < 0:
        raise ConfigError(f"check-states = {args.check_states}: must be >= 0")
    module_name, extra = exporter_for(args.model_dir)
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        raise ConfigError(
            f"exporting {args.model_dir} needs the {extra} extra ({exc.name} missing): "
            f"pip install torch==2.13.0, then pip install -e '.[{extra}]'"
        ) from None
    card = module.export_onnx(args.model_dir, check_states=args.check_states)
    for name, spec in card.graphs.items():
        print(f"{name}: {args.model_dir / spec.file}")
    print(f"card: {args.model_dir / 'onnx.json'}")
    print(check_summary(card.kind, card.extra))
    return 0


def check_summary(kind: str, extra: dict[str, Any]) -> str:
    """One line on the torch-vs-ONNX check the export ran (kept in onnx.json's ``extra``): what
    was compared, on how many states, the largest difference, and that it passed (a failed
    check is the command's one-line error and writes no card). docs/onnx.md explains it."""
    if kind == "rl-agent":
        states = int(extra.get("check_states", 0))
        if not states:
            return "check: skipped (--check-states 0): ONNX Runtime was not compared with torch"
        return (
            f"check: torch vs ONNX Runtime, the greedy row on {states} generated states: "
            f"same row on all {states}; max |logit difference| "
            f"{float(extra['max_abs_logit_diff']):.2e}: pass"
        )
    check = extra.get("check", {})
    states = int(check.get("states", 0))
    if not states:
        return "check: skipped (--check-states 0): ONNX Runtime was not compared with torch"
    ties = int(check.get("ties", 0))
    tied = f", {ties} picks between placements tied within {TIE_TOLERANCE:g}" if ties else ""
    return (
        f"check: torch vs ONNX Runtime, the listed pick on {states} generated states: "
        f"same pick on {int(check.get('argmax_equal', 0))}{tied}; max |score difference| "
        f"{float(check.get('max_abs_diff', 0.0)):.2e}: pass"
    )
