"""The local VLM inference policies: ``vlm`` (a local transformers model) and ``vlm-small`` (the
checkpoint shipped in the package). The ``endpoint`` policy (an OpenAI-compatible server) is
:mod:`packlab.vlm.serve.endpoint`.

Each step renders the context X_t from the observation with :mod:`packlab.vlm.prompt.render`
(the same code the SFT export used, so training and inference read the same text), asks the
model, and parses the answer with :func:`packlab.vlm.prompt.parse.parse_or_unparsable`. An answer
that does not parse is returned as :class:`~packlab.core.types.Unparsable`; the episode records
it as an invalid step with reason ``unparsable`` and goes on (DESIGN.md section 4). Run untrained
(a base checkpoint), the same policy is the paper's zero-shot baseline.

Importing this module is cheap: torch and transformers are imported when a ``vlm`` policy loads
its model (:mod:`packlab.vlm.infer.runtime`, on the first :meth:`VLMPolicy.reset`), so policies
are picklable and cheap to build in the parent process and each worker loads its own copy.

Per-step diagnostics (token counts, prefix reuse, timings, the answer's format event) are kept
in the policy's ``step_log`` (a list of dicts, one per ``act`` of the current episode); how each
answer was read also reaches the episode's records (:meth:`VLMPolicy.last_answer_format`).

``prompt=reference`` plays a model trained on the reference implementation's data with the
reference's request and answer reading (:mod:`packlab.vlm.serve.reference_turns`, as the
``endpoint`` policy does): its text, images and thinking prefill, which the model continues; the
chat template gets ``enable_thinking`` true unless ``template_kwargs`` says otherwise. A
re-ask (``reask``) keeps the same template switches (a server would use its defaults);
``fallback`` picks the reference's relaxed (``set_aside``) or strict (``invalid``) handling of
an answer that does not parse.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from packlab.core.choices import HistoryMode, ImageMode, require_choice
from packlab.core.errors import ConfigError
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Case, Observation, Unparsable
from packlab.vlm.candidate.files import is_pointer_dir
from packlab.vlm.candidate.policy import CandidateVLMPolicy
from packlab.vlm.extra import VLM_EXTRA_HINT, import_torch_side
from packlab.vlm.prompt.context import DEFAULT_IMAGE_SIZE, ContextRenderer
from packlab.vlm.prompt.parse import logged_answer_format, parse_with_format
from packlab.vlm.prompt.reference import EXTRA_BODY as REFERENCE_EXTRA_BODY
from packlab.vlm.prompt.reference import SAMPLING as REFERENCE_SAMPLING
from packlab.vlm.prompt.reference import with_prefill
from packlab.vlm.prompt.reference_parse import Fallback, parse_reference
from packlab.vlm.prompt.render import PROMPT_VERSION, PromptOptions
from packlab.vlm.serve.reference_turns import (
    ReferenceTurns,
    check_fallback,
    local_image,
    reads_sample_id,
)

if TYPE_CHECKING:  # generate.py imports torch; only its type is needed here
    from packlab.vlm.infer.generate import Generation

__all__ = ["SHIPPED_MODEL_DIR", "VLMPolicy", "make_vlm", "make_vlm_small"]

#: Where the package ships its own trained checkpoint (``vlm-small``, also ``vlm``'s default).
SHIPPED_MODEL_DIR = Path(__file__).resolve().parents[2] / "data" / "models" / "vlm-small"
#: The policy's torch side (vlm extra), imported on the first load.

RUNTIME_MODULE = "packlab.vlm.infer.runtime"
#: The options of a candidate-mode checkpoint (:class:`CandidateVLMPolicy`).
CANDIDATE_ARGS = ("model", "threads", "name", "blank_image", "runtime", "overflow")
#: The prompt protocols and the answer budget each defaults to.
PROMPTS = ("packlab", "reference")
DEFAULT_MAX_NEW_TOKENS = {"packlab": 64, "reference": REFERENCE_SAMPLING["max_tokens"]}
#: How answers are decoded with other episodes' (``batch``; batching.MODES, without torch here).
BATCH_MODES = ("auto", "on", "off")
#: Most answers decoded together (``max_batch``; batching.DEFAULT_MAX_BATCH).
DEFAULT_MAX_BATCH = 8


def _check_settings(
    model: object,
    history: str | None,
    image: str | None,
    max_new_tokens: int,
    max_length: int | None,
    threads: int | None,
) -> None:
    """ConfigError (one line) for a setting the policy cannot run with."""
    if not isinstance(model, str) or not model:
        raise ConfigError(
            f"model = {model!r}: expected a checkpoint directory or tiny:<family>:<size>"
        )
    if not model.startswith("tiny:") and not (Path(model) / "config.json").is_file():
        raise ConfigError(f"model = {model!r}: not a checkpoint directory (no config.json)")
    if max_new_tokens < 1:
        raise ConfigError(f"max_new_tokens = {max_new_tokens}: must be >= 1")
    if max_length is not None and max_length < 64:
        raise ConfigError(f"max_length = {max_length}: must be >= 64 tokens")
    if threads is not None and threads < 1:
        raise ConfigError(f"threads = {threads}: must be >= 1")
    if history is not None:
        require_choice(history, HistoryMode, "history")
    if image is not None:
        require_choice(image, ImageMode, "image")


def _check_batch(batch: object, max_batch: object) -> None:
    """ConfigError (one line) for a batch setting the policy cannot run with."""
    if batch not in BATCH_MODES:
        raise ConfigError(f"batch = {batch!r}: choose one of {', '.join(BATCH_MODES)}")
    if isinstance(max_batch, bool) or not isinstance(max_batch, int) or max_batch < 1:
        raise ConfigError(f"max_batch = {max_batch!r}: must be a whole number >= 1")


def _generation_log(gen: Generation) -> dict[str, object]:
    """The step log's fields about one generation (tokens, cache reuse, dropped steps)."""
    return {
        "prompt_tokens": gen.prompt_tokens,
        "reused_tokens": gen.reused_tokens,
        "new_tokens": len(gen.token_ids),
        "finished": gen.finished,
        "dropped_steps": gen.dropped_steps,
        "batch_rows": gen.batch_rows,
    }


