"""``packlab serve``: serve a packing VLM over an OpenAI-compatible chat-completions API for the
``endpoint`` policy. ``--engine packlab`` (default) is packlab's own small server, the offline
test server for tiny models (vlm extra); ``--engine vllm`` starts vLLM with the flags packing
needs, the serving path for real checkpoints (vllm extra)."""

from __future__ import annotations

import argparse
import json
import shlex
from typing import Any

from packlab.cli.options import add_field, command_options, config_kwargs
from packlab.core.errors import ConfigError
from packlab.vlm.serve import command  # no torch at import
from packlab.vlm.serve.vllm_command import PROMPTS, VllmSettings

#: Who generates the answers: packlab's own test server, or vLLM.
ENGINES = ("packlab", "vllm")
COMMAND = "serve"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Serve a model at http://HOST:PORT/v1 under --served-name (default: the checkpoint "
        "directory's name) for the endpoint policy (packlab bench --policies endpoint with "
        "base_url=http://HOST:PORT/v1) or any OpenAI client. --engine packlab (default) is "
        "packlab's own server, one answer at a time: the offline test server for tiny models "
        "(tiny:<family>:<size>) and quick trials of a checkpoint; it streams with stream=true "
        "and answers a malformed request 400 with a reason. --engine vllm is the serving path "
        "for real checkpoints: it starts vllm serve with the flags packing needs (images per "
        "request, context length, served name, batch size, the prompt protocol's chat-template "
        "switches) and prints the matching packlab bench command; --print-command prints both "
        "and starts nothing."
    )
    p.add_argument(
        "--engine",
        choices=ENGINES,
        default="packlab",
        help="packlab: packlab's own server, the offline test server for tiny models (vlm "
        "extra); vllm: vLLM, the serving path for real checkpoints (vllm extra); default packlab",
    )
    command.add_arguments(p)
    _add_vllm_arguments(p)
    p.set_defaults(func=run)


def _add_vllm_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``--engine vllm``: fields of :class:`VllmSettings`."""
    p.add_argument(
        "--print-command",
        action="store_true",
        help="vllm: print the vllm serve command and the matching packlab bench command; "
        "start nothing",
    )
    _add_context_options(p)
    _add_server_options(p)


def _add_context_options(p: argparse.ArgumentParser) -> None:
    """What the bench's requests will hold: protocol, history, images."""
    add_field(
        p,
        VllmSettings,
        "prompt",
        "--prompt",
        choices=PROMPTS,
        help="vllm: the prompt protocol the bench will send (endpoint:prompt); reference "
        "serves as the reference implementation serves its model; default {default}",
    )
    add_field(
        p,
        VllmSettings,
        "history",
        "--history",
        help="vllm: the context's history (endpoint:history); default: what the checkpoint was "
        "trained with, else full",
    )
    add_field(
        p,
        VllmSettings,
        "image",
        "--image",
        help="vllm: the context's images (endpoint:image); default: what the checkpoint was "
        "trained with, else heightmap",
    )
    add_field(
        p,
        VllmSettings,
        "max_past_steps",
        "--max-past-steps",
        metavar="N",
        help="vllm: the bench sends only the N most recent past steps (endpoint:max_past_steps), "
        "which caps the images per request; default: all",
    )
    add_field(
        p,
        VllmSettings,
        "max_steps",
        "--max-steps",
        metavar="N",
        help="vllm: the most steps an episode takes (its case's object count), which sizes the "
        "images per request; default {default}, the largest case of the bundled suites",
    )


def _add_server_options(p: argparse.ArgumentParser) -> None:
    """How vLLM serves: context, memory, batch, seed, caching, template, more flags."""
    add_field(
        p,
        VllmSettings,
        "max_model_len",
        "--max-model-len",
        metavar="TOKENS",
        help="vllm: the longest context served; default {default}",
    )
    add_field(
        p,
        VllmSettings,
        "gpu_memory_utilization",
        "--gpu-memory-utilization",
        metavar="FRACTION",
        help="vllm: the share of GPU memory vLLM takes; default {default}",
    )
    add_field(
        p,
        VllmSettings,
        "workers",
        "--workers",
        metavar="N",
        help="vllm: the bench's worker processes; default {default}",
    )
    add_field(
        p,
        VllmSettings,
        "concurrency",
        "--concurrency",
        metavar="N",
        help="vllm: episodes each bench worker plays at once; vLLM batches up to workers x N "
        "requests (--max-num-seqs); default {default}",
    )
    add_field(p, VllmSettings, "seed", "--seed", help="vllm: vLLM's seed; default {default}")
    add_field(
        p,
        VllmSettings,
        "prefix_caching",
        "--no-prefix-caching",
        help="vllm: turn prefix caching off (each step's context extends the previous one's, "
        "so the cache saves most of a prompt's work)",
    )
    add_field(
        p,
        VllmSettings,
        "trust_remote_code",
        "--trust-remote-code",
        help="vllm: run the checkpoint's own model code (always on under --prompt reference)",
    )
    add_field(
        p,
        VllmSettings,
        "template_kwargs",
        "--template-kwargs",
        parse=_json_object,
        metavar="JSON",
        help="vllm: the chat template's switches for requests that send none, e.g. "
        "'{\"enable_thinking\": false}'; default: what the checkpoint was trained with, or "
        "under --prompt reference the reference's",
    )
    add_field(
        p,
        VllmSettings,
        "extra_args",
        "--vllm-args",
        parse=_split_args,
        metavar="ARGS",
        help="vllm: more vllm serve arguments, passed last, e.g. "
        "--vllm-args='--tensor-parallel-size 2'",
    )


def _json_object(text: str) -> dict[str, Any]:
    try:
        value = json.loads(text)
    except json.JSONDecodeError as e:
        raise ConfigError(f"--template-kwargs {text!r}: not JSON ({e.msg})") from None
    if not isinstance(value, dict):
        raise ConfigError(f"--template-kwargs {text!r}: must be a JSON object")
    return value


def _split_args(text: str) -> tuple[str, ...]:
    try:
        return tuple(shlex.split(text))
    except ValueError as e:  # an unclosed quote
        raise ConfigError(f"--vllm-args {text!r}: {e}") from None


def given_vllm_options(args: argparse.Namespace) -> list[str]:
    """The ``--engine vllm`` options this command line gave."""
    given = [
        o.flags[0]
        for o in command_options(COMMAND, VllmSettings)
        if getattr(args, o.dest) is not o.cli_default
    ]
    return ["--print-command", *given] if args.print_command else given


def run(args: argparse.Namespace) -> int:
    if args.engine == "vllm":
        options = config_kwargs(args, COMMAND, VllmSettings)
        return command.run_vllm(command.vllm_settings(args, options), args.print_command)
    given = given_vllm_options(args)
    if given:
        what = "an option" if len(given) == 1 else "options"
        raise ConfigError(f"{', '.join(given)}: {what} of --engine vllm (add --engine vllm)")
    return command.run_server(args)
