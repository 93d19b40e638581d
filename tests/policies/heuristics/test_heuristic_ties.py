"""The tie-break option of every heuristic: larger volume first (default) or the shown order."""

from __future__ import annotations

import heuristics_reference as ref
import numpy as np
import pytest
from heuristics_strategies import EQUAL_VOLUME_SHAPES, LEVEL_HEIGHTS_MM, packing_states
from hypothesis import given, settings
from hypothesis import strategies as st

from packlab.core.errors import ConfigError
from packlab.core.feasibility import id_order, search_candidates
from packlab.core.types import Action, Box, Case, Container, Observation, ShownItem
from packlab.policies import make_policy
from packlab.policies.heuristics import DEFAULT_TIE_BREAK, SCORERS, TIE_BREAKS, HeuristicPolicy
from packlab.policies.heuristics.select import choose, object_rank
from packlab.sim.episode import run_episode

NAMES = tuple(SCORERS)


def _observation(shown: list[ShownItem], hm: np.ndarray, rim_mm: int = 200) -> Observation:
    nx, ny = hm.shape
    return Observation(0, Container((nx * 25, ny * 25, rim_mm)), hm.astype(np.int32), tuple(shown))


def _tied_pair() -> list[ShownItem]:
    """Two 1 x 1 boxes, the smaller shown first. On a 1 x 1 floor there is one cell, both rest
    at z = 0 and fit under the 200 mm rim: DBLF's (z, x, y) and FFP's (no keys) tie."""
    return [ref.shown_item(0, 1, 1, 20), ref.shown_item(1, 1, 1, 40)]


def _equal_volume_pair() -> list[ShownItem]:
    """25 x 25 x 80 shown before 50 x 25 x 40: one volume, different shapes. On a 2 x 1 floor
    both rest at (0, 0, z = 0) and raise the heightmap's sum by their volume alike, so DBLF's
    and HM's keys tie too; the larger footprint is the rule's next key."""
    return [ref.shown_item(0, 1, 1, 80), ref.shown_item(1, 2, 1, 40)]


def test_the_default_is_the_literatures_rule() -> None:
    assert DEFAULT_TIE_BREAK == "larger_volume"
    assert TIE_BREAKS == ("larger_volume", "shown_order")
    assert all(make_policy(name).tie_break == "larger_volume" for name in NAMES)


def test_dblf_keys_tie_and_the_rule_decides() -> None:
    shown = _tied_pair()
    c = search_candidates(np.zeros((1, 1), dtype=np.int32), shown, 200)
    keys = SCORERS["dblf"](c)
    assert all(np.unique(np.asarray(k)).size == 1 for k in keys)  # a tie on every key
    assert c.obj[choose(c, keys)] == 1
    assert c.obj[choose(c, keys, "shown_order")] == 0


@pytest.mark.parametrize("name", ["dblf", "ffp"])
def test_tie_on_every_key_goes_to_the_larger_object_by_default(name: str) -> None:
    obs = _observation(_tied_pair(), np.zeros((1, 1)))
    assert make_policy(name).act(obs) == Action(1, 0, 0, 0)
    assert make_policy(name, tie_break="larger_volume").act(obs) == Action(1, 0, 0, 0)


@pytest.mark.parametrize("name", ["dblf", "ffp"])
def test_shown_order_takes_the_first_shown(name: str) -> None:
    obs = _observation(_tied_pair(), np.zeros((1, 1)))
    assert make_policy(name, tie_break="shown_order").act(obs) == Action(0, 0, 0, 0)


def test_equal_volumes_go_to_the_larger_footprint_then_longer_side() -> None:
    # One volume (100,000 mm^3), four shapes: the largest footprint first; the two 1,250 mm^2
    # footprints by l, larger first. Every shape differs, so the shown order never decides.
    sizes = np.array([[25, 25, 160], [50, 25, 80], [25, 50, 80], [50, 50, 40]])
    assert object_rank(sizes, np.array([0, 1, 2, 3])).tolist() == [3, 1, 2, 0]
    assert object_rank(sizes, np.array([3, 2, 1, 0])).tolist() == [3, 1, 2, 0]  # ids unused


