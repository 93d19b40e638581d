"""``packlab bench compare``: several runs in one table, only when they are comparable."""

from __future__ import annotations

import json

import numpy as np
import pytest
from record_helpers import ok_record

from packlab.bench.compare import (
    compare_markdown,
    differences_markdown,
    judged_significant,
    load_summary,
    merge_summaries,
    paired_differences,
    reliable_groups,
)
from packlab.bench.intervals import Interval
from packlab.bench.report import summary_json
from packlab.bench.summary import summarize
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
    ("other", "said"),
    [
        (_summary({"vlm": 0.1}, seeds=(0,)), "differ in seeds (--seeds): 0,1,2 in 'a', 0 in 'b'"),
        (
            _summary({"vlm": 0.1}, sha="zzz"),
            "differ in cases (--cases): s (sha256 abc...) in 'a', s (sha256 zzz...) in 'b'",
        ),
    ],
)
def test_incomparable_runs_are_refused_in_the_users_words(other, said):
    with pytest.raises(PacklabError) as err:
        merge_summaries([_summary({"vlm": 0.4}), other], ["a", "b"])
    message = str(err.value)
    assert said in message and "UNSET" not in message and "_sha256" not in message
    assert "compare needs the same cases, seeds, difficulties and backend" in message


def _sensing(**settings: str) -> dict:
    return {"observation": "exact", "execution": "exact", "noise": "structured-light", **settings}


def test_documented_ablations_are_labelled_rows():
    # README's ablation: the paper's protocol (--sides catalogue) against the default names.
    # A run made before the side names were always recorded has no sensing entry: it named
    # them as the catalogue does. Neither run has a segmentation: none leaks into the labels.
    lf = _summary_json({"dblf": 0.3, "hm": 0.35}) | {"sensing": _sensing(sides="longer-first")}
    paper = _summary_json({"dblf": 0.4, "hm": 0.38}) | {"sensing": _sensing(sides="catalogue")}
    for catalogue in (
        _summary({"dblf": 0.4, "hm": 0.38}),
        summary_from_json(json.dumps(paper), "s"),
    ):
        merged = merge_summaries(
            [catalogue, summary_from_json(json.dumps(lf), "s.json")], ["paper", "ours"]
        )
        assert merged.policies == (
            "paper (sides catalogue): DBLF",
            "paper (sides catalogue): HM",
            "ours (sides longer-first): DBLF",
            "ours (sides longer-first): HM",
        )
    perceived = _summary_json({"vlm": 0.2}) | {
        "sensing": _sensing(observation="perceived", segmentation="truth")
    }
    depth = _summary_json({"vlm": 0.1}) | {
        "sensing": _sensing(observation="perceived", segmentation="depth")
    }
    merged = merge_summaries(
        [summary_from_json(json.dumps(x), "s.json") for x in (perceived, depth)], ["t", "d"]
    )
    assert merged.policies == ("t (segmentation truth)", "d (segmentation depth)")
    # A perceived run always named sides longer first, recorded or not (``depth`` has no
    # ``sides``): against an old exact run (the catalogue's names) the names differ too ...
    merged = merge_summaries(
        [_summary({"vlm": 0.4}), summary_from_json(json.dumps(depth), "s.json")], ["e", "p"]
    )
    assert merged.policies == (
        "e (observation exact, sides catalogue)",
        (
            "p (observation perceived, noise structured-light, segmentation depth, sides "
            "longer-first, size prior grid)"
        ),
    )
    # ... against an exact run of this version (longer first by default) only the modes do.
    merged = merge_summaries(
        [summary_from_json(json.dumps(x), "s.json") for x in (lf, depth)], ["e", "p"]
    )
    assert merged.policies == (
        "e (observation exact): DBLF",
        "e (observation exact): HM",
        "p (observation perceived, noise structured-light, segmentation depth, size prior grid)",
    )


