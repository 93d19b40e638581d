"""Format events of the text-answer policies: packlab's parser labels answers as the
reference's does, both policies report them to the episode (``last_answer_format``), and the
reference prompt's ``fallback`` plays its relaxed mode (a forced set-aside) or its strict mode
(an invalid step)."""

from __future__ import annotations

import json

import pytest
from _cases import small_case
from msgspec import UNSET

from packlab.cli.policy_options import check_policy_args
from packlab.core.errors import ConfigError
from packlab.core.records import StepRecord, convert
from packlab.core.types import Action, Unparsable
from packlab.sim.episode import Episode, run_episode
from packlab.vlm.prompt.parse import parse_with_format
from packlab.vlm.serve.endpoint import EndpointPolicy
from packlab.vlm.serve.server import scripted, serve

ACTION = {"object_id": 0, "rotation": 0, "x": 0, "y": 0}
J = json.dumps(ACTION)
GARBAGE = "The box goes in the corner."
REFERENCE = '{"object_id":0,"x":0,"y":0,"rotation":0}'  # the reference's key order


@pytest.mark.parametrize(
    ("text", "event"),
    [
        (J, "strict_json"),
        (f"  \n{J}\n", "strict_json"),
        (f"<think>corner</think>\n{J}", "strict_json"),
        (f"```json\n{J}\n```", "extra_text"),
        (f"Answer: {J}.", "extra_text"),
        (f"<think>corner</think>Answer: {J}", "extra_text"),
        (GARBAGE, "parse_fail"),
        ('{"object_id": 0}', "parse_fail"),
        ("", "parse_fail"),
    ],
)
def test_packlab_parser_labels_each_answer(text, event):
    action, found = parse_with_format(text)
    assert found == event
    assert isinstance(action, Unparsable) == (event == "parse_fail")


def _steps(result) -> list[StepRecord]:
    return [convert(s, StepRecord, "step") for s in result.to_record()["steps"]]


def _played(answers, default, **options):
    """The step records of one episode of ``endpoint`` against a scripted server."""
    with serve(scripted(answers, default=default)) as server:
        policy = EndpointPolicy(base_url=server.base_url, deadline_s=5, retries=0, **options)
        return _steps(run_episode(small_case(), policy, 0, backend="geometric"))


def test_endpoint_reports_packlab_prompt_events():
    steps = _played([f"```\n{J}\n```", GARBAGE], J)
    assert [s.format_event for s in steps[:3]] == ["extra_text", "parse_fail", "strict_json"]
    assert steps[1].reason == "unparsable" and steps[1].action.unparsable == GARBAGE


def test_fallback_set_aside_plays_a_forced_set_aside():
    steps = _played([GARBAGE], REFERENCE, prompt="reference")
    first = steps[0]
    assert (first.format_event, first.forced, first.reason) == (
        "parse_fail",
        "parse_fail",
        "set_aside",
    )
    assert first.valid is False and first.action.placement() is not None  # Action.set_aside(k)
    assert {s.format_event for s in steps[1:]} == {"strict_json"}


def test_fallback_invalid_records_an_invalid_step():
    steps = _played(
        [GARBAGE, '{"object_id":7,"x":0,"y":0}'], REFERENCE, prompt="reference", fallback="invalid"
    )
    first, second = steps[:2]
    assert (first.format_event, first.reason) == ("parse_fail", "unparsable")
    assert (first.action.unparsable, first.action.error) == (GARBAGE, "json_parse_failed")
    assert first.forced is UNSET and first.reasked is UNSET  # nothing forced, no re-ask on
    # An object outside the buffer is played as the model named it (the strict mode's way).
    assert (second.format_event, second.reason) == ("strict_json", "bad_object_id")


def test_fallback_is_checked():
    with pytest.raises(ConfigError, match="fallback = 'strict'"):
        EndpointPolicy(prompt="reference", fallback="strict")
    with pytest.raises(ConfigError, match="fallback = 'invalid': applies to prompt=reference"):
        EndpointPolicy(fallback="invalid")
    assert EndpointPolicy(prompt="reference", fallback="invalid").config()["fallback"] == "invalid"
    check_policy_args([("endpoint", "fallback", "invalid"), ("vlm", "fallback", "set_aside")])
    with pytest.raises(ConfigError, match="policy-arg endpoint:fallback = 'nope'"):
        check_policy_args([("endpoint", "fallback", "nope")])


class _Reports:
    """A policy whose hook reports ``value`` at every step."""

    name = "reporter"

    def __init__(self, value):
        self.value = value

    def reset(self, case, seed):
        pass

    def act(self, observation):
        return Action(0, 0, 0, 0)

    def last_answer_format(self):
        return self.value


@pytest.mark.parametrize(
    ("value", "said"),
    [
        ({"format_event": "fenced"}, "format_event = 'fenced'"),
        ({"format_event": "strict_json", "reasked": "yes"}, "reasked = 'yes'"),
        ({"format_event": "strict_json", "forced": ""}, "forced = ''"),
        ({"format_event": "strict_json", "why": 1}, "unknown key(s) 'why'"),
        ("strict_json", "expected a mapping"),
    ],
)
def test_a_bad_hook_value_is_named(value, said):
    with pytest.raises(ValueError, match="policy 'reporter': last_answer_format") as err:
        run_episode(small_case(), _Reports(value), 0, backend="geometric")
    assert said in str(err.value)


def test_the_hook_reaches_every_step_record():
    report = {"format_event": "extra_text", "reasked": True, "forced": "parse_fail"}
    steps = _steps(run_episode(small_case(), _Reports(report), 0, backend="geometric"))
    assert {(s.format_event, s.reasked, s.forced) for s in steps} == {
        ("extra_text", True, "parse_fail")
    }
    silent = run_episode(small_case(), _Reports(None), 0, backend="geometric").to_record()
    assert not any("format_event" in s for s in silent["steps"])


@pytest.mark.torch
def test_local_model_reports_events_and_plays_the_strict_fallback():
    pytest.importorskip("transformers")
    from packlab.vlm.infer.policy import VLMPolicy

    case = small_case()
    observation = Episode("geometric").reset(case, 0)
    common = {"model": "tiny:qwen3_5:tiny", "max_new_tokens": 4, "device": "cpu"}
    # A random-weight model writes no JSON: its answer is a parse failure, under either prompt.
    for options in ({"prompt": "reference", "fallback": "invalid"}, {}):
        policy = VLMPolicy(**common, **options)
        policy.reset(case, 0)
        assert isinstance(policy.act(observation), Unparsable)
        assert policy.last_answer_format() == {"format_event": "parse_fail"}
    assert policy.config()["fallback"] == "set_aside"
