"""Command-line defaults and choices come from the config dataclasses, stated once.

Every option of every ``packlab`` subcommand either sets a config field (``cli/options.py``
``add_field``, recorded in ``FIELD_OPTIONS``) or is listed in ``CLI_ONLY`` below; an option that
sets a field has that field's default and, for a ``Literal`` field, exactly its choices.
"""

from __future__ import annotations

import argparse
import dataclasses
import typing

import pytest

from packlab.cli.main import build_parser
from packlab.cli.options import FIELD_OPTIONS, command_options, field_choices

#: The shortest valid command line of each subcommand.
MINIMAL_ARGV: dict[str, list[str]] = {
    "bench": ["bench"],
    "bench report": ["bench", "report", "runs/x"],
    "bench compare": ["bench", "compare", "runs/x"],
    "cases validate": ["cases", "validate", "cases.jsonl"],
    "cases export": ["cases", "export", "cases.jsonl", "--format", "jsonl", "--out", "x.jsonl"],
    "cases fresh": ["cases", "fresh", "packlab-bench-v1", "--seed", "1", "--out", "x.jsonl"],
    "generate": ["generate", "--out", "data"],
    "inspect-data": ["inspect-data", "data"],
    "policies": ["policies"],
    "train sft": ["train", "sft", "--data", "data", "--out", "runs/sft"],
    "train candidate": ["train", "candidate", "--cases", "cases", "--out", "runs/cand"],
    "train rl": ["train", "rl"],
    "train rl-imitate": ["train", "rl-imitate", "--states", "s.jsonl"],
    "export onnx": ["export", "onnx", "runs/rl/best"],
    "export sft": ["export", "sft", "data/packdata"],
    "serve": ["serve"],
    "cell serve": ["cell", "serve"],
    "cell schema": ["cell", "schema"],
    "viz episode": [
        "viz",
        "episode",
        "runs/x",
        "--case",
        "c",
        "--policy",
        "dblf",
        "--out",
        "x.png",
    ],
    "viz rerun": ["viz", "rerun", "runs/x", "--case", "c", "--policy", "dblf"],
}

#: Options that set no config field: what a command does (--describe), what it prints or draws,
#: or commands without a config dataclass (reading a run, the test server).
CLI_ONLY: dict[str, set[str]] = {
    "bench": {"--describe", "--no-figures", "--no-html", "--wide"},
    "bench report": {"--case", "--seed", "--no-figures", "--html", "--wide"},
    "bench compare": {"--labels", "--out", "--html", "--reference", "--wide"},
    "cases validate": set(),
    "cases export": {"--format", "--out"},
    "cases fresh": {"--seed", "--out", "--per-level"},
    "generate": set(),
    "inspect-data": {"--plots", "--json", "--tokenizer", "--token-sample"},
    "policies": {"--json"},
    "train sft": set(),
    "train candidate": {"--cases"},
    "train rl": {"--cases"},
    "train rl-imitate": {"--states", "--cases"},
    "export onnx": {"--check-states"},
    "export sft": {"--format", "--window", "--out"},
    "serve": {
        "--engine",
        "--model",
        "--served-name",
        "--host",
        "--port",
        "--max-new-tokens",
        "--print-command",
    },
    "cell serve": set(),
    "cell schema": {"--out"},
    "viz episode": {"--case", "--policy", "--seed", "--cases", "--out", "--max-steps"},
    # Live episodes take the bench's RunConfig; absent flags leave its defaults (stated there).
    "viz rerun": {
        "--case",
        "--policy",
        "--seed",
        "--cases",
        "--resimulate",
        "--live",
        "--backend",
        "--physics",
        "--policy-arg",
        "--out",
        "--spawn",
        "--connect",
    },
}


def _subcommands(
    parser: argparse.ArgumentParser, path: str = ""
) -> dict[str, argparse.ArgumentParser]:
    """Every (sub)command parser by its path ("bench", "train sft"); "" is the top level."""
    found = {path: parser}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found.update(_subcommands(sub, f"{path} {name}".strip()))
    return found


