"""What ``packlab policies`` does (:mod:`packlab.cli.policies` defines its flags and imports this
module when it runs): every policy a bench can run, with its options and their defaults.

Options and defaults are read from the code, not restated. A built-in's option names are those
``--policy-arg`` accepts (:data:`packlab.cli.policy_options.POLICY_OPTIONS`, which a test keeps
equal to each factory's), and each default is read off a policy its factory makes with no
options, through the attribute that holds it (:attr:`Builtin.paths`): the factory applies its
own defaults (``plan-fast``'s smaller budget, ``irbpp-random``'s ``k``), so what is shown is
what a bench row without ``--policy-arg`` plays. Another package's policy shows the keyword
parameters of its factory, or of its class when the factory takes ``**kwargs``. Making a policy
loads no model (each loads on its first ``reset``); listing costs the imports of the families.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import textwrap
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any

import packlab
from packlab.bench.options import DEFAULT_POLICIES
from packlab.cli.policy_options import POLICY_OPTIONS, TEXT_ANSWER_KEYS
from packlab.core.choices import HEURISTICS, did_you_mean
from packlab.core.errors import ConfigError
from packlab.policies.registry import ENTRY_POINT_GROUP, available_policies, policy_factory

#: The version of ``packlab policies --json``'s output.
FORMAT = "packlab-policies-1"
#: The distribution that declares the built-in policies.
PACKLAB_DIST = "packlab"
CORE = "core install"
PACKAGE_DIR = Path(packlab.__file__).resolve().parent
WIDTH = 100
NAME_COLUMN = 16

#: A random-weight text-answer model: made (never loaded) to read the text-answer defaults.
TINY_TEXT_MODEL = "tiny:qwen3_5:tiny"
_TEXT_ONLY = "text-answer checkpoints only"


@dataclass(frozen=True)
class Builtin:
    """What the code cannot say about a built-in policy, and where its defaults live."""

    description: str
    needs: str = CORE
    #: The extra some setting needs (``runtime=torch``, a text-answer checkpoint); None: none.
    extra: str | None = None
    #: Option -> attribute path on a policy made with no options (default: the option's name).
    paths: Mapping[str, str] = field(default_factory=dict)
    notes: Mapping[str, str] = field(default_factory=dict)
    #: Factory keywords of the policies made to read defaults, first match wins: ``vlm``'s
    #: text-answer options live on a text-answer policy, not on the shipped pointer model.
    probes: tuple[Mapping[str, Any], ...] = ({},)
    #: Options ``--policy-arg`` passes on but the factory refuses (not shown).
    refused: tuple[str, ...] = ()


_PLAN_PATHS = {
    **{k: f"budget.{k}" for k in ("first", "listed", "rollout", "depth", "beam", "time_s")},
    **{
        f"w_{k}": f"weights.{k}"
        for k in ("final", "open", "over_rim", "steps", "trapped", "unreachable")
    },
    "nodes": "completion.max_nodes",
    "decision_nodes": "completion.decision_nodes",
    "jokers": "completion.max_jokers",
    "joker_seen": "completion.joker_min_seen",
    "guesses": "completion.guesses",
    "mixed_jokers": "completion.mixed_jokers",
    "mixed_evidence": "completion.mixed_evidence",
    "mixed": "completion.mixed",
    "commit": "completion.commit",
    "endgame_nodes": "endgame.config.max_nodes",
    "endgame_boxes": "endgame.config.max_boxes",
    "guillotine_nodes": "endgame.config.guillotine_nodes",
    "guillotine_boxes": "endgame.config.guillotine_boxes",
    "endplay": "endplay.config.alternatives",
    "endplay_boxes": "endplay.config.max_boxes",
    "guide": "guide.agent",
    "guide_model": "guide.model",
    "guide_first": "guide.first",
}
_PLAN_NOTES = {
    "time_s": "no time limit, so bit-reproducible",
    "guide_model": "the shipped agent that guide names",
}
_RL_NEEDS = f"{CORE} (ONNX Runtime); runtime=torch needs the rl extra"
_VLM_PATHS = {"model": "model_spec"}
_VLM_NOTES = {k: _TEXT_ONLY for k in TEXT_ANSWER_KEYS}
_HEURISTICS = {
    "dblf": "Deepest-Bottom-Left-Fill heuristic: the lowest resting place, then the deepest, "
    "then the leftmost",
    "hm": "Heightmap Minimization heuristic: the placement that raises the heightmap's sum least",
    "mta": "Maximum Touching Area heuristic: the placement touching the most floor, walls, boxes",
    "ffp": "First Feasible Placement heuristic: the first placement, box by box, under the rim",
    "sdf": "SDF-Pack heuristic: a low resting height plus a snug fit on a distance field",
}

#: Every policy packlab declares (pyproject ``packlab.policies``); a test checks the two agree.
BUILTINS: dict[str, Builtin] = {
    **{name: Builtin(_HEURISTICS[name]) for name in HEURISTICS},
    "random": Builtin("Uniform over the placements whose top stays under the rim (the floor row)"),
    "oracle": Builtin("Replays a case's perfect layout (gt_plan): the ceiling; needs that plan"),
    "plan": Builtin(
        "The planner: exact completion of the lowest free level, else a receding-horizon lookahead",
        paths=_PLAN_PATHS,
        notes=_PLAN_NOTES,
    ),
    "plan-fast": Builtin(
        "Plan at a smaller search budget (first, depth, listed, no endplay): the bench's planner",
        paths=_PLAN_PATHS,
        notes=_PLAN_NOTES,
    ),
    "plan-lookahead": Builtin(
        "Plan without its completion stage: the lookahead alone (an ablation row)",
        paths=_PLAN_PATHS,
        notes=_PLAN_NOTES,
    ),
    "proposer": Builtin(
        "The proposer's first listed placement: the floor a candidate-mode model starts from",
        paths={"k": "config.k", "rule": "config.rule"},
    ),
    "vlm": Builtin(
        "A packing VLM: the shipped pointer model (candidate mode), or a checkpoint as model=DIR",
        needs=f"{CORE} for candidate-mode checkpoints (ONNX Runtime); text-answer checkpoints, "
        "tiny: models and runtime=torch need the vlm extra",
        extra="vlm",
        paths=_VLM_PATHS,
        notes=_VLM_NOTES,
        probes=({}, {"model": TINY_TEXT_MODEL}),
    ),
    "vlm-small": Builtin(
        "The shipped candidate-mode VLM (PackLab pointer LM, packlab/data/models/vlm-small)",
        needs=f"{CORE} (ONNX Runtime); runtime=torch needs the vlm extra",
        extra="vlm",
        paths=_VLM_PATHS,
        notes={"model": "fixed: use policy vlm with model=DIR for another"},
        refused=TEXT_ANSWER_KEYS,  # a candidate-mode checkpoint takes none of them
    ),
    "endpoint": Builtin(
        "A packing VLM behind an OpenAI-compatible chat-completions server (vLLM, packlab serve)",
        needs=f"{CORE}; a running server at base_url (packlab serve --engine vllm serves a "
        "checkpoint with vLLM: the vllm extra)",
        paths={"history": "options.history", "image": "options.image", "timeout_s": "deadline_s"},
        notes={
            "timeout_s": "older name of deadline_s",
            "seed": "the server's choice",
            "prompt": "packlab | reference: the reference implementation's prompt and parsing "
            "(docs/vlm.md)",
            "max_tokens": "512 under prompt=reference",
            "reask": "prompt=reference: ask once more after an answer that does not parse",
            "fallback": "prompt=reference, after an unreadable answer: set_aside a random "
            "shown box | invalid: an invalid step (the reference's strict mode)",
            "tag_requests": "send the OpenAI user field as <case id>/<run seed> (server logs, "
            "scripted test servers); names the case, so never for a model under evaluation",
        },
    ),
    "irbpp": Builtin(
        "A trained RL agent choosing among listed placements (IR-BPP's action space)",
        needs=_RL_NEEDS,
        extra="rl",
        paths={"model": "model_dir"},
    ),
    "tapnet": Builtin(
        "A trained RL agent choosing the object, placed by rule (TAP-Net's action space)",
        needs=_RL_NEEDS,
        extra="rl",
        paths={"model": "model_dir"},
    ),
    "irbpp-random": Builtin(
        "A uniformly random row of irbpp's action space: the floor an agent must clear",
        paths={"k": "spec.n_items"},
    ),
    "tapnet-random": Builtin(
        "A uniformly random row of tapnet's action space: the floor an agent must clear"
    ),
}


@dataclass(frozen=True)
class OptionInfo:
    """One ``--policy-arg NAME:KEY=VALUE`` key and its default."""

    key: str
    default: Any = None
    #: False when the default could not be read (the value is then meaningless).
    known: bool = True
    note: str = ""


@dataclass(frozen=True)
class PolicyInfo:
    """One policy as ``packlab policies`` shows it."""

    name: str
    description: str
    #: The distribution that declares it (``packlab`` for the built-ins), or ``run time``.
    source: str
    factory: str  # module:attribute
    needs: str
    extra: str | None
    default_row: bool  # a row of ``packlab bench`` without --policies
    options: tuple[OptionInfo, ...]
    error: str = ""  # why the defaults could not be read ("" when they were)


def _declared() -> dict[str, EntryPoint]:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def _dist_name(ep: EntryPoint | None) -> str:
    if ep is None:
        return "run time"
    dist = getattr(ep, "dist", None)
    return str(dist.name) if dist is not None else "unknown package"


def _read(obj: Any, path: str) -> Any:
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def _make_all(factory: Callable[..., Any], probes: Iterable[Mapping[str, Any]]) -> list[Any]:
    """Policies made from each probe's keywords; a probe the factory refuses is skipped."""
    made = []
    for probe in probes:
        try:
            made.append(factory(**probe))
        except Exception:  # a probe that does not apply reads nothing (the first re-raises)
            if not probe:
                raise
    return made


