"""``--policy-arg POLICY:KEY=VALUE`` checked from the command line alone, before any policy,
engine or model is imported.

A policy's factory checks its own options, but it lives beside the policy's stack (the planner
loads scipy, the RL agents ONNX Runtime) and a model directory is only opened on an episode's
first ``reset``: a misspelt key or a model path that does not exist would surface only after
seconds of imports, or as a failed record for every episode. Here each built-in policy's
option names are listed once more, with the checks that need nothing but the standard library
(choices, numbers, the model directory's marker files); ``tests/test_cli_errors.py`` compares
every list with its factory, so the two cannot drift apart. A policy from another package (an
entry point not listed here) is left to its factory, which the runner builds once before any
episode.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from packlab.core.choices import (
    HEURISTICS,
    RUNTIMES,
    CommitRule,
    HistoryMode,
    ImageMode,
    OverflowRule,
    ProposerRule,
    RLAgent,
    RolloutBase,
    StabilityCheck,
    TieBreak,
    choices,
    did_you_mean,
)
from packlab.core.errors import ConfigError

#: Files that mark a model directory (the same names as ``packlab.rl.card.CARD_FILE``,
#: ``packlab.policies.onnx_model.CARD_FILE``, a Hugging Face checkpoint's config and the pointer
#: VLM's head, ``packlab.vlm.candidate.files.HEAD_FILE``; a test checks each).
RL_CARD = "card.json"
ONNX_CARD = "onnx.json"
HF_CONFIG = "config.json"
POINTER_HEAD = "pointer_head.safetensors"

#: A value check: (policy, key, value) -> None, or a ConfigError in one line.
Check = Callable[[str, str, Any], None]


def _where(policy: str, key: str, value: Any) -> str:
    return f"policy-arg {policy}:{key} = {value!r}"


def _one_of(allowed: Iterable[str]) -> Check:
    names = tuple(allowed)

    def check(policy: str, key: str, value: Any) -> None:
        if value not in names:
            raise ConfigError(
                f"{_where(policy, key, value)}: unknown{did_you_mean(value, names)}; "
                f"choose one of {', '.join(names)}"
            )

    return check


def _whole(minimum: int) -> Check:
    def check(policy: str, key: str, value: Any) -> None:
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise ConfigError(f"{_where(policy, key, value)}: must be a whole number >= {minimum}")

    return check


def _positive(policy: str, key: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise ConfigError(f"{_where(policy, key, value)}: must be a number > 0")


def _switch(policy: str, key: str, value: Any) -> None:
    if not isinstance(value, bool):
        raise ConfigError(f"{_where(policy, key, value)}: must be true or false")


def _http_url(policy: str, key: str, value: Any) -> None:
    if not isinstance(value, str) or not value.startswith(("http://", "https://")):
        raise ConfigError(
            f"{_where(policy, key, value)}: expected an http(s) URL such as "
            "http://127.0.0.1:8000/v1"
        )


def _model_dir(policy: str, key: str, value: Any) -> Path:
    """The directory ``value`` names, or a ConfigError saying it does not exist."""
    path = Path(str(value))
    if not path.is_dir():
        raise ConfigError(
            f"{_where(policy, key, value)}: no such directory"
            + (" (it is a file)" if path.exists() else "")
        )
    return path


def _rl_model(policy: str, key: str, value: Any, options: dict[str, Any]) -> None:
    path = _model_dir(policy, key, value)
    if not (path / RL_CARD).is_file():
        raise ConfigError(
            f"{_where(policy, key, value)}: no {RL_CARD}, not an RL agent directory "
            f"(packlab train rl writes RUN/best and RUN/final)"
        )
    if options.get("runtime", "onnx") == "onnx" and not (path / ONNX_CARD).is_file():
        raise ConfigError(
            f"{_where(policy, key, value)}: no {ONNX_CARD} (not exported to ONNX); run "
            f"packlab export onnx {path}, or add --policy-arg {policy}:runtime=torch"
        )


def _agent_dir(policy: str, key: str, value: Any) -> None:
    """An RL agent directory exported to ONNX (what a planner's ``guide_model`` plays)."""
    _rl_model(policy, key, value, {"runtime": "onnx"})


def _vlm_model(policy: str, key: str, value: Any, options: dict[str, Any]) -> None:
    if isinstance(value, str) and value.startswith("tiny:"):
        return  # a random-weight model built on the spot
    path = _model_dir(policy, key, value)
    if not (path / HF_CONFIG).is_file():
        raise ConfigError(
            f"{_where(policy, key, value)}: no {HF_CONFIG}, not a checkpoint directory "
            "(give RUN/final, or tiny:<family>:<size> for a random model)"
        )
    pointer = (path / POINTER_HEAD).is_file()
    if pointer and options.get("runtime", "onnx") == "onnx" and not (path / ONNX_CARD).is_file():
        raise ConfigError(
            f"{_where(policy, key, value)}: no {ONNX_CARD} (not exported to ONNX); run "
            f"packlab export onnx {path}, or add --policy-arg {policy}:runtime=torch"
        )


def _refuse_model(policy: str, key: str, value: Any, options: dict[str, Any]) -> None:
    raise ConfigError(
        f"{_where(policy, key, value)}: {policy} plays the shipped checkpoint; "
        "use policy vlm with model=DIR for another one"
    )


@dataclass(frozen=True)
class PolicyOptions:
    """The options a built-in policy's factory takes, with the checks that need no import."""

    keys: tuple[str, ...]
    checks: dict[str, Check] = field(default_factory=dict)
    #: How ``model`` is checked (it may depend on the other options, e.g. ``runtime``).
    model: Callable[[str, str, Any, dict[str, Any]], None] | None = None


#: Every ``overflow`` option (packlab.policies.overflow) takes the same values.
_OVERFLOW = _one_of(choices(OverflowRule))
_HEURISTIC = PolicyOptions(
    ("tie_break", "overflow"),
    {"tie_break": _one_of(choices(TieBreak)), "overflow": _OVERFLOW},
)
#: ``plan``'s budget, weights, completion stage and switches (packlab.policies.plan.policy).
_PLAN = PolicyOptions(
    (
        "first",
        "listed",
        "rollout",
        "depth",
        "beam",
        "time_s",
        "w_final",
        "w_open",
        "w_over_rim",
        "w_steps",
        "w_trapped",
        "w_unreachable",
        "nodes",
        "decision_nodes",
        "jokers",
        "joker_seen",
        "guesses",
        "mixed_jokers",
        "mixed_evidence",
        "endgame_nodes",
        "endgame_boxes",
        "guillotine_nodes",
        "guillotine_boxes",
        "complete",
        "mixed",
        "finale",
        "finale_boxes",
        "endplay",
        "endplay_boxes",
        "commit",
        "stability",
        "overflow",
        "guide",
        "guide_model",
        "guide_first",
    ),
    {
        "mixed": _switch,
        "finale": _switch,
        "finale_boxes": _whole(1),
        "endplay": _whole(0),
        "endplay_boxes": _whole(1),
        "commit": _one_of(choices(CommitRule)),
        "guide": _one_of(("none", *choices(RLAgent))),
        "guide_model": _agent_dir,
        "guide_first": _whole(0),
        "endgame_nodes": _whole(0),
        "endgame_boxes": _whole(0),
        "guillotine_nodes": _whole(0),
        "guillotine_boxes": _whole(0),
        "first": _whole(1),
        "listed": _whole(0),
        "rollout": _one_of(choices(RolloutBase)),
        "depth": _whole(1),
        "beam": _whole(1),
        "time_s": _positive,
        "complete": _switch,
        "stability": _one_of(choices(StabilityCheck)),
        "overflow": _OVERFLOW,
    },
)
_RL = PolicyOptions(
    ("model", "threads", "runtime", "overflow"),
    {
        "threads": _whole(1),
        "runtime": _one_of(RUNTIMES),
        "overflow": _OVERFLOW,
    },
    model=_rl_model,
)
#: Options only a text-answer ``vlm`` checkpoint (VLMPolicy) takes; a candidate-mode one refuses
#: them (``packlab policies`` says so).
TEXT_ANSWER_KEYS = (
    "history",
    "image",
    "max_new_tokens",
    "device",
    "dtype",
    "max_length",
    "template_kwargs",
    "image_size",
    "reuse_cache",
    "model_seed",
    "prompt",
    "reask",
    "fallback",
    "batch",
    "max_batch",
)
#: ``vlm``: a text-answer checkpoint's options and a candidate-mode one's.
_VLM_KEYS = (
    "model",
    *TEXT_ANSWER_KEYS,
    "threads",
    "name",
    "blank_image",
    "runtime",
    "overflow",
)
#: The prompt protocols of the text-answer policies (their modules' PROMPTS).
_PROMPTS = _one_of(("packlab", "reference"))
#: What ``prompt=reference`` plays for an answer that does not parse (its modules' FALLBACKS:
#: the reference's relaxed and strict modes).
_FALLBACKS = _one_of(("set_aside", "invalid"))
_VLM_CHECKS: dict[str, Check] = {
    "prompt": _PROMPTS,
    "reask": _switch,
    "fallback": _FALLBACKS,
    "overflow": _OVERFLOW,
    "history": _one_of(choices(HistoryMode)),
    "image": _one_of(choices(ImageMode)),
    "max_new_tokens": _whole(1),
    "max_length": _whole(64),
    "threads": _whole(1),
    "runtime": _one_of(RUNTIMES),
    # The vlm policy's BATCH_MODES (packlab.vlm.infer.batching.MODES).
    "batch": _one_of(("auto", "on", "off")),
    "max_batch": _whole(1),
}
_ENDPOINT = PolicyOptions(
    (
        "base_url",
        "model",
        "api_key_env",
        "deadline_s",
        "retries",
        "backoff_s",
        "max_backoff_s",
        "history",
        "image",
        "image_size",
        "temperature",
        "max_tokens",
        "seed",
        "extra_body",
        "max_past_steps",
        "name",
        "timeout_s",
        "prompt",
        "reask",
        "fallback",
        "tag_requests",
    ),
    {
        "base_url": _http_url,
        "prompt": _PROMPTS,
        "reask": _switch,
        "fallback": _FALLBACKS,
        "tag_requests": _switch,
        "history": _one_of(choices(HistoryMode)),
        "image": _one_of(choices(ImageMode)),
        "retries": _whole(0),
        "max_tokens": _whole(1),
    },
)

#: Built-in policy -> its options (the names in pyproject's ``packlab.policies`` entry points).
POLICY_OPTIONS: dict[str, PolicyOptions] = {
    **{name: _HEURISTIC for name in HEURISTICS},
    "random": PolicyOptions(()),
    "oracle": PolicyOptions(()),
    "plan": _PLAN,
    "plan-fast": _PLAN,
    "plan-lookahead": _PLAN,
    "proposer": PolicyOptions(
        ("k", "rule", "overflow"),
        {
            "k": _whole(1),
            "rule": _one_of(choices(ProposerRule)),
            "overflow": _OVERFLOW,
        },
    ),
    "vlm": PolicyOptions(_VLM_KEYS, _VLM_CHECKS, model=_vlm_model),
    "vlm-small": PolicyOptions(_VLM_KEYS, _VLM_CHECKS, model=_refuse_model),
    "endpoint": _ENDPOINT,
    "irbpp": _RL,
    "tapnet": _RL,
    "irbpp-random": PolicyOptions(("k",), {"k": _whole(1)}),
    "tapnet-random": PolicyOptions(()),
}


def check_policy_args(policy_args: Iterable[tuple[str, str, Any]]) -> None:
    """ConfigError (one line) for the first ``--policy-arg`` a built-in policy cannot take: an
    unknown key (with the nearest known one), a bad value, a model directory that is missing or
    lacks the files the policy opens."""
    by_policy: dict[str, dict[str, Any]] = {}
    for name, key, value in policy_args:
        by_policy.setdefault(name, {})[key] = value
    for name, options in by_policy.items():
        spec = POLICY_OPTIONS.get(name)
        if spec is None:  # another package's policy: its factory checks its options
            continue
        for key, value in options.items():
            if key not in spec.keys:
                known = ", ".join(spec.keys) if spec.keys else "none (it takes no options)"
                raise ConfigError(
                    f"policy-arg {name}:{key}: unknown option{did_you_mean(key, spec.keys)}; "
                    f"{name} takes {known}"
                )
            if key in spec.checks:
                spec.checks[key](name, key, value)
            if key == "model" and spec.model is not None:
                spec.model(name, key, value, options)


__all__ = ["POLICY_OPTIONS", "TEXT_ANSWER_KEYS", "PolicyOptions", "check_policy_args"]