def test_identical_boxes_go_by_id() -> None:
    sizes = np.array([[50, 25, 40], [25, 25, 40], [50, 25, 40]])
    assert object_rank(sizes, np.array([1, 2, 0])).tolist() == [1, 2, 0]


def test_id_order_sorts_reference_string_ids_and_never_mixes_types() -> None:
    def items(ids):
        return [ShownItem(i, iid, (25, 25, 20), (1, 1, 10)) for i, iid in enumerate(ids)]

    assert id_order(items(["obj_00010", "obj_00002", "obj_00009"])).tolist() == [2, 0, 1]
    assert id_order(items([10, 2, 9])).tolist() == [2, 0, 1]
    assert id_order(items(["a", 5, 1])).tolist() == [2, 1, 0]  # ints before strings


@pytest.mark.parametrize("name", ["dblf", "hm", "ffp"])
def test_equal_volumes_tie_on_the_keys_and_go_to_the_larger_footprint(name: str) -> None:
    shown = _equal_volume_pair()
    c = search_candidates(np.zeros((2, 1), dtype=np.int32), shown, 200)
    at_origin = np.flatnonzero((c.x == 0) & (c.y == 0))  # both rotations of the square one
    assert set(c.obj[at_origin].tolist()) == {0, 1}
    for key in SCORERS[name](c):
        assert np.unique(np.asarray(key)[at_origin]).size == 1
    obs = _observation(shown, np.zeros((2, 1)))
    assert make_policy(name).act(obs) == Action(1, 0, 0, 0)
    assert make_policy(name, tie_break="shown_order").act(obs) == Action(0, 0, 0, 0)


def _permute(shown: list[ShownItem], order: list[int]) -> list[ShownItem]:
    return [
        ShownItem(i, shown[j].internal_id, shown[j].size_mm, shown[j].size_cells)
        for i, j in enumerate(order)
    ]


def _chosen(obs: Observation, name: str, tie_break: str) -> tuple:
    """The choice independent of shown indices: the chosen box's id and its placement."""
    a = make_policy(name, tie_break=tie_break).act(obs)
    return (obs.shown[a.object_id].internal_id, a.rotation, a.x, a.y)


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=30, deadline=None)
@given(
    state=packing_states(
        max_cells=5, max_items=4, shapes=EQUAL_VOLUME_SHAPES, heights=LEVEL_HEIGHTS_MM
    ),
    data=st.data(),
)
def test_default_choice_does_not_depend_on_the_shown_order(name: str, state, data) -> None:
    hm, shown, rim = state
    if not shown:
        return
    order = data.draw(st.permutations(range(len(shown))))
    before = _chosen(_observation(shown, hm, rim), name, "larger_volume")
    after = _chosen(_observation(_permute(shown, order), hm, rim), name, "larger_volume")
    assert before == after


def test_shown_order_does_depend_on_the_shown_order() -> None:
    # The counterpart of the property above: the same tie, reversed, changes shown_order's box.
    obs = _observation(_tied_pair(), np.zeros((1, 1)))
    flipped = _observation(_permute(_tied_pair(), [1, 0]), np.zeros((1, 1)))
    assert _chosen(obs, "dblf", "shown_order") != _chosen(flipped, "dblf", "shown_order")
    assert _chosen(obs, "dblf", "larger_volume") == _chosen(flipped, "dblf", "larger_volume")


def _equal_volume_case() -> Case:
    """Eight boxes, four shapes of one volume each twice (identical pairs meet in the buffer),
    buffer 4, on a 6 x 4 floor: the heuristics' keys often tie between objects. String ids in
    the reference's style, numbered against the arrival order."""
    sizes = [(50, 25, 40), (25, 50, 40), (25, 25, 80), (50, 50, 20)] * 2
    boxes = tuple(
        Box(internal_id=f"obj_{7 - i:05d}", size_mm=s, gt_index=i) for i, s in enumerate(sizes)
    )
    return Case("equal-volumes", Container((150, 100, 300)), 4, boxes, seed=3)


