"""The ``vllm serve`` command line that serves a packing VLM for the bench, and the ``packlab
bench`` command that plays it (``packlab serve --engine vllm``).

Pure: :func:`vllm_argv` and :func:`bench_argv` turn :class:`VllmSettings` into argument lists;
nothing here reads a checkpoint, imports vLLM or starts a process (:mod:`.command` does).

What packing needs from the server, flag by flag:

- ``--limit-mm-per-prompt``: vLLM refuses a request with more images than this, and a
  full-history context shows one image per past step plus the current one
  (:func:`images_per_prompt`); ``video`` is 0, so vLLM sets no memory aside for video;
- ``--max-model-len``: the longest context served (65536, as the reference implementation
  serves its model);
- ``--served-model-name``: the name the ``endpoint`` policy asks for (``endpoint:model``);
- ``--max-num-seqs``: the requests the bench has in flight at once (workers x concurrency), so
  the whole batch runs together;
- ``--enable-prefix-caching``: each step's context is the previous one plus a turn, so all but
  the new turn is already cached;
- ``--seed``, and under packlab's prompt ``--generation-config vllm``: answers are greedy
  with vLLM's defaults, not the checkpoint's generation_config.json (a repetition penalty
  there would change greedy answers), as the local ``vlm`` policy decodes;
- ``--chat-template-content-format openai``: packlab's messages are lists of parts;
- ``--default-chat-template-kwargs``: the chat template's switches for requests that send
  none. Under ``prompt=reference`` this and the other flags of the reference's own server
  (``--trust-remote-code``, ``--disable-custom-all-reduce``, ``--gdn-prefill-backend triton``)
  are passed as the reference passes them.
"""

from __future__ import annotations

import json
import shlex
from dataclasses import dataclass, field
from typing import Any

from packlab.core.choices import HistoryMode, ImageMode, require_choice
from packlab.core.errors import ConfigError

#: The prompt protocols of the ``endpoint`` policy (``packlab.vlm.serve.endpoint.PROMPTS``,
#: kept here so that building the command imports no image code; a test keeps them equal).
PROMPTS = ("packlab", "reference")
#: The most objects a case of the bundled suites has; an episode takes one step per object.
BUNDLED_MAX_STEPS = 32
#: The reference implementation's server settings (its evaluation script).
REFERENCE_MAX_MODEL_LEN = 65536
REFERENCE_GPU_MEMORY_UTILIZATION = 0.85
#: Chat-template switches of the reference's server for requests that send none (its re-asks;
#: its first asks switch thinking on themselves).
REFERENCE_TEMPLATE_KWARGS: dict[str, Any] = {"enable_thinking": False}
#: Flags the reference's server is started with, besides those every protocol gets.
REFERENCE_FLAGS = (
    "--trust-remote-code",
    "--disable-custom-all-reduce",
    "--gdn-prefill-backend",
    "triton",
)
#: The reference's client waits 120 s for an answer of up to 512 tokens.
REFERENCE_DEADLINE_S = 120
#: Most episodes a bench worker runs at once (``packlab.executors.MAX_CONCURRENCY``).
MAX_CONCURRENCY = 64
#: Hosts that mean "every interface" to a server; a client on the same machine uses loopback.
ANY_HOST = ("0.0.0.0", "::", "")


