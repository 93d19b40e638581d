"""No policy is handed what a robot cell would not know.

The episode hands a policy's ``reset`` an :class:`EpisodeStart` (the container, the buffer
size, random streams of its own), never the case: not its boxes, plan, id or seed, from which
the case could be rebuilt. Only a policy that declares ``needs_case`` gets the case, and the
registered ones that do are :data:`PEEKS_BY_DESIGN`. Every policy declared under the
``packlab.policies`` entry-point group (listed at collection time, so a newly registered one is
covered without touching this file) plays exact, perceived (a deterministic fake perceiver that
shows sizes off the grid) and on the robot path (the depth perceiver under structured light and
noisy MuJoCo execution) through ``run_episode``, which is checked to hand it nothing else.
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

from packlab.core.errors import ConfigError
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Case
from packlab.policies import make_policy
from packlab.policies.registry import ENTRY_POINT_GROUP
from packlab.sim.episode import Episode, episode_start, policy_start, run_episode
from packlab.sim.replan import Perception, Scene

#: Every bench policy: the names declared under the entry-point group (run-time registrations
#: are test doubles, e.g. tests/bench's deliberately crashing policy, and are left out).
BENCH_POLICIES = sorted({ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)})

#: Policies that read what the episode does not hand a policy, on purpose, and why.
PEEKS_BY_DESIGN = {
    "oracle": "replays the case's gt_plan (the generator's perfect packing): the upper bound "
    "reported beside the policies, not a policy under test",
}

#: What an episode start holds: what every observation shows anyway, and random streams.
START_FIELDS = ("container", "buffer_size", "streams")

#: Options that make a policy cheap and self-contained here; the rest are built with none.
OPTIONS: dict[str, dict[str, Any]] = {
    "vlm": {"model": "tiny:qwen3_5:tiny", "max_new_tokens": 8},  # the generative path
}

#: Modules a policy needs beyond the core install (skipped where they are missing).
EXTRAS = {
    "vlm": ("torch", "transformers"),  # OPTIONS: a tiny generative model (the torch path)
}


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
    handed=None,
    perceiver=None,
    shown: list | None = None,
    observations: list | None = None,
    show_remaining: bool = True,
) -> list:
    """``run_episode``'s loop, handing the policy ``handed`` (default: what the episode hands it);
    the sizes the policy was shown go to ``shown``, the observations to ``observations``."""
    episode = Episode("geometric", perceiver=perceiver, show_remaining=show_remaining)
    observation = episode.reset(case, 1)
    policy.reset(policy_start(policy, case, 1) if handed is None else handed, 1)
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
        actions = _play(make(), case, None, OffGridPerceiver(), show_remaining=False)
    assert len(actions) == len(case.objects)


class _Spy:
    """Wraps a policy and keeps what its ``reset`` was handed."""

    def __init__(self, inner) -> None:
        self.inner, self.name, self.handed = inner, inner.name, []
        self.needs_case = getattr(inner, "needs_case", False)

    def reset(self, start, seed: int) -> None:
        self.handed.append(start)
        self.inner.reset(start, seed)

    def act(self, observation):
        return self.inner.act(observation)


def _robot_path():
    """The robot path's modes: the depth perceiver under structured light, noisy execution."""
    from packlab.sim.modes import episode_modes

    modes = episode_modes("perceived", "noisy", noise="structured-light")
    return {"perceiver": modes.perceiver, "execution": modes.execution}


@pytest.mark.parametrize("mode", ["exact", "perceived", "robot"])
@pytest.mark.parametrize("name", [n for n in BENCH_POLICIES if n not in PEEKS_BY_DESIGN])
def test_the_episode_hands_every_policy_its_start_only(name, mode):
    """Through ``run_episode`` (geometric exact, the off-grid perceiver, and the robot path on
    MuJoCo) each registered policy is handed an ``EpisodeStart`` holding nothing of the case
    but its container and buffer size, and plays the case to the end."""
    case = _case()
    kwargs: dict[str, Any] = {"backend": "geometric"}
    if mode == "perceived":
        kwargs["perceiver"] = OffGridPerceiver()
    elif mode == "robot":
        kwargs = {"backend": "mujoco", **_robot_path()}
    with _policy_maker(name) as make:
        spy = _Spy(make())
        result = run_episode(case, spy, seed=1, **kwargs)
    assert not spy.needs_case, f"{name} asks for the case"
    [start] = spy.handed
    assert type(start) is EpisodeStart
    assert (start.container, start.buffer_size) == (case.container, case.buffer_size)
    assert result.metrics is not None


def test_an_episode_start_holds_nothing_the_case_could_be_rebuilt_from():
    """No field of the start names the case (its fields are the container, the buffer size and
    a stream maker); a policy looking for the case's seed, id or boxes finds nothing; its
    streams are reproducible per case and run seed, and apart from the episode's own shuffle."""
    from dataclasses import fields

    from packlab.sim.buffer import episode_rng

    case = _case()
    start = episode_start(case, 1)
    assert tuple(f.name for f in fields(start)) == START_FIELDS
    for name in ("seed", "episode_id", "objects", "gt_plan", "difficulty", "generator", "origin"):
        assert not hasattr(start, name), name
    draws = start.rng(5).integers(1 << 30, size=4)
    assert (draws == episode_start(case, 1).rng(5).integers(1 << 30, size=4)).all()
    assert (draws != episode_start(case, 2).rng(5).integers(1 << 30, size=4)).any()
    assert (draws != episode_rng(case.seed, 1).integers(1 << 30, size=4)).any()
    with pytest.raises(ValueError, match="stream"):
        start.rng(0)  # the episode's own shuffle is not the policy's


class _Rebuilder:
    """A policy that tries to rebuild its case from any seed it is handed."""

    name = "rebuilder"

    def reset(self, start, seed: int) -> None:
        from packlab.datagen.generator import build_case

        self.rebuilt = build_case(start.seed, "easy")

    def act(self, observation) -> Action:
        return Action(0, 0, 0, 0)


def test_a_policy_that_rebuilds_its_case_from_a_seed_is_stopped():
    with pytest.raises(AttributeError, match="seed"):
        run_episode(_case(), _Rebuilder(), seed=0, backend="geometric")


def test_the_exceptions_are_registered_policies_that_do_peek():
    """The policies that ask for the case are the registered exceptions, and they need it:
    handed only the start, each fails."""
    assert set(PEEKS_BY_DESIGN) <= set(BENCH_POLICIES), set(PEEKS_BY_DESIGN) - set(BENCH_POLICIES)
    case = _case()
    for name in PEEKS_BY_DESIGN:
        policy = make_policy(name)
        assert policy.needs_case
        with pytest.raises(ConfigError, match="handed the case"):
            policy.reset(episode_start(case, 1), 1)
        assert len(_play(make_policy(name), case)) == len(case.objects)


@pytest.mark.parametrize(
    ("options", "needs"),
    [
        ({}, False),
        ({"prompt": "reference", "fallback": "invalid"}, False),
        ({"prompt": "reference"}, True),  # the reference seeds its forced set-aside by sample id
        ({"tag_requests": True}, True),
    ],
)
def test_the_endpoint_asks_for_the_case_only_where_an_option_reads_it(options, needs):
    assert make_policy("endpoint", **options).needs_case is needs
