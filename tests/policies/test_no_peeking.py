"""No policy reads what the episode does not hand it.

Every policy declared under the ``packlab.policies`` entry-point group (listed at collection
time, so a newly registered one is covered without touching this file) plays one small case,
once with the real case and once with a :class:`BlindCase` at ``reset``: a stand-in that answers
only the fields a policy may know before the first observation and fails the test on any other
read (the arrival sequence ``objects``, so future objects and true sizes in perceived mode; the
``gt_plan``; ``difficulty``, ``generator``, ``origin``; the ``episode_id``, which names a bench
case and so its content). Reads are also recorded, so a policy that swallows the failure is
still caught. The blind run must take the same actions as the honest one, in exact and in
perceived mode (a deterministic fake perceiver that shows sizes off the grid).

The one exception is :data:`PEEKS_BY_DESIGN`.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Iterator
from contextlib import contextmanager
from importlib.metadata import entry_points
from typing import Any

import numpy as np
import pytest
from layered_cases import make_layered_case

from packlab.core.types import Action, Case
from packlab.policies import make_policy
from packlab.policies.registry import ENTRY_POINT_GROUP
from packlab.sim.episode import Episode
from packlab.sim.replan import Perception, Scene

#: Every bench policy: the names declared under the entry-point group (run-time registrations
#: are test doubles, e.g. tests/bench's deliberately crashing policy, and are left out).
BENCH_POLICIES = sorted({ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)})

#: Policies that read what the episode does not hand a policy, on purpose, and why.
PEEKS_BY_DESIGN = {
    "oracle": "replays the case's gt_plan (the generator's perfect packing): the upper bound "
    "reported beside the policies, not a policy under test",
}

#: The case fields a policy may read at reset. ``container`` and ``buffer_size`` are in every
#: observation anyway; ``seed`` is an ingredient of a policy's own random stream (the random
#: baselines derive theirs from it and the run seed, as the episode derives the buffer shuffle).
ALLOWED = ("container", "buffer_size", "seed")

#: Options that make a policy cheap and self-contained here; the rest are built with none.
OPTIONS: dict[str, dict[str, Any]] = {
    "vlm": {"model": "tiny:qwen3_5:tiny", "max_new_tokens": 8},  # the generative path
}

#: Modules a policy needs beyond the core install (skipped where they are missing).
EXTRAS = {
    "vlm": ("torch", "transformers"),  # OPTIONS: a tiny generative model (the torch path)
}


class BlindCase:
    """The case as a policy may see it at reset: ``ALLOWED`` fields (plus ``also``) only."""

    def __init__(self, case: Case, also: tuple[str, ...] = ()) -> None:
        for name in (*ALLOWED, *also):
            object.__setattr__(self, name, getattr(case, name))
        object.__setattr__(self, "forbidden_reads", [])

    def __getattr__(self, name: str) -> Any:  # only called for names not set above
        self.forbidden_reads.append(name)
        # Not an AttributeError: getattr(case, name, default) and hasattr must not hide it.
        raise AssertionError(f"the policy read case.{name}, which the episode does not hand it")

    def __setattr__(self, name: str, value: Any) -> None:
        raise AssertionError(f"the policy wrote case.{name}")


class OffGridPerceiver:
    """A deterministic perceived mode: every shown size 7 mm long, 4 mm narrow, 3 mm tall, and
    the heightmap 2 mm high wherever something stands (so a leak of the true one shows). The
    heightmaps it returned are kept in ``seen``."""

    def __init__(self) -> None:
        self.seen: list[np.ndarray] = []

    def __call__(self, scene: Scene, rng: np.random.Generator) -> Perception:
        sizes = tuple(
            (int(s[0]) + 7, max(1, int(s[1]) - 4), int(s[2]) + 3)
            for s in scene.sizes_mm[list(scene.shown)]
        )
        heightmap = np.where(scene.heightmap > 0, scene.heightmap + 2, 0).astype(np.int32)
        self.seen.append(heightmap)
        return Perception(heightmap.copy(), sizes)  # type: ignore[arg-type]


def _case() -> Case:
    """7 objects (a layer of 3 and one of 4), buffer 3: future objects exist at every step."""
    return make_layered_case(2, cells=(8, 6), layer_heights_mm=(100, 60), buffer_size=3)


def _play(
    policy,
    case: Case,
    handed,
    perceiver=None,
    shown: list | None = None,
    observations: list | None = None,
    show_remaining: bool = True,
) -> list:
    """``run_episode``'s loop, handing ``handed`` to the policy in place of ``case``; the sizes
    the policy was shown go to ``shown``, the observations to ``observations``."""
    episode = Episode("geometric", perceiver=perceiver, show_remaining=show_remaining)
    observation = episode.reset(case, 1)
    policy.reset(handed, 1)
    actions = []
    while not episode.done:
        if shown is not None:
            shown.extend(item.size_mm for item in observation.shown)
        if observations is not None:
            observations.append(observation)
        action = policy.act(observation)
        actions.append(action)
        episode.step(action)
        if not episode.done:
            observation = episode.observe()
    return actions


@contextmanager
def _policy_maker(name: str) -> Iterator:
    """Yields ``make() -> policy`` for a bench policy, with whatever it needs running."""
    for module in EXTRAS.get(name, ()):
        if importlib.util.find_spec(module) is None:
            pytest.skip(f"policy {name!r} needs {module}, which is not installed")
    if name != "endpoint":
        yield lambda: make_policy(name, **OPTIONS.get(name, {}))
        return
    # The endpoint policy plays against a local OpenAI-compatible server (no network).
    from packlab.vlm.prompt.render import action_text
    from packlab.vlm.serve.server import scripted, serve

    with serve(scripted([], default=action_text(Action(0, 0, 0, 0)))) as server:
        yield lambda: make_policy("endpoint", base_url=server.base_url, timeout_s=30)


def _check_blind(name: str, perceiver=None) -> None:
    case, shown = _case(), []
    with _policy_maker(name) as make:
        honest = _play(make(), case, case, perceiver)
        blind = BlindCase(case)
        actions = _play(make(), case, blind, perceiver, shown)
    assert blind.forbidden_reads == [], f"{name} read case.{blind.forbidden_reads[0]}"
    assert actions == honest, f"{name} acts differently on what it is handed alone"
    if perceiver is not None:  # the true sizes never reached the policy
        assert shown and not {b.size_mm for b in case.objects} & set(shown)


def _ids(observation) -> list:
    return [s.internal_id for s in observation.shown]


def test_perceived_mode_hands_no_truth_but_sizes_and_heightmap_as_perceived():
    """What the episode hands in perceived mode: the perceived heightmap (now and in the
    history), fresh ids at every observation that name no box of the case, no catalogue type,
    and ``remaining`` only when the run shows it."""
    case = _case()
    for show_remaining in (True, False):
        perceiver, observations = OffGridPerceiver(), []
        _play(make_policy("dblf"), case, case, perceiver, None, observations, show_remaining)
        case_ids = {b.internal_id for b in case.objects}
        ids = [i for o in observations for i in _ids(o)]
        assert not case_ids & set(ids)
        assert len(set(ids)) == len(ids), "an id was shown at two observations"
        assert {s.type_id for o in observations for s in o.shown} == {0}
        assert len(perceiver.seen) == len(observations) + 1  # one more after the last step
        for k, o in enumerate(observations):
            np.testing.assert_array_equal(o.heightmap, perceiver.seen[k])
            for j, past in enumerate(o.history):
                np.testing.assert_array_equal(past.heightmap, perceiver.seen[j])
                assert _ids(observations[j]) == [s.internal_id for s in past.shown]
            assert o.remaining == (len(case.objects) - k if show_remaining else None)


@pytest.mark.parametrize("name", [n for n in BENCH_POLICIES if n not in PEEKS_BY_DESIGN])
def test_every_policy_plays_with_remaining_hidden(name):
    """``--remaining hidden``: every policy does without the count of boxes still to come."""
    case = _case()
    with _policy_maker(name) as make:
        actions = _play(make(), case, case, OffGridPerceiver(), show_remaining=False)
    assert len(actions) == len(case.objects)


@pytest.mark.parametrize("name", [n for n in BENCH_POLICIES if n not in PEEKS_BY_DESIGN])
def test_no_policy_reads_beyond_its_observation(name):
    _check_blind(name)


@pytest.mark.parametrize("name", [n for n in BENCH_POLICIES if n not in PEEKS_BY_DESIGN])
def test_no_policy_reads_true_sizes_in_perceived_mode(name):
    _check_blind(name, OffGridPerceiver())


def test_the_exceptions_are_registered_policies_that_do_peek():
    assert set(PEEKS_BY_DESIGN) <= set(BENCH_POLICIES), set(PEEKS_BY_DESIGN) - set(BENCH_POLICIES)
    case = _case()
    for name in PEEKS_BY_DESIGN:  # still needed: blind, each fails ...
        with pytest.raises(AssertionError, match=r"case\.gt_plan"):
            _play(make_policy(name), case, BlindCase(case))
    # ... and the oracle reads nothing beyond its plan and the catalogue sizes the plan's
    # rotations refer to (to turn a box the observation names the other way round).
    blind = BlindCase(case, also=("gt_plan", "objects"))
    assert _play(make_policy("oracle"), case, blind) == _play(make_policy("oracle"), case, case)
    assert blind.forbidden_reads == []


class _Peeker:
    """A policy that looks at the next arrival, hiding the failure if it can."""

    name = "peeker"

    def __init__(self, field: str) -> None:
        self.field = field

    def reset(self, case, seed: int) -> None:
        try:
            self.seen = getattr(case, self.field, None)
        except Exception:  # noqa: BLE001 - a policy hiding the failure on purpose
            self.seen = None

    def act(self, observation) -> Action:
        return Action(0, 0, 0, 0)


@pytest.mark.parametrize("field", ["objects", "gt_plan", "episode_id", "difficulty", "generator"])
def test_the_blind_case_catches_a_peek_even_when_it_is_swallowed(field):
    case = _case()
    blind = BlindCase(case)
    _play(_Peeker(field), case, blind)
    assert blind.forbidden_reads == [field]
    for name in ALLOWED:  # what may be read is the case's own value
        assert getattr(blind, name) == getattr(case, name)
