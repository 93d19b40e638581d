"""The ``packlab serve`` command (also ``python -m packlab.vlm.serve``): serve a checkpoint, or a
tiny random model, over the OpenAI-compatible API of :mod:`packlab.vlm.serve.server`.

Importing this module imports no torch: the model's side (:mod:`packlab.vlm.serve.model_answers`)
is imported when the command runs.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from packlab.core.errors import ConfigError
from packlab.vlm.extra import VLM_EXTRA_HINT, import_torch_side, missing_extra
from packlab.vlm.serve.protocol import MAX_TOKENS_LIMIT
from packlab.vlm.serve.server import serve

#: Answers of a local model (vlm extra), imported when the command runs.
MODEL_ANSWERS_MODULE = "packlab.vlm.serve.model_answers"


def served_name(model: str) -> str:
    """The name a model is served under by default: a ``tiny:F:S`` spec as it is, a checkpoint
    by its directory's name (never the path, which would tell clients about the server's disk)."""
    if model.startswith("tiny:"):
        return model
    return Path(model).resolve().name or "packlab-model"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model",
        default="tiny:qwen3_5:tiny",
        help="checkpoint directory or tiny:<family>:<size> (default: tiny random)",
    )
    parser.add_argument(
        "--served-name",
        default=None,
        help="the model's name in /v1/models and in answers (default: the checkpoint "
        "directory's name, or the tiny:F:S spec)",
    )
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument("--max-new-tokens", type=int, default=64)


def run_server(args: argparse.Namespace) -> int:
    """Serve ``args.model`` until interrupted (the ``packlab serve`` command)."""
    model = args.model
    if not model.startswith("tiny:") and not (Path(model) / "config.json").is_file():
        raise ConfigError(
            f"--model {model!r}: not a checkpoint directory (no config.json) "
            "and not tiny:<family>:<size>"
        )
    if not 0 <= args.port <= 65535:
        raise ConfigError(f"--port {args.port}: must be in [0, 65535] (0: any free port)")
    if not 1 <= args.max_new_tokens <= MAX_TOKENS_LIMIT:
        raise ConfigError(
            f"--max-new-tokens {args.max_new_tokens}: must be in [1, {MAX_TOKENS_LIMIT}]"
        )
    name = args.served_name or served_name(model)
    try:
        model_answers = import_torch_side(MODEL_ANSWERS_MODULE)
    except ModuleNotFoundError as e:
        if missing_extra(e):
            raise ConfigError(VLM_EXTRA_HINT) from None
        raise
    answer_fn = model_answers.model_answer_fn(model, args.max_new_tokens)
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m packlab.vlm.serve",
        description="Serve a packing VLM over an OpenAI-compatible "
        "/v1/chat/completions API (a test server).",
    )
    add_arguments(parser)
    return run_server(parser.parse_args(argv))
