"""The ``rs`` layout family: i.i.d. boxes from Zhao et al.'s 64 types (sides 2..5
units, unit = a tenth of the smaller floor side on the grid), drawn until the container's volume
is reached; no ``gt_plan``, no replay validation, refused by the oracle."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from packlab.core.errors import ConfigError
from packlab.core.types import Container
from packlab.datagen import DIFFICULTIES, CaseConfig, DatasetConfig, build_case, generate_cases
from packlab.datagen.config import ObjectLimits
from packlab.datagen.generator import draw_blueprint, fill_slot
from packlab.datagen.rs_family import MAX_BOXES, TYPES, draw_rs_boxes, unit_mm
from packlab.datagen.seeds import case_seed
from packlab.policies import make_policy
from packlab.sim.episode import run_episode

RS = CaseConfig(layout="rs")


def _cases(difficulty, n=15, user_seed=6):
    return [
        build_case(case_seed(user_seed, "train", difficulty, slot), difficulty, RS)
        for slot in range(n)
    ]


def test_the_type_set_is_the_64_triples_of_2_to_5():
    assert len(TYPES) == 64 == len(set(TYPES))
    assert {v for t in TYPES for v in t} == {2, 3, 4, 5}


@pytest.mark.parametrize(
    ("floor_mm", "unit"),
    [((500, 500), 50), ((600, 525), 50), ((625, 700), 75), ((1000, 925), 100), ((1400, 1325), 125)],
)
def test_the_unit_is_a_tenth_of_the_smaller_floor_side_on_the_grid(floor_mm, unit):
    assert unit_mm(Container((*floor_mm, 500))) == unit


def test_a_50_cm_cube_gives_sides_of_10_to_25_cm_and_stops_at_its_volume():
    c = Container((500, 500, 500))
    draw = draw_rs_boxes(c, 10, np.random.default_rng(0))
    assert draw.unit_mm == 50
    assert {v for s in draw.sizes_mm for v in s} <= {100, 150, 200, 250}
    volumes = [l * w * h for l, w, h in draw.sizes_mm]
    # Drawn until the volume reaches the container's: the last box reaches it, no earlier one.
    assert sum(volumes) >= c.volume_mm3 > sum(volumes[:-1])
    assert [TYPES[k] for k in draw.type_index] == [
        (l // 50, w // 50, h // 50) for l, w, h in draw.sizes_mm
    ]


def test_types_are_drawn_uniformly():
    counts = Counter()
    rng = np.random.default_rng(1)
    for _ in range(60):
        counts.update(draw_rs_boxes(Container((500, 500, 500)), 10, rng).type_index)
    n = sum(counts.values())
    assert len(counts) == 64
    assert max(counts.values()) < 3 * n / 64  # no type far above its share


@pytest.mark.parametrize("difficulty", list(DIFFICULTIES))
def test_rs_cases_obey_the_size_rules_and_exceed_the_container_volume(difficulty):
    lim = ObjectLimits()
    spec = DIFFICULTIES[difficulty]
    for case in _cases(difficulty):
        c = case.container
        g = case.generator
        unit = round(g["unit_cm"] * 10)
        assert case.gt_plan is None and case.buffer_size == spec.buffer_size
        assert g["layout"] == "rs" and g["order"] == "draw" and len(g["types"]) == len(case.objects)
        assert [b.internal_id for b in case.objects] == list(range(len(case.objects)))
        for b, (a, bb, cc) in zip(case.objects, g["types"]):
            l, w, h = b.size_mm
            assert (l, w) == (a * unit, bb * unit)
            assert abs(h - cc * unit) <= 5 and h % lim.height_step_mm == 0
            assert min(l, w, h) >= lim.min_side_mm and max(l, w) <= lim.max_aspect * min(l, w)
            assert l % c.cell_xy_mm == 0 and w % c.cell_xy_mm == 0
            assert max(l, w) <= min(c.size_mm[:2]) and h <= c.size_mm[2]  # every box fits alone
        assert case.total_volume_mm3 >= c.volume_mm3 and len(case.objects) < MAX_BOXES
        assert g["drawn_fill"] == pytest.approx(case.total_volume_mm3 / c.volume_mm3, abs=1e-6)


def test_rs_cases_are_deterministic_and_differ_between_seeds():
    seed = case_seed(3, "train", "medium", 0)
    assert build_case(seed, "medium", RS) == build_case(seed, "medium", RS)
    assert build_case(seed + 1, "medium", RS).objects != build_case(seed, "medium", RS).objects


def test_rs_cases_take_attempt_zero_without_validation_and_refuse_the_oracle():
    from packlab.datagen.config import ValidationConfig

    out = fill_slot(1, "train", "easy", 0, RS, ValidationConfig(), "t-")
    assert out.case is not None and out.trajectory is None and out.rejected == ()
    assert out.case.generator["attempt"] == 0
    cases = generate_cases("hard", 2, seed=2, config=RS, domain="train")
    assert [c.generator["layout"] for c in cases] == ["rs", "rs"]
    with pytest.raises(ConfigError, match="gt_plan"):
        run_episode(cases[0], make_policy("oracle"), 0, backend="geometric")
    result = run_episode(cases[0], make_policy("dblf"), 0, backend="geometric")
    assert len(result.steps) == len(cases[0].objects)


def test_rs_config_errors_name_the_field():
    with pytest.raises(ConfigError, match="order = 'layers'.*rs"):
        CaseConfig(layout="rs", order="layers")
    with pytest.raises(ConfigError, match="order = 'support'"):
        CaseConfig(layout="rs", order="support")
    with pytest.raises(ConfigError, match="teacher = 'oracle'.*rs layout"):
        DatasetConfig(difficulties=("easy",), episodes=(1,), case=RS)
    with pytest.raises(ConfigError, match="no blueprint"):
        draw_blueprint(5, "easy", RS)
