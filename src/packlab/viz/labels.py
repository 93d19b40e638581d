"""How policies, groups and metrics are named in tables and figures (pure strings)."""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping

from packlab.metrics import AVERAGE

#: How methods are called in tables and figures (the paper's names); others print as registered.
DISPLAY_NAMES = {
    "dblf": "DBLF",
    "hm": "HM",
    "mta": "MTA",
    "ffp": "FFP",
    "sdf": "SDF-Pack",
    "plan": "Plan (completion + lookahead)",
    "plan-fast": "Plan (completion + lookahead, fast)",
    "plan-lookahead": "Plan (lookahead only)",
    "proposer": "Proposer (index 0)",
    "vlm-small": "PackLab pointer LM (vlm-small, candidate mode)",
    # The learned rows of the default table: the paper's names for its baselines (the agents are
    # IR-BPP- and TAP-Net-style, trained here; docs/rl.md) and the candidate-mode model, whatever
    # checkpoint `--policy-arg vlm:model=` names. Its row says what the shipped model is (issue
    # 36): a Qwen3-VL text stack with a pointer head that reads the heightmap as digits; its image
    # input never changed a decision (docs/vlm.md), so it ships without the vision tower.
    "vlm": "PackLab pointer LM",
    "irbpp": "IR-BPP",
    "tapnet": "TAP-Net",
    "random": "Random",
    "oracle": "Oracle (gt plan)",
}
METRIC_SHORT = {"success_ratio": "SR", "compactness": "Compact.", "overall": "Overall"}


def display_name(policy: str) -> str:
    return DISPLAY_NAMES.get(policy, policy)


def group_title(group: str) -> str:
    return "Average" if group == AVERAGE else (group.capitalize() if group else "Unlabelled")


#: Policy options that change what a row measures, named in its label whenever a run sets them
#: (``--policy-arg``), in this order: the text-answer policies' prompt protocol and context
#: ablations. A value in :data:`UNLABELLED` is the default every policy taking the option has,
#: and leaves the label as it is.
LABELLED_OPTIONS = ("prompt", "history", "image", "max_past_steps", "reask", "fallback")
UNLABELLED: dict[str, object] = {"prompt": "packlab", "reask": False, "fallback": "set_aside"}
#: Options that say how a policy runs, not what it does: never named, even where runs differ.
OPERATIONAL_OPTIONS = frozenset(
    {
        "name",
        "base_url",
        "api_key_env",
        "deadline_s",
        "timeout_s",
        "retries",
        "backoff_s",
        "max_backoff_s",
        "threads",
        "device",
        "runtime",
        "reuse_cache",
    }
)


def _value_text(value: object) -> str:
    """An option's value as typed on the command line (JSON for true/false, lists, objects)."""
    return value if isinstance(value, str) else json.dumps(value, separators=(",", ":"))


#: An option a run did not set.
NOT_SET: object = object()


def option_setting(key: str, value: object = NOT_SET) -> str:
    """One option as a label shows it: ``reference prompt`` for the prompt protocol, else
    ``key=value``; an option a run did not set reads ``key=default`` (``packlab prompt``)."""
    if key == "prompt":
        return f"{'packlab' if value is NOT_SET else _value_text(value)} prompt"
    return f"{key}={'default' if value is NOT_SET else _value_text(value)}"


def _labelled(key: str, value: object) -> bool:
    return key in LABELLED_OPTIONS and (key not in UNLABELLED or UNLABELLED[key] != value)


def option_settings(
    options: Mapping[str, object] | None, differing: Iterable[str] = ()
) -> list[str]:
    """The settings a row's label names: the :data:`LABELLED_OPTIONS` its run set (defaults
    aside), and each option in ``differing`` (those that differ between compared runs) whether
    set or not; labelled options first, in their order, then the others by name."""
    given = dict(options or {})
    shown = {k for k, v in given.items() if _labelled(k, v)}
    shown |= set(differing) - OPERATIONAL_OPTIONS
    order = [k for k in LABELLED_OPTIONS if k in shown] + sorted(shown - set(LABELLED_OPTIONS))
    return [option_setting(k, given.get(k, NOT_SET)) for k in order]


def with_settings(name: str, settings: Iterable[str]) -> str:
    """``name (a, b)``; ``name`` alone without settings."""
    shown = list(settings)
    return f"{name} ({', '.join(shown)})" if shown else name


def policy_label(
    policy: str, options: Mapping[str, object] | None = None, differing: Iterable[str] = ()
) -> str:
    """A row's label: the method's display name and the options it ran with that change what
    it measures (:func:`option_settings`), e.g. ``endpoint (reference prompt, image=blank)``;
    the display name alone for a method run with its defaults. ``options`` are the run's
    ``--policy-arg`` options of the method (summary.json ``policy_args``)."""
    return with_settings(display_name(policy), option_settings(options, differing))