def _builtin_options(name: str, spec: Builtin) -> tuple[tuple[OptionInfo, ...], str]:
    keys = [k for k in POLICY_OPTIONS[name].keys if k not in spec.refused]
    try:
        made = _make_all(policy_factory(name), spec.probes)
    except Exception as exc:  # noqa: BLE001 - shown as why the defaults are missing
        unknown = tuple(OptionInfo(k, None, False, spec.notes.get(k, "")) for k in keys)
        return unknown, f"{type(exc).__name__}: {exc}"
    options = []
    for key in keys:
        path, note = spec.paths.get(key, key), spec.notes.get(key, "")
        for policy in made:
            try:
                options.append(OptionInfo(key, _read(policy, path), True, note))
                break
            except AttributeError:
                continue
        else:
            options.append(OptionInfo(key, None, False, note))
    return tuple(options), ""


def _keywords(target: Any) -> tuple[list[OptionInfo], bool]:
    """(keyword parameters of a callable with their defaults, whether it takes ``**kwargs``)."""
    options, var_keyword = [], False
    for param in inspect.signature(target).parameters.values():
        if param.kind is param.VAR_KEYWORD:
            var_keyword = True
        elif param.kind in (param.POSITIONAL_OR_KEYWORD, param.KEYWORD_ONLY):
            required = param.default is param.empty
            note = "required" if required else ""
            options.append(OptionInfo(param.name, None if required else param.default, True, note))
    return options, var_keyword