@dataclass(frozen=True)
class VllmSettings:
    """What the served model and the bench run need to agree on.

    ``history``, ``image`` and ``template_kwargs`` left at None take the checkpoint's training
    settings (``packlab serve`` reads them from its packlab_model.json), else full history,
    heightmap images and the protocol's template switches.
    """

    model: str  # checkpoint directory or a model id on the Hugging Face Hub
    served_name: str
    host: str = "127.0.0.1"
    port: int = 8000
    prompt: str = "packlab"
    history: HistoryMode | None = None
    image: ImageMode | None = None
    #: The endpoint sends only the N most recent past steps (None: all of them).
    max_past_steps: int | None = None
    #: The most steps an episode takes (its case's object count).
    max_steps: int = BUNDLED_MAX_STEPS
    max_model_len: int = REFERENCE_MAX_MODEL_LEN
    gpu_memory_utilization: float = REFERENCE_GPU_MEMORY_UTILIZATION
    #: The bench's worker processes and episodes in flight per worker.
    workers: int = 4
    concurrency: int = 8
    seed: int = 0
    prefix_caching: bool = True
    trust_remote_code: bool = False
    template_kwargs: dict[str, Any] | None = None
    #: More ``vllm serve`` arguments, passed as they are, last.
    extra_args: tuple[str, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        if self.prompt not in PROMPTS:
            raise ConfigError(f"--prompt {self.prompt!r}: choose one of {', '.join(PROMPTS)}")
        if self.history is not None:
            require_choice(self.history, HistoryMode, "--history")
        if self.image is not None:
            require_choice(self.image, ImageMode, "--image")
        for flag, value, low, high in (
            ("--port", self.port, 1, 65535),
            ("--max-steps", self.max_steps, 1, 10_000),
            ("--max-model-len", self.max_model_len, 256, 10_000_000),
            ("--workers", self.workers, 1, 512),
            ("--concurrency", self.concurrency, 1, MAX_CONCURRENCY),
            ("--seed", self.seed, 0, 2**32 - 1),
        ):
            _check_int(flag, value, low, high)
        if self.max_past_steps is not None:
            _check_int("--max-past-steps", self.max_past_steps, 0, 10_000)
        g = self.gpu_memory_utilization
        if isinstance(g, bool) or not isinstance(g, (int, float)) or not 0.0 < g <= 1.0:
            raise ConfigError(f"--gpu-memory-utilization {g!r}: must be a fraction in (0, 1]")
        if self.template_kwargs is not None and not isinstance(self.template_kwargs, dict):
            raise ConfigError(
                f"--template-kwargs {self.template_kwargs!r}: must be a JSON object, "
                "e.g. '{\"enable_thinking\": false}'"
            )

    @property
    def resolved_history(self) -> HistoryMode:
        return self.history or "full"

    @property
    def resolved_image(self) -> ImageMode:
        return self.image or "heightmap"

    @property
    def max_num_seqs(self) -> int:
        """Requests in flight at once: each bench worker plays ``concurrency`` episodes."""
        return self.workers * self.concurrency

    @property
    def base_url(self) -> str:
        """Where a client on this machine reaches the server."""
        host = "127.0.0.1" if self.host in ANY_HOST else self.host
        if ":" in host:  # an IPv6 address
            host = f"[{host}]"
        return f"http://{host}:{self.port}/v1"

    def chat_template_kwargs(self) -> dict[str, Any]:
        """The template switches the server applies to requests that send none."""
        if self.template_kwargs is not None:
            return self.template_kwargs
        return dict(REFERENCE_TEMPLATE_KWARGS) if self.prompt == "reference" else {}


def _check_int(flag: str, value: object, low: int, high: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ConfigError(f"{flag} {value!r}: must be a whole number in [{low}, {high}]")


def images_per_prompt(
    history: HistoryMode, image: ImageMode, max_steps: int, max_past_steps: int | None
) -> int:
    """The most images one request shows: the current state's, plus one per past step the
    context keeps (none under ``current_only``; at most ``max_past_steps``).

    A bound, never short: it counts ``max_steps`` past steps, one more than the last step of
    an episode of ``max_steps`` steps has (a request over the server's limit is refused, and
    the step is lost).
    """
    if image == "none":
        return 0
    past = 0 if history == "current_only" else max_steps
    if max_past_steps is not None:
        past = min(past, max_past_steps)
    return past + 1


def vllm_argv(s: VllmSettings) -> list[str]:
    """``vllm serve MODEL ...`` for these settings."""
    images = images_per_prompt(s.resolved_history, s.resolved_image, s.max_steps, s.max_past_steps)
    argv = [
        "vllm",
        "serve",
        s.model,
        "--served-model-name",
        s.served_name,
        "--host",
        s.host,
        "--port",
        str(s.port),
        "--max-model-len",
        str(s.max_model_len),
        "--limit-mm-per-prompt",
        json.dumps({"image": images, "video": 0}),
        "--max-num-seqs",
        str(s.max_num_seqs),
        "--gpu-memory-utilization",
        f"{s.gpu_memory_utilization:g}",
        "--seed",
        str(s.seed),
    ]
    argv.append("--enable-prefix-caching" if s.prefix_caching else "--no-enable-prefix-caching")
    if s.prompt == "reference":
        argv += REFERENCE_FLAGS
    else:
        argv += ["--generation-config", "vllm", "--chat-template-content-format", "openai"]
        if s.trust_remote_code:
            argv.append("--trust-remote-code")
    kwargs = s.chat_template_kwargs()
    if kwargs:
        argv += ["--default-chat-template-kwargs", json.dumps(kwargs)]
    return argv + list(s.extra_args)


def bench_argv(s: VllmSettings) -> list[str]:
    """``packlab bench ...`` that plays the served model with matching settings."""

    def arg(key: str, value: object) -> list[str]:
        return ["--policy-arg", f"endpoint:{key}={value}"]

    argv = ["packlab", "bench", "--policies", "endpoint"]
    argv += arg("base_url", s.base_url) + arg("model", s.served_name)
    if s.prompt == "reference":
        # The reference's data names each box's sides as its catalogue does; its client waits
        # 120 s for an answer.
        argv = argv[:2] + ["--sides", "catalogue"] + argv[2:]
        argv += arg("prompt", "reference") + arg("deadline_s", REFERENCE_DEADLINE_S)
    if s.resolved_history != "full":
        argv += arg("history", s.resolved_history)
    if s.resolved_image != "heightmap":
        argv += arg("image", s.resolved_image)
    if s.max_past_steps is not None:
        argv += arg("max_past_steps", s.max_past_steps)
    return argv + ["--workers", str(s.workers), "--concurrency", str(s.concurrency)]


def shell_text(argv: list[str]) -> str:
    """``argv`` as a shell command to copy, one option (and its value) per line."""
    lines: list[list[str]] = [[]]
    for word in argv:
        if word.startswith("--") and lines[-1]:
            lines.append([])
        lines[-1].append(shlex.quote(word))
    return " \\\n    ".join(" ".join(line) for line in lines)


__all__ = [
    "BUNDLED_MAX_STEPS",
    "PROMPTS",
    "VllmSettings",
    "bench_argv",
    "images_per_prompt",
    "shell_text",
    "vllm_argv",
]
