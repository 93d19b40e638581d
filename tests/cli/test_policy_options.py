"""The CLI's light copy of each built-in policy's options (packlab.cli.policy_options) agrees
with the factories, and ``--policies``' help states the real default list."""

from __future__ import annotations

import inspect
from importlib.metadata import entry_points

from packlab.bench.config import default_policies
from packlab.bench.options import DEFAULT_POLICIES
from packlab.bench.suites import load_suite
from packlab.cli import policy_options as po
from packlab.cli.main import build_parser
from packlab.core.choices import HEURISTICS


def test_every_builtin_policy_has_an_entry():
    declared = {ep.name for ep in entry_points(group="packlab.policies")}
    assert set(po.POLICY_OPTIONS) == declared


def test_option_names_match_the_factories():
    from packlab.policies.candidates import ProposerPolicy
    from packlab.policies.heuristics.policy import OPTIONS as HEURISTIC_OPTIONS
    from packlab.policies.plan import policy as plan
    from packlab.rl.policy import OPTIONS as RL_OPTIONS
    from packlab.vlm.infer.policy import CANDIDATE_ARGS, VLMPolicy
    from packlab.vlm.serve.endpoint import EndpointPolicy

    def keys(name: str) -> set[str]:
        return set(po.POLICY_OPTIONS[name].keys)

    for name in HEURISTICS:
        assert keys(name) == set(HEURISTIC_OPTIONS)
    plan_keys = {
        *plan._BUDGET_KEYS,
        *plan._WEIGHT_KEYS,
        *plan._COMPLETION_KEYS,
        *plan._ENDGAME_KEYS,
        *plan._SWITCHES,
        *plan._FINALE_KEYS,
        *plan._ENDPLAY_KEYS,
    }
    assert keys("plan") == plan_keys | {"stability", "overflow", "commit", *plan._GUIDE_KEYS}
    assert keys("irbpp") == keys("tapnet") == set(RL_OPTIONS)
    assert keys("vlm") == set(inspect.signature(VLMPolicy).parameters) | set(CANDIDATE_ARGS)
    assert keys("endpoint") == set(inspect.signature(EndpointPolicy).parameters)
    assert keys("proposer") == set(inspect.signature(ProposerPolicy).parameters)


def test_marker_file_names_match_the_loaders():
    from packlab.policies.onnx_model import CARD_FILE as ONNX_CARD
    from packlab.rl.card import CARD_FILE
    from packlab.vlm.candidate.files import HEAD_FILE

    assert (po.RL_CARD, po.ONNX_CARD, po.POINTER_HEAD) == (CARD_FILE, ONNX_CARD, HEAD_FILE)


def test_shipped_models_pass_the_checks():
    from packlab.rl.policy import SHIPPED_MODELS

    po.check_policy_args(
        [
            ("irbpp", "model", str(SHIPPED_MODELS / "irbpp")),
            ("tapnet", "model", str(SHIPPED_MODELS / "tapnet")),
            ("vlm", "model", str(SHIPPED_MODELS / "vlm-small")),
            ("vlm", "model", "tiny:qwen3_5:tiny"),
        ]
    )


def test_heuristic_names_match_the_scorers():
    from packlab.policies.heuristics import SCORERS

    assert tuple(SCORERS) == HEURISTICS


def test_policies_help_states_the_default_list():
    bench = build_parser()._subparsers._group_actions[0].choices["bench"]  # type: ignore[union-attr]
    policies = next(a for a in bench._actions if "--policies" in a.option_strings)
    assert ", ".join(DEFAULT_POLICIES) in policies.help
    assert default_policies(tuple(load_suite("packlab-bench-v1"))) == DEFAULT_POLICIES
    assert len(DEFAULT_POLICIES) == 11


def test_light_policy_names_are_the_registry_names():
    from packlab.bench.options import POLICY_ENTRY_POINTS, POLICY_REGISTRY, policy_names
    from packlab.policies import registry

    assert (POLICY_REGISTRY, POLICY_ENTRY_POINTS) == (registry.__name__, registry.ENTRY_POINT_GROUP)
    assert policy_names() == registry.available_policies()
