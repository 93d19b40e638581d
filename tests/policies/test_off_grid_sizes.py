"""Boxes whose sides are not multiples of the 25 mm cell: a footprint covers every cell it
touches (rounded up) in the shown items, the episode's checks, the heightmap update and every
registered policy, which plays an off-grid generated case to its end on the geometric backend."""

from __future__ import annotations

import pytest
from test_no_peeking import BENCH_POLICIES, PEEKS_BY_DESIGN, _policy_maker

from packlab.core.types import Action, Box, Case, Container
from packlab.datagen.config import CaseConfig
from packlab.datagen.generator import build_case
from packlab.sim.buffer import MEASURED_SIDE_SLACK_MM, size_cells
from packlab.sim.episode import Episode, run_episode

#: Policies whose actions are a model's free text: here a tiny random-weight model
#: (``vlm``) or a scripted server answer (``endpoint``) that need not name a usable placement.
TEXT_ANSWERS = {"vlm", "endpoint"}

#: An off-grid case per level (train seed domain, a fixed case seed each).
OFF_GRID = CaseConfig(sizes="off-grid")


def _case_of(difficulty: str, seed: int = 2**51 + 17) -> Case:
    return build_case(seed, difficulty, OFF_GRID)


def test_a_260_by_140_by_97_box_covers_11_by_6_cells():
    container = Container(size_mm=(500, 500, 400))
    assert size_cells((260, 140, 97), container) == (11, 6, 49)
    # A measured side up to the slack over a cell multiple takes that multiple; heights none.
    assert size_cells((253, 128, 97), container, MEASURED_SIDE_SLACK_MM) == (10, 5, 49)
    assert size_cells((254, 129, 97), container, MEASURED_SIDE_SLACK_MM) == (11, 6, 49)
    assert size_cells((250, 125, 96), container, MEASURED_SIDE_SLACK_MM) == (10, 5, 48)
    # The episode's shown item, the geometric heightmap and the next drop agree.
    case = Case(
        episode_id="one-off-grid",
        container=container,
        buffer_size=1,
        objects=(Box(0, (260, 140, 97)), Box(1, (75, 75, 50))),
        seed=0,
        difficulty="easy",
    )
    episode = Episode("geometric")
    observation = episode.reset(case, 0)
    [item] = [s for s in observation.shown if s.size_mm == (260, 140, 97)]
    assert item.size_cells[:2] == (11, 6)
    step = episode.step(Action(object_id=item.shown_index, rotation=0, x=0, y=0))
    assert step.valid
    hm = episode.observe().heightmap
    assert (hm[:11, :6] == 97).all() and (hm[11:, :] == 0).all() and (hm[:, 6:] == 0).all()
    # Turned, it covers 6 x 11 cells; at x = 10 its 11 cells would end past the 20-cell floor.
    case2 = Case(
        episode_id="turned",
        container=container,
        buffer_size=1,
        objects=(Box(0, (260, 140, 97)),),
        seed=0,
        difficulty="easy",
    )
    episode = Episode("geometric")
    episode.reset(case2, 0)
    step = episode.step(Action(object_id=0, rotation=1, x=0, y=10))
    assert not step.valid and step.reason == "out_of_bounds"
    episode = Episode("geometric")
    episode.reset(case2, 0)
    assert episode.step(Action(object_id=0, rotation=1, x=14, y=9)).valid
    hm = episode.observe().heightmap
    assert (hm[14:20, 9:20] == 97).all() and int((hm > 0).sum()) == 6 * 11


def test_the_off_grid_case_is_off_the_grid():
    case = _case_of("medium")
    assert any(b.size_mm[0] % 25 or b.size_mm[1] % 25 for b in case.objects)
    assert any(b.size_mm[2] % 2 for b in case.objects)


@pytest.mark.parametrize("name", [n for n in BENCH_POLICIES if n not in PEEKS_BY_DESIGN])
def test_every_policy_plays_an_off_grid_case_to_the_end(name):
    """Each registered policy (the oracle apart: it replays a plan, checked in the datagen
    tests) packs an off-grid medium case on the geometric backend: no error, every box
    processed, nothing invalid but deliberate set-asides."""
    case = _case_of("medium")
    with _policy_maker(name) as make:
        result = run_episode(case, make(), seed=0, backend="geometric")
    assert len(result.steps) == len(case.objects)
    reasons = {s.reason for s in result.steps if not s.valid}
    if name not in TEXT_ANSWERS:  # a candidate-choosing policy never picks an unusable one
        assert reasons <= {"set_aside"}, reasons
    assert result.metrics is not None and 0.0 <= result.metrics.overall <= 1.0
    if name not in TEXT_ANSWERS:
        assert result.metrics.overall > 0.0