def _options(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {
        a.option_strings[0]: a
        for a in parser._actions
        if a.option_strings and not isinstance(a, argparse._HelpAction)
    }


PARSER = build_parser()  # fills FIELD_OPTIONS
#: Every command but those that only group subcommands ("cases", "train", "viz").
COMMANDS = {
    k: v
    for k, v in _subcommands(PARSER).items()
    if k and (_options(v) or not any(isinstance(a, argparse._SubParsersAction) for a in v._actions))
}


def test_every_command_is_listed_here():
    assert set(COMMANDS) == set(MINIMAL_ARGV) == set(CLI_ONLY)


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_option_sets_a_config_field_or_is_declared_cli_only(command):
    options = _options(COMMANDS[command])
    mapped = {o.flags[0] for o in command_options(command)}
    assert mapped.isdisjoint(CLI_ONLY[command])
    assert set(options) == mapped | CLI_ONLY[command], "add it with cli.options.add_field"


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_defaults_and_choices_come_from_the_config_field(command):
    args = PARSER.parse_args(MINIMAL_ARGV[command])
    actions = _options(COMMANDS[command])
    for option in command_options(command):
        where = f"packlab {command} {option.flags[0]} ({option.config.__name__}.{option.field})"
        action = actions[option.flags[0]]
        default = option.field_default
        if default is dataclasses.MISSING:  # a required field: required flag, or a rule (recipe)
            assert action.default is None, where
            continue
        if isinstance(action, argparse._AppendAction):  # argparse appends to a list
            assert action.default == list(default), where
        else:
            assert action.default == default, where
        assert option.value(args) == default, where
        allowed = field_choices(option.config, option.field)
        if allowed is not None:
            assert tuple(action.choices) == allowed, where


def test_literal_fields_take_their_choices_from_core_choices():
    from packlab.core import choices as core

    literals = {
        core.choices(t): t for t in vars(core).values() if typing.get_origin(t) is typing.Literal
    }
    for option in FIELD_OPTIONS.values():
        allowed = field_choices(option.config, option.field)
        if allowed is not None:
            where = f"{option.config.__name__}.{option.field}"
            assert allowed in literals, f"{where}: not a core.choices type"


def test_bench_with_no_flags_is_the_default_run_config():
    from packlab.bench.config import RunConfig
    from packlab.cli.bench import config_from_args

    assert config_from_args(PARSER.parse_args(["bench"])) == RunConfig()


def test_generate_defaults_are_the_dataset_config_defaults():
    from packlab.cli.generate import config_from_args, options_from_args
    from packlab.datagen.config import DatasetConfig
    from packlab.datagen.engine import RunOptions

    args = PARSER.parse_args(["generate", "--difficulty", "easy", "--episodes", "2", "--out", "d"])
    assert config_from_args(args) == DatasetConfig(("easy",), (2,))
    assert config_from_args(args).seed == 0
    assert options_from_args(args) == RunOptions("d")
    args = PARSER.parse_args(["generate", "--recipe", "packdata-mini", "--out", "d"])
    assert config_from_args(args) == DatasetConfig.from_recipe("packdata-mini")
    assert config_from_args(args).seed == 20250  # the recipe's seed, not 0


def test_train_sft_defaults_are_the_sft_config_defaults():
    from packlab.cli.train import config_from_args
    from packlab.vlm.train.config import SFTConfig

    args = PARSER.parse_args(MINIMAL_ARGV["train sft"])
    assert config_from_args(args) == SFTConfig(data="data", out="runs/sft")


def test_absent_flags_are_told_apart_after_the_parser_is_built_again():
    # main() builds a fresh parser on every call; options of an earlier build must still read
    # an absent flag as the field's default (not parse the default as if it were typed).
    from packlab.bench.config import RunConfig
    from packlab.cli.bench import config_from_args

    args = PARSER.parse_args(["bench", "--policy-arg", "dblf:x=1"])
    build_parser()
    assert config_from_args(args) == RunConfig(policy_args=(("dblf", "x", 1),))
    assert config_from_args(PARSER.parse_args(["bench"])) == RunConfig()