class VLMPolicy:
    """Greedy answers of a local Qwen-VL-family model, reusing the conversation's cached prefix.

    ``model`` is a local checkpoint directory or ``tiny:<family>:<size>`` (a random-weight model,
    for tests and latency runs). ``history``/``image``/``max_length``/``template_kwargs`` left at
    None take the values the checkpoint was trained with (its ``packlab_model.json``), else the
    defaults (full history, heightmap images, no length limit). ``reuse_cache=False`` re-encodes
    the whole context every step (same answers, slower; for checks and latency comparisons).
    ``batch`` decodes this episode's answers together with those of the other episodes asking
    the same model in this process (``packlab bench --concurrency N``), up to ``max_batch`` at
    once: ``auto`` while another episode is asking, ``on`` always, ``off`` never
    (:mod:`packlab.vlm.infer.batching`).
    """

    def __init__(
        self,
        model: str = "tiny:qwen3_5:tiny",
        history: str | None = None,
        image: str | None = None,
        max_new_tokens: int | None = None,
        device: str = "auto",
        dtype: str = "auto",
        max_length: int | None = None,
        template_kwargs: dict[str, Any] | None = None,
        image_size: int = DEFAULT_IMAGE_SIZE,
        reuse_cache: bool = True,
        model_seed: int = 0,
        threads: int | None = None,
        name: str | None = None,
        prompt: str = "packlab",
        reask: bool = False,
        fallback: Fallback = "set_aside",
        batch: str = "auto",
        max_batch: int = DEFAULT_MAX_BATCH,
    ) -> None:
        if prompt not in PROMPTS:
            raise ConfigError(f"prompt = {prompt!r}: choose one of {', '.join(PROMPTS)}")
        if not isinstance(reask, bool):
            raise ConfigError(f"reask = {reask!r}: must be true or false")
        check_fallback(fallback, prompt)
        if max_new_tokens is None:
            max_new_tokens = DEFAULT_MAX_NEW_TOKENS[prompt]
        _check_settings(model, history, image, max_new_tokens, max_length, threads)
        _check_batch(batch, max_batch)
        self.batch, self.max_batch = batch, max_batch
        self.prompt, self.reask, self.fallback = prompt, reask, fallback
        # The protocol is part of what a row measures, so a report can tell the two apart.
        self.name = name or ("vlm (reference prompt)" if prompt == "reference" else "vlm")
        self.model_spec = model
        self.history, self.image = history, image
        self.max_new_tokens = max_new_tokens
        self.device, self.dtype = device, dtype
        self.max_length = max_length
        self.template_kwargs = template_kwargs
        self.image_size = image_size
        self.reuse_cache = reuse_cache
        self.model_seed = model_seed
        self.threads = threads
        self.step_log: list[dict[str, Any]] = []
        self._generator: Any = None
        self._renderer: ContextRenderer | None = None
        self._reference: ReferenceTurns | None = None
        self.resolved: dict[str, Any] = {}

    @classmethod
    def from_vlm(
        cls,
        vlm: Any,
        options: PromptOptions | None = None,
        max_new_tokens: int = 64,
        image_size: int = DEFAULT_IMAGE_SIZE,
        template_kwargs: dict[str, Any] | None = None,
        name: str = "vlm",
    ) -> VLMPolicy:
        """A policy playing a model already in memory (a trainer's closed-loop evaluation):
        nothing is loaded; the model stays where it is, in its dtype."""
        # Its default spec is never loaded; one evaluation loop, so no batcher.
        policy = cls(max_new_tokens=max_new_tokens, name=name, batch="off")
        policy.model_spec = "in-memory"
        runtime = import_torch_side(RUNTIME_MODULE)
        policy._generator = runtime.make_generator(
            vlm, max_new_tokens, True, image_size, None, dict(template_kwargs or {})
        )
        policy._renderer = ContextRenderer(options or PromptOptions(), image_size)
        policy.resolved = {"model": "in-memory", "family": vlm.family, "greedy": True}
        return policy

    # -- pickling: config only; each process loads its own model -----------------------------
    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_generator"], state["_renderer"], state["step_log"] = None, None, []
        state["_reference"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    # -- loading -----------------------------------------------------------------------------
    def load(self) -> None:
        """Load (or build) the model now; :meth:`reset` does it on first use."""
        if self._generator is not None:
            return
        try:
            runtime = import_torch_side(RUNTIME_MODULE)
        except ModuleNotFoundError as exc:
            raise ConfigError(
                f"policy {self.name!r}: {VLM_EXTRA_HINT} ({exc.name} missing)"
            ) from None
        if self.threads is not None:
            runtime.set_threads(self.threads)
        device = runtime.resolve_device(self.device)
        dtype = runtime.resolve_dtype(self.dtype, device)
        vlm = runtime.load_vlm(self.model_spec, device, dtype, self.model_seed)
        sft = self._training_settings(vlm.meta or {})
        # The checkpoint's card is read from disk: its values are checked like the user's.
        history = self.history or sft.get("history", "full")
        image = self.image or sft.get("image", "heightmap")
        require_choice(history, HistoryMode, "history")
        require_choice(image, ImageMode, "image")
        options = PromptOptions(history=cast(HistoryMode, history), image=cast(ImageMode, image))
        max_length = self.max_length if self.max_length is not None else sft.get("max_length")
        if self.template_kwargs is not None:
            template_kwargs = self.template_kwargs
        elif self.prompt == "reference":  # what the reference's requests switch on
            template_kwargs = dict(REFERENCE_EXTRA_BODY["chat_template_kwargs"])
        else:
            template_kwargs = dict(sft.get("template_kwargs") or {})
        self._generator = runtime.make_generator(
            vlm, self.max_new_tokens, self.reuse_cache, self.image_size, max_length, template_kwargs
        )
        runtime.attach_batcher(self._generator, self.batch, self.max_batch)
        self._renderer = ContextRenderer(options, self.image_size)
        if self.prompt == "reference":
            self._reference = ReferenceTurns(
                options.history, options.image, image_part=local_image, fallback=self.fallback
            )
        self.resolved = {
            "model": self.model_spec,
            "family": vlm.family,
            "device": device,
            "dtype": runtime.dtype_name(dtype),
            "options": options.to_dict(),
            "max_length": max_length,
            "template_kwargs": template_kwargs,
            "max_new_tokens": self.max_new_tokens,
            "reuse_cache": self.reuse_cache,
            "image_size": self.image_size,
            "batch": self.batch,
            "max_batch": self.max_batch,
            "greedy": True,
        }

    def _training_settings(self, meta: dict[str, Any]) -> dict[str, Any]:
        """The checkpoint's SFT config (empty when none), after checking its prompt version."""
        trained_with = meta.get("prompt_version")
        if trained_with is not None and trained_with != PROMPT_VERSION:
            raise ConfigError(
                f"model = {self.model_spec!r}: trained with prompt {trained_with!r}, this packlab "
                f"renders {PROMPT_VERSION!r}; retrain or use the packlab version it was made with"
            )
        return meta.get("sft_config") or {}

    def config(self) -> dict[str, Any]:
        """The requested configuration, plus what loading resolved (device, dtype, options
        taken from the checkpoint, ...) once the model is loaded; for run records."""
        requested = {
            "model": self.model_spec,
            "history": self.history,
            "image": self.image,
            "max_new_tokens": self.max_new_tokens,
            "device": self.device,
            "dtype": self.dtype,
            "max_length": self.max_length,
            "template_kwargs": self.template_kwargs,
            "image_size": self.image_size,
            "reuse_cache": self.reuse_cache,
            "model_seed": self.model_seed,
            "batch": self.batch,
            "max_batch": self.max_batch,
            "prompt": self.prompt,
            "reask": self.reask,
            "fallback": self.fallback,
        }
        return {**requested, **self.resolved}

    @property
    def generator(self) -> Any:
        """The :class:`packlab.vlm.infer.generate.PrefixCachedGenerator` (after :meth:`load`)."""
        return self._generator

    @property
    def needs_case(self) -> bool:
        """Handed the case at reset only for the reference protocol's relaxed mode: its forced
        set-aside is seeded by the case's sample id, as the reference seeds it."""
        return reads_sample_id(self.prompt, self.fallback)

    # -- the Policy protocol -----------------------------------------------------------------
    def reset(self, start: EpisodeStart | Case, seed: int) -> None:
        self.load()
        assert self._renderer is not None  # set by load()
        self._generator.reset()
        self._renderer.reset()
        self.step_log = []
        if self._reference is not None:
            self._reference.reset(start)

    def act(self, observation: Observation) -> Action | Unparsable:
        if self._generator is None or self._renderer is None:
            raise RuntimeError(f"policy {self.name!r}: act() before reset()")
        if self._reference is not None:
            return self._act_reference(observation, self._reference)
        t0 = time.perf_counter()
        messages = self._renderer.messages(observation)
        render_s = time.perf_counter() - t0
        gen = self._generator.generate(messages)
        action, event = parse_with_format(gen.text)
        self.step_log.append(
            {
                "step": observation.step_index,
                **_generation_log(gen),
                "render_s": round(render_s, 6),
                "encode_s": round(gen.encode_s, 6),
                "prefill_s": round(gen.prefill_s, 6),
                "decode_s": round(gen.decode_s, 6),
                "parsed": isinstance(action, Action),
                "format_event": event,
            }
        )
        return action

    def last_answer_format(self) -> dict[str, Any] | None:
        """How the latest :meth:`act` read its answer (the episode's answer-format hook,
        DESIGN.md section 7): format event, re-ask (``reask`` on) and forced set-aside."""
        return logged_answer_format(self.step_log[-1]) if self.step_log else None

    def _act_reference(
        self, observation: Observation, turns: ReferenceTurns
    ) -> Action | Unparsable:
        """One step of the reference's protocol: the model continues the thinking prefill; an
        answer it cannot use is asked for once more (``reask``), then set aside or played as an
        invalid step as the reference's evaluation does (``fallback``)."""
        view = turns.view(observation)
        gen = self._generator.generate(with_prefill(view))
        text, parsed, reasked = gen.text, parse_reference(gen.text), False
        if parsed.action is None and self.reask:
            gen = self._generator.generate(ReferenceTurns.reask(view, text))
            text, parsed, reasked = gen.text, parse_reference(gen.text), True
        decision = turns.decide(observation, text, parsed)
        self.step_log.append(
            {
                "step": observation.step_index,
                **_generation_log(gen),
                "parsed": parsed.action is not None,
                "format_event": decision.event,
                "parse_error": decision.error,
                "forced_set_aside": decision.forced,
                # logged where a second ask was possible
                **({"reasked": reasked} if self.reask else {}),
            }
        )
        return decision.action


def make_vlm(**kwargs: Any) -> VLMPolicy | CandidateVLMPolicy:
    """``vlm``: a local checkpoint (``model=DIR``) or a random tiny model (``model=tiny:F:S``).

    A candidate-mode checkpoint (a pointer head beside the model) plays in candidate mode
    (:mod:`packlab.vlm.candidate.policy`), on ONNX Runtime by default (``runtime=torch``: through
    transformers); without ``model`` the shipped model plays (``packlab/data/models/vlm-small``,
    candidate mode), else a random tiny model.
    """
    model = kwargs.get("model", SHIPPED_MODEL_DIR)
    if is_pointer_dir(model):
        extra = sorted(set(kwargs) - set(CANDIDATE_ARGS))
        if extra:
            raise ConfigError(
                f"policy 'vlm': model {str(model)!r} is a candidate-mode checkpoint, which takes "
                f"only {', '.join(CANDIDATE_ARGS)}; got {', '.join(extra)}"
            )
        return CandidateVLMPolicy(**{**kwargs, "model": str(model)})
    return VLMPolicy(**kwargs)


def make_vlm_small(**kwargs: Any) -> VLMPolicy | CandidateVLMPolicy:
    """``vlm-small``: the model shipped in the package (``packlab/data/models/vlm-small``)."""
    if "model" in kwargs:
        raise ConfigError(
            "policy 'vlm-small' uses the shipped checkpoint; use policy 'vlm' with "
            "model=DIR for another one"
        )
    if not (SHIPPED_MODEL_DIR / "config.json").is_file():
        raise ConfigError(
            f"policy 'vlm-small': no checkpoint is shipped in this install ({SHIPPED_MODEL_DIR} "
            "has no config.json). Reproduce it (docs/vlm.md): generate training cases with "
            "`packlab generate`, train with `packlab train candidate --cases CASES --out RUN`, "
            f"then copy RUN/final to {SHIPPED_MODEL_DIR} or run policy 'vlm' with model=RUN/final"
        )
    kwargs.setdefault("name", "vlm-small")
    return make_vlm(model=str(SHIPPED_MODEL_DIR), **kwargs)