def test_few_cases_a_level_make_unreliable_unmarked_intervals(tmp_path):
    # One case per level: the interval collapses to a point; it is shown, flagged, not bold.
    a = _run_dir(tmp_path, "a", {"p": {"c1": [0.5] * 3, "c2": [0.6] * 3}})
    b = _run_dir(tmp_path, "b", {"p": {"c1": [0.36] * 3, "c2": [0.46] * 3}})
    text = compare_markdown([a, b])
    row = next(line for line in text.splitlines() if line.startswith("| b | 2 |"))
    assert "-0.140 [-0.140, -0.140]†" in row and "**" not in row
    assert row.endswith("| not judged (fewer than 5 cases a level) |")
    assert "† fewer than 5 cases per level: intervals not reliable" in text
    merged = merge_summaries([load_summary(a), load_summary(b)], ["a", "b"])
    diffs = paired_differences(merged, "b", "a")
    assert diffs["average"].significant  # the bootstrap alone would call it significant
    assert reliable_groups(diffs) == {"easy": False, "hard": False, "average": False}
    assert not judged_significant(diffs["average"], False)


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
               "--labels", "full,blank image", "--out", str(out), "--wide"])  # fmt: skip
    assert rc == 0
    text = capsys.readouterr().out
    # summaries without per-case cells: the means alone, and no paired differences to make
    assert "| blank image | 0.250 | 0.250 |" in text and "| full | 0.400 |" in text
    assert "none here: this summary has no per-case scores" in text
    assert "| blank image | - | - | - |\n" in text  # row, cases, easy, verdict
    assert out.read_text() + "\n" == text  # the file holds exactly what --wide printed
    # Without --wide the results table is the 120-column view; the file stays the whole table.
    main(["bench", "compare", str(tmp_path / "run-full"), str(tmp_path / "run-blank"),
          "--labels", "full,blank image", "--out", str(out)])  # fmt: skip
    compact = capsys.readouterr().out
    assert "| blank image |        0.250 |" in compact and "--wide prints them" in compact
    assert out.read_text() + "\n" == text
    assert compare_markdown([tmp_path / "run-full"]).count("| run-full |") == 2  # both tables


def test_missing_summary_is_a_clear_error(tmp_path):
    with pytest.raises(PacklabError, match="no summary.json"):
        compare_markdown([tmp_path])


def _run_dir(tmp_path, name, scores):
    """A run directory whose summary.json comes from records: policy -> case -> per-seed."""
    recs = [
        ok_record(case, seed, policy, "easy" if int(case[1:]) % 2 else "hard", value)
        for policy, cases in scores.items()
        for case, per_seed in cases.items()
        for seed, value in enumerate(per_seed)
    ]
    summary = summarize(recs, list(scores), [0, 1, 2], ["easy", "hard"])
    (tmp_path / name).mkdir()
    (tmp_path / name / "summary.json").write_text(summary_json(summary))
    return tmp_path / name


