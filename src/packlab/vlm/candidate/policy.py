"""The candidate-mode VLM policy: list K placements, score them with the pointer model, take
the best. Torch-free at import (the registry imports it); the model loads on first reset.

Every answer is a listed placement, so it always parses and always fits. Where no shown box fits
under the rim, the shared overflow rule decides (option ``overflow``, default ``score``;
:mod:`packlab.policies.overflow`). When nothing fits (the
proposer lists nothing) the policy hands the step to SDF-Pack, which then makes the same
set-aside decision any policy would; such steps are counted in ``fallbacks``.

A scorer whose scores are not one number per listed placement, or none of them finite, names no
listed placement: that step is an :class:`Unparsable` (invalid, ``unparsable``), never a crash
or a silent pick of placement 0 (:func:`pick_listed`).

``runtime`` picks how the model plays: ``"onnx"`` (default) runs the directory's ONNX graphs on
ONNX Runtime (:mod:`.onnx_scoring`, core install, no torch; ``packlab export onnx DIR`` writes
them), ``"torch"`` the checkpoint itself through transformers (:mod:`.scoring`, vlm extra). Both
score the same inputs, built by one code (:mod:`.encoding`). The free-JSON answer ablation
generates text and plays under torch only; a model handed over in memory
(:meth:`CandidateVLMPolicy.use_model`, during training) plays under torch.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

import numpy as np

from packlab.core.choices import RUNTIMES, OverflowRule, require_choice
from packlab.core.errors import ConfigError
from packlab.core.feasibility import observation_candidates
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Observation, Unparsable
from packlab.policies.candidates import ProposerConfig, propose_from
from packlab.policies.model_cache import load_once
from packlab.policies.overflow import overflow_decision
from packlab.policies.registry import make_policy
from packlab.vlm.candidate.files import is_pointer_dir
from packlab.vlm.extra import VLM_EXTRA_HINT, import_torch_side
from packlab.vlm.prompt.parse import parse_or_unparsable
from packlab.vlm.prompt.render import PROMPT_VERSION

#: ``model`` of a policy given its model by :meth:`CandidateVLMPolicy.use_model`.
IN_MEMORY = "<in memory>"
SCORING_MODULE = "packlab.vlm.candidate.scoring"
SAVED_MODULE = "packlab.vlm.candidate.saved"
ONNX_SCORING_MODULE = "packlab.vlm.candidate.onnx_scoring"
#: Loaded with the model, not at import: it reaches scipy (line vectors), which the policy
#: registry (every CLI start) should not pay for.
ENCODING_MODULE = "packlab.vlm.candidate.encoding"


class CandidateVLMPolicy:
    """Picks the highest-scoring listed placement of a pointer model (``model`` = a directory)."""

    def __init__(
        self,
        model: str | Path,
        threads: int | None = 1,
        name: str = "vlm",
        blank_image: bool = False,
        runtime: str = "onnx",
        overflow: OverflowRule = "score",
    ) -> None:
        """``blank_image`` (ablation, ``--policy-arg vlm:blank_image=true``): the model is shown
        the map of an empty container at every step, in whatever form it reads the map (image
        or digits); the listed lines and their vectors are unchanged. ``runtime``: ``"onnx"`` or
        ``"torch"`` (module docstring). ``overflow``: where no shown box fits under the rim
        (or the last box would raise the top), ``score`` (default) lets the shared rule decide
        (:mod:`packlab.policies.overflow`), ``place`` the model."""
        if model != IN_MEMORY and not is_pointer_dir(model):
            raise ConfigError(f"model = {str(model)!r}: not a candidate-mode checkpoint directory")
        if threads is not None and threads < 1:
            raise ConfigError(f"threads = {threads}: must be >= 1")
        if not isinstance(blank_image, bool):
            raise ConfigError(f"blank_image = {blank_image!r}: must be true or false")
        if runtime not in RUNTIMES:
            raise ConfigError(f"runtime = {runtime!r}: expected one of {', '.join(RUNTIMES)}")
        self.model_spec, self.threads, self.name = str(model), threads, name
        self.runtime = runtime
        require_choice(overflow, OverflowRule, f"policy-arg {name}:overflow")
        self.overflow = overflow
        self.blank_image = blank_image
        self.fallbacks = 0  # steps handed to SDF-Pack (nothing listed)
        self.overflowed = 0  # steps the overflow rule took
        self.decisions = 0
        self._model: Any = None

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_model": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    def load(self) -> None:
        if self._model is not None:
            return
        if self.runtime == "onnx":
            self._load_onnx()
            return
        try:
            scoring = import_torch_side(SCORING_MODULE)
            saved = import_torch_side(SAVED_MODULE)
        except ModuleNotFoundError as exc:
            raise ConfigError(
                f"policy {self.name!r} (runtime=torch): {VLM_EXTRA_HINT} ({exc.name} missing); "
                f"runtime=onnx plays without torch"
            ) from None
        scoring.set_threads(self.threads)
        settings = ("pointer", "torch")  # threads are the process's (torch.set_num_threads)
        loaded = load_once(
            Path(self.model_spec), settings, lambda: saved.load_pointer(self.model_spec)
        )
        self.use_model(loaded)

    def _load_onnx(self) -> None:
        """The directory's ONNX graphs (:mod:`.onnx_scoring`; torch-free)."""
        onnx_scoring = importlib.import_module(ONNX_SCORING_MODULE)
        meta = onnx_scoring.read_meta(Path(self.model_spec))
        if meta.get("answer", "index") == "json":
            raise ConfigError(
                f"policy {self.name!r}: model {self.model_spec!r} answers in free JSON (the "
                f"format ablation), which generates text and plays with runtime=torch only"
            )
        settings = ("pointer", "onnx", self.threads)
        try:
            model = load_once(
                Path(self.model_spec),
                settings,
                lambda: onnx_scoring.load_onnx_pointer(self.model_spec, self.threads),
            )
        except ConfigError as exc:
            raise ConfigError(
                f"policy {self.name!r} (runtime=onnx): {exc}; or play it with runtime=torch"
            ) from None
        self._configure(model.meta)
        self._model = model
        self._score = onnx_scoring.score_listed

    def use_model(self, model: Any, meta: dict[str, Any] | None = None) -> None:
        """Play with an already loaded pointer model (torch); ``meta`` replaces its model card
        (for a model still in training)."""
        scoring = import_torch_side(SCORING_MODULE)
        self._configure(model.vlm.meta if meta is None else meta)
        self._model = model
        self.runtime = "torch"
        self._score = scoring.score_listed
        self._generate = scoring.generate_answer

    def _configure(self, meta: dict[str, Any]) -> None:
        """The proposer and prompt settings of a model card, after checking its prompt."""
        if meta.get("prompt_version") != PROMPT_VERSION:
            raise ConfigError(
                f"model = {self.model_spec!r}: trained with prompt {meta.get('prompt_version')!r}"
                f", this packlab renders {PROMPT_VERSION!r}; retrain it"
            )
        self._proposer = ProposerConfig(**meta["proposer"])
        encoding = importlib.import_module(ENCODING_MODULE)
        self._settings = encoding.PromptSettings.of(meta, blank_map=self.blank_image)

    def reset(self, start: EpisodeStart, seed: int) -> None:
        self.load()
        self._fallback = make_policy("sdf")
        self._fallback.reset(start, seed)

    def act(self, observation: Observation) -> Action | Unparsable:
        self.decisions += 1
        cands = observation_candidates(observation)
        overflowed = overflow_decision(observation, cands, self.overflow)
        if overflowed is not None:
            self.overflowed += 1
            return overflowed
        listed = propose_from(cands, self._proposer)
        if not listed:
            self.fallbacks += 1
            return self._fallback.act(observation)
        if self._settings.answer == "json":  # the format ablation: free text, may not parse
            return parse_or_unparsable(
                self._generate(self._model, observation, listed, self._settings)
            )
        scores = self._score(self._model, observation, listed, self._settings)
        return pick_listed(listed, scores)


def pick_listed(listed: Any, scores: Any) -> Action | Unparsable:
    """The listed placement with the highest score, or an :class:`Unparsable` (with the scores'
    shape or the reason in ``error``) when the scores are not one number per listed placement
    or none of them is finite: an answer that names no listed placement is an invalid step, not
    a crash or a silent pick of placement 0. Non-finite scores among finite ones never win."""
    try:
        values = np.asarray(scores, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        return Unparsable(text="", error=f"scores are not numbers: {exc}")
    if values.shape != (len(listed),):
        return Unparsable(
            text="",
            error=f"scores of shape {values.shape} for {len(listed)} listed placements",
        )
    finite = np.isfinite(values)
    if not finite.any():
        return Unparsable(text="", error=f"no finite score among {len(listed)} placements")
    return listed[int(np.argmax(np.where(finite, values, -np.inf)))].action
