"""What the ``packlab serve`` command does (its options: :mod:`packlab.cli.serve`).

Two engines:

- ``packlab`` (default; also ``python -m packlab.vlm.serve``): packlab's own small server
  (:mod:`packlab.vlm.serve.server`), one answer at a time; the offline test server for tiny
  models and quick trials (vlm extra);
- ``vllm``: starts ``vllm serve`` with the flags packing needs
  (:mod:`packlab.vlm.serve.vllm_command`) and prints the ``packlab bench`` command that plays
  the served model (vllm extra, Linux with a GPU); ``--print-command`` prints both and starts
  nothing. This is the serving path for real checkpoints.

Importing this module imports no torch: the model's side (:mod:`packlab.vlm.serve.model_answers`)
is imported when the command runs.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

from packlab.core.errors import ConfigError
from packlab.vlm.extra import VLM_EXTRA_HINT, import_torch_side, missing_extra
from packlab.vlm.prompt.render import PROMPT_VERSION
from packlab.vlm.serve.protocol import MAX_TOKENS_LIMIT
from packlab.vlm.serve.server import serve
from packlab.vlm.serve.vllm_command import VllmSettings, bench_argv, shell_text, vllm_argv

#: Answers of a local model (vlm extra), imported when the command runs.
MODEL_ANSWERS_MODULE = "packlab.vlm.serve.model_answers"
DEFAULT_MODEL = "tiny:qwen3_5:tiny"
DEFAULT_MAX_NEW_TOKENS = 64
#: Written beside a checkpoint that packlab saved (``packlab.vlm.model.checkpoint``, which
#: imports torch): its training settings.
PACKLAB_META = "packlab_model.json"
VLLM_EXTRA_HINT = (
    "vLLM is not installed (no `vllm` command on PATH): pip install -e '.[vllm]' on Linux with "
    "a CUDA GPU, or add --print-command to print the command line without starting it"
)


def served_name(model: str) -> str:
    """The name a model is served under by default: a ``tiny:F:S`` spec as it is, a checkpoint
    by its directory's name (never the path, which would tell clients about the server's disk)."""
    if model.startswith("tiny:"):
        return model
    return Path(model).resolve().name or "packlab-model"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "checkpoint",
        nargs="?",
        metavar="MODEL",
        help="the model, as --model (for vLLM: a checkpoint directory or a Hugging Face model id)",
    )
    parser.add_argument(
        "--model",
        default=None,
        help=f"checkpoint directory or tiny:<family>:<size> (default: {DEFAULT_MODEL}, "
        "a tiny random model)",
    )
    parser.add_argument(
        "--served-name",
        default=None,
        help="the model's name in /v1/models and in answers, which endpoint:model names "
        "(default: the checkpoint directory's name, or the tiny:F:S spec)",
    )
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument(
        "--max-new-tokens",
        type=int,
        default=None,
        help=f"packlab engine: the most tokens an answer has (default {DEFAULT_MAX_NEW_TOKENS}); "
        "under vLLM the endpoint's max_tokens sets it per request",
    )


def _model(args: argparse.Namespace) -> str | None:
    """The model named by MODEL or --model (None: neither)."""
    if args.checkpoint is not None and args.model is not None and args.checkpoint != args.model:
        raise ConfigError(
            f"MODEL {args.checkpoint!r} and --model {args.model!r}: name the model once"
        )
    return args.checkpoint if args.checkpoint is not None else args.model


def run_server(args: argparse.Namespace) -> int:
    """Serve the model with packlab's own server until interrupted."""
    model = _model(args) or DEFAULT_MODEL
    if not model.startswith("tiny:") and not (Path(model) / "config.json").is_file():
        raise ConfigError(
            f"--model {model!r}: not a checkpoint directory (no config.json) "
            "and not tiny:<family>:<size>"
        )
    if not 0 <= args.port <= 65535:
        raise ConfigError(f"--port {args.port}: must be in [0, 65535] (0: any free port)")
    max_new_tokens = DEFAULT_MAX_NEW_TOKENS if args.max_new_tokens is None else args.max_new_tokens
    if not 1 <= max_new_tokens <= MAX_TOKENS_LIMIT:
        raise ConfigError(f"--max-new-tokens {max_new_tokens}: must be in [1, {MAX_TOKENS_LIMIT}]")
    name = args.served_name or served_name(model)
    try:
        model_answers = import_torch_side(MODEL_ANSWERS_MODULE)
    except ModuleNotFoundError as e:
        if missing_extra(e):
            raise ConfigError(VLM_EXTRA_HINT) from None
        raise
    answer_fn = model_answers.model_answer_fn(model, max_new_tokens)
    try:
        server = serve(answer_fn, args.host, args.port, model_name=name)
    except (OSError, OverflowError) as e:  # port in use, no such address, port out of range
        reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        raise ConfigError(
            f"--host {args.host} --port {args.port}: cannot listen there ({reason})"
        ) from None
    print(f"serving {name!r} at {server.base_url} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    return 0


# -- --engine vllm -----------------------------------------------------------------------------
def is_hub_id(model: str) -> bool:
    """Whether ``model`` reads as a Hugging Face model id (``owner/name``) rather than a path."""
    parts = model.split("/")
    return (
        len(parts) == 2
        and all(parts)
        and not model.startswith((".", "~"))
        and not Path(model).exists()
    )


def checkpoint_settings(model: str) -> dict[str, Any]:
    """What a packlab-trained checkpoint was trained with (``history``, ``image``,
    ``template_kwargs``; {} for any other model); ConfigError for a checkpoint that cannot be
    served as chat: a candidate-mode (pointer) model, or one trained on another prompt."""
    path = Path(model) / PACKLAB_META
    if not path.is_file():
        return {}
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise ConfigError(f"{path}: not readable as JSON ({e})") from None
    if not isinstance(meta, dict):
        raise ConfigError(f"{path}: expected a JSON object")
    if meta.get("action_format") == "candidate":
        raise ConfigError(
            f"MODEL {model!r}: a candidate-mode checkpoint answers with its pointer head, not "
            "as chat; play it with --policies vlm --policy-arg vlm:model=DIR"
        )
    trained_with = meta.get("prompt_version")
    if trained_with is not None and trained_with != PROMPT_VERSION:
        raise ConfigError(
            f"MODEL {model!r}: trained with prompt {trained_with!r}, the endpoint policy "
            f"renders {PROMPT_VERSION!r}"
        )
    sft = meta.get("sft_config") or {}
    keys = ("history", "image", "template_kwargs")
    return {k: sft[k] for k in keys if isinstance(sft, dict) and sft.get(k) not in (None, {})}


def vllm_settings(args: argparse.Namespace, options: dict[str, Any]) -> VllmSettings:
    """The settings of ``--engine vllm``: the model and address from the command line, the
    vLLM ``options`` given (fields of :class:`VllmSettings`), and what the checkpoint was
    trained with for the options left unset."""
    model = _model(args)
    if model is None:
        raise ConfigError(
            "--engine vllm needs the model: packlab serve --engine vllm MODEL_DIR "
            "(a checkpoint directory or a Hugging Face model id)"
        )
    if model.startswith("tiny:"):
        raise ConfigError(
            f"MODEL {model!r}: tiny random models are served by --engine packlab; "
            "vLLM serves checkpoint directories and Hugging Face model ids"
        )
    hub = is_hub_id(model)
    if not hub and not (Path(model) / "config.json").is_file():
        raise ConfigError(
            f"MODEL {model!r}: not a checkpoint directory (no config.json) and not a "
            "Hugging Face model id (owner/name)"
        )
    if args.max_new_tokens is not None:
        raise ConfigError(
            f"--max-new-tokens {args.max_new_tokens}: an option of --engine packlab; under "
            "vLLM the bench's endpoint:max_tokens sets an answer's length"
        )
    fields = dict(options)
    # packlab's own checkpoints record their prompt settings; a model trained on the
    # reference's data has no such card.
    packlab_prompt = fields.get("prompt", "packlab") == "packlab"
    card = checkpoint_settings(model) if packlab_prompt and not hub else {}
    for key, value in card.items():
        if fields.get(key) is None:
            fields[key] = value
    name = args.served_name or served_name(model)
    return VllmSettings(model=model, served_name=name, host=args.host, port=args.port, **fields)


def run_vllm(settings: VllmSettings, print_only: bool) -> int:
    """Print the ``vllm serve`` and ``packlab bench`` commands (``print_only``), or print the
    bench command and start vLLM in this process's place."""
    serve_argv = vllm_argv(settings)
    bench_text = shell_text(bench_argv(settings))
    if print_only:
        print("# serve the model (vLLM):")
        print(shell_text(serve_argv))
        print("# then, once it answers, play the bench against it:")
        print(bench_text, flush=True)
        return 0
    exe = shutil.which("vllm")
    if exe is None:
        raise ConfigError(VLLM_EXTRA_HINT)
    print(f"starting {shell_text(serve_argv)}", flush=True)
    print(f"once it answers, play the bench against it:\n{bench_text}", flush=True)
    # vLLM takes this process's place: Ctrl-C and a scheduler's SIGTERM reach it directly.
    os.execv(exe, serve_argv)
    return 0  # not reached


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m packlab.vlm.serve",
        description="Serve a packing VLM over an OpenAI-compatible "
        "/v1/chat/completions API (a test server).",
    )
    add_arguments(parser)
    return run_server(parser.parse_args(argv))
