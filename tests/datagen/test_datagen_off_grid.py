"""The off-grid carton family (``CaseConfig.sizes = "off-grid"``): the grid case's layout,
order and colours, each box a drawn clearance smaller than its slot, the plan checked on the
slots and replay-validated against the boxes' fill of them."""

from __future__ import annotations

import dataclasses

import pytest

from packlab.bench.suites import fresh_spec
from packlab.cases import load_cases, save_cases
from packlab.cli.main import main
from packlab.core.errors import ConfigError
from packlab.datagen.config import CaseConfig, ClearanceConfig, ValidationConfig
from packlab.datagen.generator import build_case, fill_slot, generate_cases
from packlab.datagen.validate import judge, plan_fill, plan_problems, replay

OFF = CaseConfig(sizes="off-grid")
GEOMETRIC = ValidationConfig(backend="geometric")
SEED = 2**51 + 4242  # a training-domain case seed


def _slot_sizes(case):
    c = case.container
    for p in case.gt_plan:
        box = case.box_by_id(p.internal_id)
        fx, fy = box.footprint_mm(p.rotation)
        slot = (p.cell_size[0] * c.cell_xy_mm, p.cell_size[1] * c.cell_xy_mm)
        yield (slot[0] - fx, slot[1] - fy, p.cell_size[2] * c.cell_z_mm - box.size_mm[2])


@pytest.mark.parametrize("difficulty", ["easy", "medium", "hard"])
@pytest.mark.parametrize("layout", ["layered", "stepped", "cut"])
def test_boxes_are_their_slots_less_a_clearance_in_range(difficulty, layout):
    order = "support" if layout == "cut" else "removal"
    grid = build_case(SEED, difficulty, CaseConfig(layout=layout, order=order))
    off = build_case(SEED, difficulty, CaseConfig(layout=layout, order=order, sizes="off-grid"))
    # The same layout, order and presentation: only the sizes differ.
    assert off.gt_plan == grid.gt_plan and off.container == grid.container
    assert [b.internal_id for b in off.objects] == [b.internal_id for b in grid.objects]
    assert [b.type_id for b in off.objects] == [b.type_id for b in grid.objects]
    offs = list(_slot_sizes(off))
    assert all(2 <= dx <= 12 and 2 <= dy <= 12 and 0 <= dz <= 4 for dx, dy, dz in offs), offs
    assert any(b.size_mm[0] % 25 for b in off.objects)
    assert off.generator["sizes"] == "off-grid" and "sizes" not in grid.generator
    assert off.generator["fill"] == round(plan_fill(off), 6) < 1.0 == plan_fill(grid)
    assert plan_problems(off) == [] == plan_problems(grid)
    assert build_case(SEED, difficulty, dataclasses.replace(OFF, layout=layout, order=order)) == off


def test_a_box_larger_than_its_slot_fails_the_plan_check():
    case = build_case(SEED, "easy", OFF)
    first = case.objects[0]
    bigger = dataclasses.replace(first, size_mm=(first.size_mm[0] + 20, *first.size_mm[1:]))
    broken = dataclasses.replace(case, objects=(bigger, *case.objects[1:]))
    assert any("disagree with size" in p for p in plan_problems(broken))


def test_replays_are_judged_against_the_fill_of_the_slots():
    case = build_case(SEED, "medium", OFF)
    trajectory = replay(case, "geometric")
    fill = plan_fill(case)
    assert fill <= trajectory.metrics.overall < 0.99
    assert judge(trajectory, 0.99) == ""  # 0.99 x the fill is the bar off the grid
    assert judge(trajectory, trajectory.metrics.overall / fill + 1e-6) == "overall_below_min"


def test_grid_configs_keep_their_bytes_and_bad_settings_are_refused():
    assert "sizes" not in CaseConfig().to_dict() and "clearance" not in CaseConfig().to_dict()
    assert OFF.to_dict()["sizes"] == "off-grid"
    assert OFF.to_dict()["clearance"] == {"xy_mm": (2, 12), "z_mm": (0, 4)}
    with pytest.raises(ConfigError, match="sizes = 'off-grid': layout 'random'"):
        CaseConfig(layout="random", sizes="off-grid")
    with pytest.raises(ConfigError, match="clearance.xy_mm"):
        CaseConfig(sizes="off-grid", clearance=ClearanceConfig(xy_mm=(2, 25)))
    with pytest.raises(ConfigError, match="clearance.z_mm = \\(5, 1\\)"):
        ClearanceConfig(z_mm=(5, 1))
    with pytest.raises(ConfigError, match="sizes = 'tiny'"):
        CaseConfig(sizes="tiny")  # type: ignore[arg-type]


def test_off_grid_cases_are_replay_validated_and_survive_a_file(tmp_path):
    cases = generate_cases("easy", 3, 4911, True, config=OFF, validation=GEOMETRIC, domain="train")
    for case in cases:
        outcome = fill_slot(
            4911, "train", "easy", int(case.episode_id[-5:]), OFF, GEOMETRIC, "train-s4911-"
        )
        assert outcome.case == case and outcome.trajectory is not None
    path = tmp_path / "off.jsonl"
    save_cases(cases, path)
    assert load_cases(path) == cases


def test_the_fresh_command_makes_an_off_grid_set(tmp_path, capsys):
    """``packlab cases fresh SUITE --sizes off-grid``: the suite's recipe with off-grid sizes,
    the same cases as the data engine's, replay-validated (here on the geometric backend)."""
    spec = fresh_spec("packlab-bench-v1", 4911, per_level=1, sizes="off-grid")
    assert spec.name.endswith("-off-grid") and spec.case_config.sizes == "off-grid"
    out = tmp_path / "fresh.jsonl"
    args = ["cases", "fresh", "packlab-bench-v1", "--seed", "4911", "--out", str(out)]
    assert (
        main([*args, "--per-level", "1", "--validation", "geometric", "--sizes", "off-grid"]) == 0
    )
    assert "boxes off the grid" in capsys.readouterr().out
    cases = load_cases(out)
    expected = [
        c
        for level in ("easy", "medium", "hard")
        for c in generate_cases(
            level, 1, 4911, True, config=OFF, validation=GEOMETRIC, domain="train"
        )
    ]
    assert cases == expected
    assert all(c.generator["sizes"] == "off-grid" for c in cases)
