"""Fixtures shared by the vlm tests: one fixed packing state used by the golden prompt tests, and
for the candidate-mode model tests torch on one thread for a module and the sdf-labelled states
of one generated medium case."""

from __future__ import annotations

import pytest

from packlab.core.types import Action, Container, ShownItem, Unparsable
from packlab.vlm.prompt.render import TurnState


def _item(i: int, internal_id: int, lc: int, wc: int, hc: int) -> ShownItem:
    # sizes in cells: 25 mm per xy cell, 2 mm per z cell
    return ShownItem(i, internal_id, (lc * 25, wc * 25, hc * 2), (lc, wc, hc))


@pytest.fixture
def torch():
    """torch, for the tests of tiny models (skipped without the vlm extra), on one thread."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("transformers")
    torch.set_num_threads(1)  # tiny models; avoids thread oversubscription on shared CPUs
    return torch


@pytest.fixture
def fixed_state():
    """(container, past, current) for a 3-step-old episode in a 10 x 8 cell container."""
    container = Container((250, 200, 200))
    s0 = TurnState("images/ep0/step0.png", (_item(0, 3, 4, 3, 20), _item(1, 0, 2, 2, 10)), 0, 5)
    s1 = TurnState("images/ep0/step1.png", (_item(0, 0, 2, 2, 10), _item(1, 4, 6, 2, 30)), 1, 4)
    s2 = TurnState("images/ep0/step2.png", (_item(0, 4, 6, 2, 30), _item(1, 1, 3, 3, 16)), 2, 3)
    past = [
        (s0, Action(object_id=0, rotation=0, x=0, y=0)),
        (s1, Unparsable(text="I would place it left", error="no JSON object found")),
    ]
    return container, past, s2


#: The proposer the candidate-mode tests' states are listed with (the tests that propose again
#: use the same settings).
CANDIDATE_PROPOSER = {"k": 8, "rule": "lowest"}


@pytest.fixture(scope="module")
def one_torch_thread():
    """torch on one thread for the module (tiny models), restored after."""
    torch = pytest.importorskip("torch")
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def cases():
    """One generated medium case of the training domain."""
    from packlab.datagen.generator import generate_cases

    return generate_cases("medium", 1, 11, validate=False, domain="train")


@pytest.fixture(scope="module")
def states(cases):
    """The labelled states (more than two placements listed) of ``cases[0]`` played by the
    sdf teacher through the candidate proposer."""
    from packlab.policies.candidates import ProposerConfig
    from packlab.policies.listed import ListedTeacher
    from packlab.sim.episode import run_episode
    from packlab.vlm.candidate.collect import Labeller

    labeller = Labeller(ListedTeacher("sdf"), ProposerConfig(**CANDIDATE_PROPOSER), "teacher")
    run_episode(cases[0], labeller, seed=0, backend="geometric")
    return [s for s in labeller.states if s.label >= 0 and len(s.listed) > 2]
