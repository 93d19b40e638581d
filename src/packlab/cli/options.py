"""Command-line options that set a config dataclass field, with everything read from the field.

``add_field(parser, RunConfig, "seeds", "--seeds", parse=parse_seeds, help=...)`` adds an
argparse option whose default is the field's default, whose choices are the values of the
field's ``Literal`` type (``packlab.core.choices``) and whose argparse type follows the field's
type (int, float; a bool field becomes a switch: ``--x`` for a False default, ``--no-x`` for a
True one). A default or a choice list is therefore written once, in the config dataclass.

Fields whose value is not a single int, float or string (tuples, dicts) take ``parse``: a
function from the command-line text (or, with ``action="append"``, the list of texts) to the
field's value. It runs when the config is built (:func:`config_kwargs`), not inside argparse,
so its ``ConfigError`` is the command's usual one-line error.

Every option made here is recorded in :data:`FIELD_OPTIONS` under (command, flag), e.g.
``("bench", "--seeds")`` or ``("train sft", "--lr")``; ``tests/test_cli_defaults.py`` checks
each against its field.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, get_args, get_origin, get_type_hints

from packlab.core.choices import choices as literal_choices

#: (command, first flag) -> the option; filled as the parsers are built (``cli.main.build_parser``).
FIELD_OPTIONS: dict[tuple[str, str], FieldOption] = {}
#: The placeholder in a help text that ``add_field`` replaces with the default as one would type it.
DEFAULT_TOKEN = "{default}"


@dataclass(frozen=True)
class FieldOption:
    """One option that sets ``config.<field>``."""

    command: str  # "bench", "generate", "train sft", ...
    flags: tuple[str, ...]
    dest: str  # attribute of the parsed namespace
    config: type
    field: str
    cli_default: Any  # what argparse leaves in the namespace when the flag is absent
    parse: Callable[[Any], Any] | None = None

    @property
    def field_default(self) -> Any:
        return field_default(self.config, self.field)

    def value(self, args: argparse.Namespace) -> Any:
        """The field's value from the parsed arguments (``dataclasses.MISSING``: not given and
        the field has no default, so the config's own rule applies, e.g. a recipe's value)."""
        value = getattr(args, self.dest)
        if value is self.cli_default:  # the flag was absent
            return self.field_default
        return value if self.parse is None else self.parse(value)


def field_default(config: type, name: str) -> Any:
    """The default of ``config.<name>`` (``default_factory`` called), or ``dataclasses.MISSING``."""
    for f in dataclasses.fields(config):
        if f.name == name:
            if f.default is not dataclasses.MISSING:
                return f.default
            if f.default_factory is not dataclasses.MISSING:
                return f.default_factory()
            return dataclasses.MISSING
    raise TypeError(f"{config.__name__} has no field {name!r}")


def field_type(config: type, name: str) -> Any:
    """The field's annotation with ``X | None`` reduced to ``X``."""
    hint = get_type_hints(config)[name]
    if get_origin(hint) in (typing.Union, types.UnionType):
        args = [a for a in get_args(hint) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return hint


def field_choices(config: type, name: str) -> tuple[str, ...] | None:
    """The allowed values of a ``Literal``-typed field, else None."""
    hint = field_type(config, name)
    return literal_choices(hint) if get_origin(hint) is Literal else None


def shown_default(value: Any) -> str:
    """A default as typed: ``0,1,2`` for a tuple, ``none`` for None, ``1800`` for 1800.0."""
    if value is None or value is dataclasses.MISSING:
        return "none"
    if isinstance(value, (tuple, list)):
        return ",".join(map(str, value)) or "none"
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def _command(parser: argparse.ArgumentParser) -> str:
    """``"packlab train sft"`` -> ``"train sft"`` (argparse names a subparser by its path)."""
    return parser.prog.partition(" ")[2]


@functools.cache
def _cli_default(config: type, name: str, append: bool) -> Any:
    """The field default as argparse holds it; one object per field however often the parser is
    built, so ``FieldOption.value`` can tell an absent flag by identity."""
    default = field_default(config, name)
    if default is dataclasses.MISSING:
        return None  # a field without a default: the flag is required or has a rule
    return list(default) if append else default  # argparse appends to a copy of a list default


def _argparse_kwargs(
    config: type,
    name: str,
    flags: tuple[str, ...],
    default: Any,
    parse: Callable[[Any], Any] | None,
    kwargs: dict[str, Any],
) -> dict[str, Any]:
    hint = field_type(config, name)
    allowed = field_choices(config, name)
    if allowed is not None:
        if "choices" in kwargs:
            raise TypeError(f"{config.__name__}.{name}: choices come from its Literal type")
        kwargs["choices"] = allowed
    elif hint is bool and parse is None:
        negated = flags[0].startswith("--no-")
        if default is not negated:  # --x sets True (default False); --no-x sets False
            raise TypeError(
                f"{config.__name__}.{name} defaults to {default}: name the switch "
                f"{'--no-' if default else '--'}..."
            )
        kwargs.setdefault("action", "store_false" if default else "store_true")
        kwargs.setdefault("dest", name)
    elif hint in (int, float) and parse is None:
        kwargs.setdefault("type", hint)
    elif hint is not str and parse is None and "type" not in kwargs:
        raise TypeError(f"{config.__name__}.{name}: a {hint} field needs parse= (text -> value)")
    return kwargs


def add_field(
    parser: argparse.ArgumentParser,
    config: type,
    name: str,
    *flags: str,
    parse: Callable[[Any], Any] | None = None,
    help: str | None = None,
    **kwargs: Any,
) -> argparse.Action:
    """Add an option setting ``config.<name>``; default, choices and type come from the field.

    ``help`` may hold ``{default}``, replaced by the field's default as typed on the command line.
    Other keyword arguments go to ``parser.add_argument`` (``required``, ``metavar``, ``action``,
    ``type`` for a value ``parse`` then converts, ``choices`` for a non-Literal field).
    """
    kwargs = _argparse_kwargs(config, name, flags, field_default(config, name), parse, kwargs)
    default = _cli_default(config, name, kwargs.get("action") == "append")
    if help is not None:
        help = help.replace(DEFAULT_TOKEN, shown_default(field_default(config, name)))
    action = parser.add_argument(*flags, default=default, help=help, **kwargs)
    option = FieldOption(_command(parser), tuple(flags), action.dest, config, name, default, parse)
    FIELD_OPTIONS[(option.command, flags[0])] = option
    return action


def command_options(command: str, config: type | None = None) -> list[FieldOption]:
    """The options of a command (optionally only those setting fields of ``config``)."""
    return [
        o
        for (cmd, _), o in FIELD_OPTIONS.items()
        if cmd == command and (config is None or o.config is config)
    ]


def config_kwargs(args: argparse.Namespace, command: str, config: type) -> dict[str, Any]:
    """Keyword arguments for ``config`` from the parsed arguments of ``command``: every field one
    of its options sets, except fields without a default whose flag was not given."""
    out = {}
    for option in command_options(command, config):
        value = option.value(args)
        if value is not dataclasses.MISSING:
            out[option.field] = value
    return out


__all__ = [
    "DEFAULT_TOKEN",
    "FIELD_OPTIONS",
    "FieldOption",
    "add_field",
    "command_options",
    "config_kwargs",
    "field_choices",
    "field_default",
    "field_type",
    "shown_default",
]