def _plugin(factory: Callable[..., Any]) -> tuple[str, tuple[OptionInfo, ...], str]:
    """(description, options, error) of a policy packlab does not declare: its factory's
    docstring and keyword parameters, else its class's (read off a policy it makes)."""
    description = inspect.getdoc(factory) or ""
    options, var_keyword = _keywords(factory)
    if description and not var_keyword:  # all there is to say, without making one
        return description, tuple(options), ""
    try:
        policy = factory()
    except Exception as exc:  # noqa: BLE001 - another package's factory may raise anything
        return description, tuple(options), f"{type(exc).__name__}: {exc}"
    description = description or inspect.getdoc(type(policy)) or ""
    if var_keyword:
        seen = {o.key for o in options}
        options += [o for o in _keywords(type(policy))[0] if o.key not in seen]
    return description, tuple(options), ""


def describe(name: str, declared: Mapping[str, EntryPoint] | None = None) -> PolicyInfo:
    """One policy (ConfigError naming the nearest known one when there is no such policy)."""
    names = available_policies()
    if name not in names:
        raise ConfigError(
            f"no policy {name!r}{did_you_mean(name, names)}; packlab policies lists the "
            f"{len(names)} there are"
        )
    declared = _declared() if declared is None else declared
    ep = declared.get(name)
    source = _dist_name(ep)
    needs = f"the {source} package" if ep is not None else "registered in this process"
    try:
        factory = policy_factory(name)
    except Exception as exc:  # noqa: BLE001 - a broken package is one entry, not a crash
        where = ep.value if ep is not None else "?"
        failed = f"cannot load {where}: {type(exc).__name__}: {exc}"
        return PolicyInfo(name, "(not loadable)", source, where, needs, None, False, (), failed)
    where = ep.value if ep is not None else f"{factory.__module__}:{factory.__qualname__}"
    spec = BUILTINS.get(name) if source == PACKLAB_DIST else None
    if spec is not None:
        options, error = _builtin_options(name, spec)
        description, needs, extra = spec.description, spec.needs, spec.extra
    else:
        description, options, error = _plugin(factory)
        extra = None
    first_line = description.strip().splitlines()[0] if description.strip() else ""
    return PolicyInfo(
        name=name,
        description=first_line or "(no description: give its factory a docstring)",
        source=source,
        factory=where,
        needs=needs,
        extra=extra,
        default_row=name in DEFAULT_POLICIES,
        options=options,
        error=error,
    )


