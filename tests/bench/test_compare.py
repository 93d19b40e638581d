"""``packlab bench compare``: several runs in one table, only when they are comparable."""

from __future__ import annotations

import json

import pytest

from packlab.bench.compare import compare_markdown, merge_summaries
from packlab.cli.main import main
from packlab.core.errors import PacklabError
from packlab.core.records import summary_from_json


def _cell(mean: float) -> dict:
    return {"mean": mean, "std": 0.01, "per_seed": {"0": mean}}


def _summary(policies: dict[str, float], seeds=(0, 1, 2), sha="abc"):
    """A summary as written before summaries carried a format (read through the migration)."""
    return summary_from_json(json.dumps(_summary_json(policies, seeds, sha)), "summary.json")


def _summary_json(policies: dict[str, float], seeds=(0, 1, 2), sha="abc") -> dict:
    groups = ("easy", "average")
    return {
        "suite": "s", "backend": "mujoco", "n_cases": 2, "seeds": list(seeds),
        "difficulties": ["easy"], "cases_sha256": sha, "policies": list(policies),
        "table": {p: {g: {m: _cell(v) for m in ("success_ratio", "compactness", "overall")}
                      for g in groups} for p, v in policies.items()},
        "counts": {p: {"episodes": 6, "errors": 0, "steps": 30, "invalid_steps": 1, "set_aside": 1,
                       "capped_placements": 0, "decision_ms": 2.0, "step_ms": 1.0, "episode_s": 0.1}
                   for p in policies},
        "errors": [],
    }  # fmt: skip


def test_rows_follow_runs_and_keep_their_numbers():
    merged = merge_summaries(
        [_summary({"vlm": 0.4}), _summary({"vlm": 0.3}), _summary({"dblf": 0.5, "mta": 0.7})],
        ["full", "blank image", "heuristics"],
    )
    assert merged.policies == ("full", "blank image", "heuristics: DBLF", "heuristics: MTA")
    assert merged.table["blank image"]["easy"].overall.mean == 0.3
    assert merged.table["heuristics: MTA"]["average"].overall.mean == 0.7


@pytest.mark.parametrize(
    ("other", "field"),
    [
        (_summary({"vlm": 0.1}, seeds=(0,)), "seeds"),
        (_summary({"vlm": 0.1}, sha="zzz"), "cases_sha256"),
    ],
)
def test_incomparable_runs_are_refused_by_name(other, field):
    with pytest.raises(PacklabError, match=f"run 'b' has {field}"):
        merge_summaries([_summary({"vlm": 0.4}), other], ["a", "b"])


def test_labels_must_match_runs_and_differ():
    with pytest.raises(PacklabError, match="2 labels for 1 runs"):
        merge_summaries([_summary({"vlm": 0.4})], ["a", "b"])
    with pytest.raises(PacklabError, match="must differ"):
        merge_summaries([_summary({"vlm": 0.4}), _summary({"vlm": 0.4})], ["a", "a"])


def test_cli_prints_and_writes_the_table(tmp_path, capsys):
    for name, v in (("run-full", 0.4), ("run-blank", 0.25)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps(_summary_json({"vlm": v})))
    out = tmp_path / "cmp" / "table.md"
    rc = main(["bench", "compare", str(tmp_path / "run-full"), str(tmp_path / "run-blank"),
               "--labels", "full,blank image", "--out", str(out)])  # fmt: skip
    assert rc == 0
    text = capsys.readouterr().out
    assert "| blank image | 0.250 ± 0.010" in text and "| full | 0.400 ± 0.010" in text
    assert out.read_text() + "\n" == text  # the file holds exactly what was printed
    assert compare_markdown([tmp_path / "run-full"]).count("| run-full |") == 2  # both tables


def test_missing_summary_is_a_clear_error(tmp_path):
    with pytest.raises(PacklabError, match="no summary.json"):
        compare_markdown([tmp_path])