def _trajectory(case: Case, name: str, tie_break: str, seed: int, backend="geometric") -> tuple:
    policy = make_policy(name, tie_break=tie_break)
    result = run_episode(case, policy, seed=seed, backend=backend)
    ids = tuple(s.internal_id for s in result.steps)
    return ids, tuple(s.drop_mm for s in result.steps), result.metrics.overall


@pytest.mark.parametrize("name", NAMES)
def test_whole_episodes_are_the_same_for_every_run_seed_by_default(name: str) -> None:
    # The run seed only reshuffles the shown order, which the default rule never reads.
    case = _equal_volume_case()
    runs = {_trajectory(case, name, "larger_volume", seed) for seed in range(4)}
    assert len(runs) == 1


@pytest.mark.physics
def test_mujoco_episodes_are_the_same_for_every_run_seed_by_default() -> None:
    # Identical boxes go by id, so even the physics engine moves the same bodies every time
    # (its contact solver is not indifferent to which of two identical bodies it moves).
    case = _equal_volume_case()
    runs = {_trajectory(case, "ffp", "larger_volume", seed, "mujoco") for seed in range(3)}
    assert len(runs) == 1


def test_with_shown_order_the_run_seed_changes_dblf_episodes() -> None:
    case = _equal_volume_case()
    assert len({_trajectory(case, "dblf", "shown_order", seed) for seed in range(4)}) > 1


@pytest.mark.parametrize("value", ["largest", "", 1, None])
def test_a_bad_value_is_a_config_error_naming_value_and_choices(value) -> None:
    with pytest.raises(ConfigError) as err:
        make_policy("dblf", tie_break=value)
    message = str(err.value)
    assert repr(value) in message and "larger_volume, shown_order" in message
    assert "dblf:tie_break" in message


def test_an_unknown_option_is_a_config_error_naming_the_known_ones() -> None:
    with pytest.raises(ConfigError, match=r"policy-arg hm:tie: unknown option .* known: tie_break"):
        make_policy("hm", tie="shown_order")


def test_the_dataclass_checks_the_value_too() -> None:
    with pytest.raises(ConfigError, match="'bigger'"):
        HeuristicPolicy("mta", SCORERS["mta"], "bigger")  # type: ignore[arg-type]


@pytest.mark.parametrize("name", NAMES)
def test_when_nothing_fits_the_set_aside_object_follows_the_rule(name: str) -> None:
    # Neither 2-cell box fits a 1 x 1 floor: the fallback names an object to set aside, and
    # under the default that is the larger one wherever it is shown.
    shown = [ref.shown_item(0, 2, 1, 20), ref.shown_item(1, 1, 2, 40)]
    obs = _observation(shown, np.zeros((1, 1)))
    assert make_policy(name).act(obs).object_id == 1
    assert make_policy(name, tie_break="shown_order").act(obs).object_id == 0


def _bench(tmp_path, *extra: str) -> list[str]:
    from packlab.cases import save_cases

    cases = save_cases([_equal_volume_case()], tmp_path / "cases.jsonl")
    return [
        "bench",
        "--cases",
        str(cases),
        "--backend",
        "geometric",
        "--policies",
        "dblf,ffp",
        "--seeds",
        "0",
        "--workers",
        "1",
        "--no-progress",
        "--no-figures",
        *extra,
    ]


def test_bench_takes_the_option_as_a_policy_arg(tmp_path, capsys) -> None:
    import json

    from packlab.cli.main import main

    out = tmp_path / "run"
    argv = _bench(tmp_path, "--out", str(out), "--policy-arg", "dblf:tie_break=shown_order")
    assert main(argv) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["policy_args"] == {"dblf": {"tie_break": "shown_order"}}


def test_bench_refuses_a_bad_value_in_one_line(tmp_path, capsys) -> None:
    from packlab.cli.main import main

    bad = "dblf:tie_break=biggest"
    argv = _bench(tmp_path, "--out", str(tmp_path / "run"), "--policy-arg", bad)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "'biggest'" in err and "larger_volume, shown_order" in err