def describe_all() -> list[PolicyInfo]:
    """Every policy: packlab's own by name, then the others by name."""
    declared = _declared()
    own = sorted(n for n, ep in declared.items() if _dist_name(ep) == PACKLAB_DIST)
    others = sorted(set(available_policies()) - set(own))
    return [describe(name, declared) for name in [*own, *others]]


def _shown(value: Any) -> str:
    """A default as ``--policy-arg`` would take it (true/false, none for None)."""
    if isinstance(value, bool):
        return str(value).lower()
    if value is None:
        return "none"
    if isinstance(value, (str, Path)) and os.path.isabs(str(value)):
        path = Path(value)
        if path.is_relative_to(PACKAGE_DIR):  # a shipped model: where it sits in the package
            return str(path.relative_to(PACKAGE_DIR.parent))
    return str(value)


def _option_line(option: OptionInfo) -> str:
    return f"{option.key}={_shown(option.default) if option.known else '?'}"


def format_list(infos: Iterable[PolicyInfo]) -> str:
    """The listing: a policy per paragraph (description, options with defaults, needs)."""
    lines = []
    indent = " " * NAME_COLUMN
    for info in infos:
        star = " *" if info.default_row else ""
        head = f"{info.name + star:<{NAME_COLUMN - 1}} {info.description}"
        lines += textwrap.wrap(head, WIDTH, subsequent_indent=indent)
        options = " ".join(_option_line(o) for o in info.options) or "none"
        lines += textwrap.wrap(
            f"options: {options}", WIDTH, initial_indent=indent, subsequent_indent=indent + "  "
        )
        lines += textwrap.wrap(
            f"needs: {info.needs}", WIDTH, initial_indent=indent, subsequent_indent=indent + "  "
        )
        if info.error:
            lines += textwrap.wrap(f"defaults not read: {info.error}", WIDTH, initial_indent=indent)
    footer = (
        "* a row of packlab bench without --policies. Set an option with "
        "--policy-arg NAME:KEY=VALUE; one policy in detail: packlab policies NAME."
    )
    return "\n".join([*lines, "", *textwrap.wrap(footer, WIDTH)])


def format_one(info: PolicyInfo) -> str:
    """One policy in detail: an option a line, with its default and a note."""
    lines = [
        f"{info.name}: {info.description}",
        f"  declared by: {info.source} ({info.factory})",
        *textwrap.wrap(f"  needs: {info.needs}", WIDTH, subsequent_indent="    "),
        f"  default bench row: {'yes' if info.default_row else 'no'}",
    ]
    if info.error:
        lines.append(f"  defaults not read: {info.error}")
    if not info.options:
        lines.append("  options: none")
        return "\n".join(lines)
    lines.append(f"  options (--policy-arg {info.name}:KEY=VALUE), default:")
    width = max(len(o.key) for o in info.options) + 2
    for option in info.options:
        value = _shown(option.default) if option.known else "?"
        note = f"  ({option.note})" if option.note else ""
        lines.append(f"    {option.key:<{width}}{value}{note}")
    return "\n".join(lines)


def _json_value(value: Any) -> Any:
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (list, tuple)):
        return [_json_value(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _json_value(v) for k, v in value.items()}
    return str(value)


def to_json(infos: Iterable[PolicyInfo]) -> dict[str, Any]:
    """``packlab policies --json``: the format version and every policy as plain data."""
    policies = []
    for info in infos:
        options = [
            {"key": o.key, "default": _json_value(o.default), "known": o.known, "note": o.note}
            for o in info.options
        ]
        policies.append(
            {
                "name": info.name,
                "description": info.description,
                "source": info.source,
                "factory": info.factory,
                "needs": info.needs,
                "extra": info.extra,
                "default_row": info.default_row,
                "options": options,
                "error": info.error,
            }
        )
    return {"format": FORMAT, "policies": policies}


def run(args: argparse.Namespace) -> int:
    """``packlab policies [NAME] [--json]``."""
    infos = [describe(args.name)] if args.name else describe_all()
    if args.json:
        print(json.dumps(to_json(infos), indent=1))
    elif args.name:
        print(format_one(infos[0]))
    else:
        print(format_list(infos))
    return 0
