"""The ``cut`` layout family: Zhao et al.'s CUT recipe on the stack cuboid, its two
arrival orders (base-height = CUT-1, support = CUT-2), and the config's refusals."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from packlab.cli.generate import config_from_args
from packlab.cli.main import build_parser
from packlab.core.errors import ConfigError
from packlab.datagen import DIFFICULTIES, CaseConfig, DatasetConfig, build_case, generate_cases
from packlab.datagen.config import ObjectLimits
from packlab.datagen.cut_family import cut_cuboid, expected_count, side_range
from packlab.datagen.generator import draw_blueprint
from packlab.datagen.layout import partition_problems
from packlab.datagen.removal import order_problems
from packlab.datagen.scenario import sample_scenario
from packlab.datagen.seeds import case_seed, case_streams
from packlab.datagen.validate import plan_problems

ORDERS = ("removal", "base-height", "support")


def _seeds(difficulty, n, user_seed=35):
    return [case_seed(user_seed, "train", difficulty, slot) for slot in range(n)]


def _blueprints(difficulty, order="support", n=30, user_seed=35):
    cfg = CaseConfig(layout="cut", order=order)
    for seed in _seeds(difficulty, n, user_seed):
        yield draw_blueprint(seed, difficulty, cfg)


@pytest.mark.parametrize("difficulty", list(DIFFICULTIES))
def test_cut_layouts_are_exact_partitions_within_the_shape_rules(difficulty):
    lim = ObjectLimits()
    for bp in _blueprints(difficulty, n=60):
        layout = bp.layout
        c = bp.scenario.container
        assert layout.family == "cut"
        assert layout.cells == c.cells
        assert layout.height * c.cell_z_mm == bp.scenario.stack_height_mm
        assert partition_problems(layout) == []  # disjoint, inside, volume = cuboid
        sides = bp.cut.sides
        bases = sorted({b.z for b in layout.boxes})
        for b in layout.boxes:
            fx, fy, h = b.dx * c.cell_xy_mm, b.dy * c.cell_xy_mm, b.dz * c.cell_z_mm
            assert min(fx, fy, h) >= lim.min_side_mm  # height too
            assert max(fx, fy) <= lim.max_aspect * min(fx, fy)
            assert h % lim.height_step_mm == 0 and b.z * c.cell_z_mm % lim.height_step_mm == 0
            assert h <= lim.layer_height_mm[1]
            for a, side in enumerate((b.dx, b.dy, b.dz)):
                assert sides.lo[a] <= side <= sides.hi[a]
            assert b.layer_index == bases.index(b.z)  # index of the base height
        # Heights are at most half the stack: every column is cut, heights are mixed.
        assert sides.hi[2] * c.cell_z_mm <= max(bp.scenario.stack_height_mm / 2, 150)
        assert len(bases) >= 2


@pytest.mark.parametrize("difficulty", list(DIFFICULTIES))
def test_cut_object_counts_land_in_the_difficulty_range(difficulty):
    lo, hi = DIFFICULTIES[difficulty].n_objects
    counts = [len(bp.layout.boxes) for bp in _blueprints(difficulty, n=60, user_seed=3)]
    inside = sum(lo <= n <= hi for n in counts)
    assert inside >= 0.95 * len(counts), Counter(counts)
    assert min(counts) >= lo - 2 and max(counts) <= hi + 4  # a fallback stays near the range
    assert len(set(counts)) >= 3  # the count varies over the range


def test_expected_count_matches_the_sampled_mean():
    cfg = CaseConfig(layout="cut")
    spec = DIFFICULTIES["medium"]
    scenario = sample_scenario(spec, cfg, case_streams(11, 4)[0])
    c = scenario.container
    size = (*c.cells, scenario.stack_height_mm // c.cell_z_mm)
    sides = side_range(scenario, cfg, 12)
    rng = np.random.default_rng(0)
    sampled = np.mean([len(cut_cuboid(size, sides, 1e9, rng)) for _ in range(400)])
    assert sampled == pytest.approx(expected_count(size, sides), rel=0.06)


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("difficulty", list(DIFFICULTIES))
def test_every_cut_order_places_each_box_flat_on_what_is_below(order, difficulty):
    cfg = CaseConfig(layout="cut", order=order)
    for seed in _seeds(difficulty, 20):
        bp = draw_blueprint(seed, difficulty, cfg)
        assert bp.order.rule == order
        # Every box rests exactly on the floor or on tops at its base when placed.
        assert order_problems(bp.layout, bp.order.order) == []
        case = build_case(seed, difficulty, cfg)
        assert case.gt_plan is not None and plan_problems(case) == []
        assert [p.internal_id for p in case.gt_plan] == list(bp.order.order)


def test_base_height_order_sorts_by_base_and_shuffles_within_one():
    shuffled = 0
    for bp in _blueprints("hard", "base-height", n=20):
        zs = [bp.layout.boxes[i].z for i in bp.order.order]
        assert zs == sorted(zs)
        floor = [i for i in bp.order.order if bp.layout.boxes[i].z == 0]
        shuffled += floor != sorted(floor)
        assert bp.order.anchor == "none"
    assert shuffled >= 15


def test_support_order_leaves_base_height_order():
    """CUT-2 lets a box arrive before a lower-based box elsewhere: not sorted by base."""
    unsorted = 0
    for bp in _blueprints("hard", "support", n=20):
        zs = [bp.layout.boxes[i].z for i in bp.order.order]
        unsorted += zs != sorted(zs)
    assert unsorted >= 10


def test_support_order_draws_uniformly_among_available_boxes():
    """First box: each floor box is available at the start, so over many order streams every
    floor box of one layout comes first at some point."""
    from packlab.datagen.cut_order import support_order

    bp = next(_blueprints("medium", "support", n=1))
    floor = {i for i, b in enumerate(bp.layout.boxes) if b.z == 0}
    firsts = {support_order(bp.layout, np.random.default_rng(k)).order[0] for k in range(400)}
    assert firsts == floor


@pytest.mark.parametrize("order", ORDERS)
def test_cut_cases_are_deterministic_per_seed(order):
    cfg = CaseConfig(layout="cut", order=order)
    seed = case_seed(2, "train", "hard", 4)
    assert build_case(seed, "hard", cfg) == build_case(seed, "hard", cfg)
    other = build_case(case_seed(2, "train", "hard", 5), "hard", cfg)
    assert other.objects != build_case(seed, "hard", cfg).objects


def test_cut_orders_change_only_the_order_stream():
    seed = case_seed(9, "train", "medium", 0)
    bps = [draw_blueprint(seed, "medium", CaseConfig(layout="cut", order=o)) for o in ORDERS]
    assert all(bp.layout == bps[0].layout and bp.rotated == bps[0].rotated for bp in bps)


def test_cut_case_records_its_family_and_presents_rotations():
    cfg = CaseConfig(layout="cut", order="support")
    rotated = 0
    for slot in range(10):
        case = build_case(case_seed(1, "train", "medium", slot), "medium", cfg)
        g = case.generator
        assert g["layout"] == "cut" and g["order"] == "support" and g["anchor"] == "none"
        assert "n_layers" not in g and "layer_heights_cm" not in g
        assert g["n_bases"] == len({p.cell_min[2] for p in case.gt_plan})
        assert len(g["side_max_cm"]) == 3 and g["side_min_cm"] == [7.5, 7.5, 8]
        rotated += sum(p.rotation for p in case.gt_plan)
        for box, p in zip(case.objects, case.gt_plan):
            fx, fy = box.footprint_mm(p.rotation)
            assert (fx // 25, fy // 25) == p.cell_size[:2]
    assert rotated > 0
    removal = build_case(case_seed(1, "train", "easy", 0), "easy", CaseConfig(layout="cut"))
    assert "order" not in removal.generator and removal.generator["anchor"] != "none"


def test_generate_cases_makes_cut_cases_validated_on_the_geometric_backend():
    from packlab.datagen.config import ValidationConfig

    cases = generate_cases(
        "easy",
        3,
        seed=4,
        config=CaseConfig(layout="cut", order="base-height"),
        validation=ValidationConfig(backend="geometric"),
        domain="train",
    )
    assert [c.generator["layout"] for c in cases] == ["cut"] * 3
    assert all(plan_problems(c) == [] for c in cases)


@pytest.mark.parametrize(
    ("fields", "words"),
    [
        ({"layout": "layered", "order": "support"}, ["order = 'support'", "layered"]),
        ({"layout": "stepped", "order": "base-height"}, ["order = 'base-height'", "stepped"]),
        ({"layout": "random", "order": "support"}, ["order = 'support'", "random"]),
        ({"layout": "cut", "order": "layers"}, ["order = 'layers'", "base-height"]),
        ({"layout": "cut", "order": "heights"}, ["order = 'heights'", "base-height"]),
    ],
)
def test_config_refuses_orders_that_do_not_suit_the_family(fields, words):
    with pytest.raises(ConfigError) as err:
        CaseConfig(**fields)
    assert all(w in str(err.value) for w in words)
    assert "\n" not in str(err.value)


def test_cut_orders_are_kept_in_saved_configs_and_removal_stays_absent():
    assert "order" not in CaseConfig(layout="cut").to_dict()
    assert CaseConfig(layout="cut", order="support").to_dict()["order"] == "support"


def test_cli_takes_the_cut_layout_and_its_orders(tmp_path):
    args = build_parser().parse_args(
        [
            "generate",
            "--difficulty",
            "easy",
            "--episodes",
            "1",
            "--out",
            str(tmp_path / "d"),
            "--layout",
            "cut",
            "--order",
            "support",
        ]
    )
    cfg = config_from_args(args)
    assert isinstance(cfg, DatasetConfig)
    assert cfg.case.layout == "cut" and cfg.case.order == "support"