def test_paired_differences_mark_only_intervals_that_exclude_zero(tmp_path):
    rng = np.random.default_rng(0)
    base = {f"c{i}": float(v) for i, v in enumerate(rng.uniform(0.3, 0.8, 30))}
    # scatter of +-0.01 that alternates within each level (cases alternate levels): no shift
    noise = {f"c{i}": 0.01 if (i // 2) % 2 else -0.01 for i in range(30)}
    run = _run_dir(
        tmp_path,
        "run",
        {
            "ref": {c: [v] * 3 for c, v in base.items()},
            "better": {c: [v + 0.05] * 3 for c, v in base.items()},
            "same": {c: [v + noise[c]] * 3 for c, v in base.items()},
        },
    )
    text = compare_markdown([run])
    assert "### Paired differences: each row minus run: ref" in text
    assert "excludes 0" in text
    better = next(line for line in text.splitlines() if line.startswith("| run: better | 30 |"))
    assert "**+0.050 [+0.050, +0.050]**" in better and better.endswith("| yes, higher |")
    same = next(line for line in text.splitlines() if line.startswith("| run: same | 30 |"))
    assert "**" not in same and same.endswith("| no (interval includes 0) |")
    merged = merge_summaries([load_summary(run)], ["run"])
    against_better = differences_markdown(merged, reference="run: better")
    assert "| run: ref | 30 |" in against_better and "yes, lower |" in against_better
    with pytest.raises(PacklabError, match="reference 'nope' is not a row"):
        differences_markdown(merged, reference="nope")
    diffs = paired_differences(merged, "run: same", "run: ref")
    assert diffs["average"].interval.low < 0 < diffs["average"].interval.high
    assert diffs["easy"].n_cases == 15 and diffs["average"].n_cases == 30


def test_differences_pair_across_runs_on_common_cases(tmp_path):
    a = _run_dir(tmp_path, "a", {"p": {"c1": [0.5, 0.5, 0.5], "c2": [0.4, 0.6, 0.5]}})
    b = _run_dir(tmp_path, "b", {"p": {"c1": [0.2, 0.2, 0.2], "c2": [0.1, 0.3, 0.2]}})
    merged = merge_summaries([load_summary(a), load_summary(b)], ["a", "b"])
    diffs = paired_differences(merged, "b", "a")
    assert diffs["average"].estimate == pytest.approx(-0.3)
    assert diffs["easy"].interval == Interval(pytest.approx(-0.3), pytest.approx(-0.3))
    text = compare_markdown([a, b])
    # a's c2 varies over seeds: two-level intervals, said under the table
    assert "for a, b (scores vary across seeds) seeds also resampled" in text


def test_cli_reference_picks_the_row_differences_are_taken_against(tmp_path, capsys):
    base = {f"c{i}": 0.3 + 0.01 * i for i in range(10)}
    run = _run_dir(
        tmp_path,
        "run",
        {
            "ref": {c: [v] * 3 for c, v in base.items()},
            "better": {c: [v + 0.05] * 3 for c, v in base.items()},
        },
    )
    assert main(["bench", "compare", str(run)]) == 0
    default = capsys.readouterr().out
    assert "each row minus run: ref" in default and "| run: better | 10 |" in default
    assert main(["bench", "compare", str(run), "--reference", "run: ref"]) == 0
    assert capsys.readouterr().out == default  # naming the first row is the default
    out = tmp_path / "against.md"
    rc = main(
        ["bench", "compare", str(run), "--reference", "run: better", "--out", str(out), "--wide"]
    )
    assert rc == 0
    text = capsys.readouterr().out
    assert "### Paired differences: each row minus run: better" in text
    ref_row = next(line for line in text.splitlines() if line.startswith("| run: ref | 10 |"))
    assert "**-0.050 [-0.050, -0.050]**" in ref_row and ref_row.endswith("| yes, lower |")
    assert "| run: better | 10 |" not in text  # the reference is no row of its own table
    assert out.read_text() + "\n" == text


def test_cli_reference_that_is_no_row_is_one_line_naming_flag_and_rows(tmp_path, capsys):
    run = _run_dir(tmp_path, "run", {"ref": {"c1": [0.5] * 3}, "other": {"c1": [0.4] * 3}})
    out = tmp_path / "never.md"
    rc = main(["bench", "compare", str(run), "--reference", "ref", "--out", str(out)])
    assert rc == 2 and not out.exists()
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert lines == [
        (
            "packlab bench: error: --reference 'ref': not a row of this comparison; "
            "rows: 'run: ref', 'run: other'"
        )
    ]


def test_report_page_does_not_judge_differences_from_few_cases(tmp_path):
    from packlab.bench.html_report import difference_notes

    a = _run_dir(tmp_path, "a", {"p": {"c1": [0.5] * 3, "c2": [0.6] * 3}})
    b = _run_dir(tmp_path, "b", {"p": {"c1": [0.36] * 3, "c2": [0.46] * 3}})
    (note,) = difference_notes(merge_summaries([load_summary(a), load_summary(b)], ["a", "b"]))
    assert note.endswith("not judged: fewer than 5 cases per level: intervals not reliable, "
                         "significance not marked.")  # fmt: skip
    assert ": significant" not in note
