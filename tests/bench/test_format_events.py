"""How a served model's answers were read, counted per row: step records carry the format event,
re-ask and forced set-aside; summary.json, table.md, report.html and ``bench compare`` count
them; rows are labelled with their prompt protocol and the policy options they ran with."""

from __future__ import annotations

import json
import re
from pathlib import Path

from msgspec import UNSET, UnsetType

from packlab.bench.compare import compare_markdown, merge_summaries
from packlab.bench.html_report import compare_html
from packlab.bench.records import read_record_file
from packlab.bench.table import render_markdown
from packlab.cli.main import main
from packlab.core.errors import EXIT_OK
from packlab.core.records import AnswerFormats, summary_from_json
from packlab.viz.labels import policy_label
from packlab.viz.report_html import embedded_data
from packlab.vlm.serve.server import scripted, serve

#: The first shown box, unrotated, in the corner: in packlab's key order and the reference's.
PACKLAB = json.dumps({"object_id": 0, "rotation": 0, "x": 0, "y": 0})
REFERENCE = '{"object_id":0,"x":0,"y":0,"rotation":0}'
FENCED = "```json\n{}\n```"
GARBAGE = "I cannot tell where it goes."


def _bench(cases: Path, out: Path, url: str, *options: str) -> None:
    argv = [
        "bench", "--cases", str(cases), "--backend", "geometric", "--policies", "endpoint",
        "--seeds", "0", "--workers", "1", "--out", str(out), "--no-progress", "--no-figures",
        "--policy-arg", f"endpoint:base_url={url}",
        "--policy-arg", "endpoint:deadline_s=5",
        "--policy-arg", "endpoint:retries=0",
    ]  # fmt: skip
    for option in options:
        argv += ["--policy-arg", f"endpoint:{option}"]
    assert main(argv) == EXIT_OK


def _served_run(cases: Path, out: Path, answers: list[str], default: str, *options: str) -> None:
    with serve(scripted(answers, default=default)) as server:
        _bench(cases, out, server.base_url, *options)


def _steps(out: Path) -> list:
    return [s for r in read_record_file(out / "episodes.jsonl").records for s in r.steps]


def _summary(out: Path):
    return summary_from_json((out / "summary.json").read_bytes(), "summary.json")


def _answer_row(table_md: str, label: str) -> list[str]:
    """The answer-format table's row of ``label``: its cells."""
    section = table_md.split("### Answer format", 1)[1]
    line = next(ln for ln in section.splitlines() if ln.startswith(f"| {label} |"))
    return [c.strip() for c in line.strip("|").split("|")][1:]


def test_packlab_prompt_answers_are_counted_in_summary_table_and_page(tiny_suite, tmp_path):
    out = tmp_path / "run"
    # strict JSON by default; one fenced answer, one among words, two without an action
    answers = [FENCED.format(PACKLAB), f"Sure: {PACKLAB}", GARBAGE, "{}"]
    _served_run(tiny_suite, out, answers, PACKLAB)

    steps = _steps(out)
    events = [s.format_event for s in steps]
    assert events[:4] == ["extra_text", "extra_text", "parse_fail", "parse_fail"]
    assert set(events[4:]) == {"strict_json"}
    assert [s.reason for s in steps[2:4]] == ["unparsable", "unparsable"]
    assert all(s.reasked is s.forced is UNSET for s in steps)  # no re-ask here

    n = len(steps)
    counts = _summary(out).counts["endpoint"].answer_formats
    assert counts == AnswerFormats(
        strict_json=n - 4, extra_text=2, parse_fail=2, reasked=0, forced=0
    )
    table_md = (out / "table.md").read_text()
    assert _answer_row(table_md, "endpoint") == [str(n - 4), "2", "2", "0", "0"]
    page = embedded_data((out / "report.html").read_text())
    (method,) = page["methods"]
    assert method["name"] == "endpoint"
    assert {k: method["counts"][k] for k in ("strict_json", "extra_text", "parse_fail")} == {
        "strict_json": n - 4,
        "extra_text": 2,
        "parse_fail": 2,
    }
    assert [c[1] for c in page["details_extra"]] == [
        "strict JSON", "extra text", "parse failures", "re-asks", "forced set-asides",
    ]  # fmt: skip


def test_reference_prompt_counts_reasks_and_forced_set_asides(tiny_suite, tmp_path):
    out = tmp_path / "run"
    answers = [
        FENCED.format(REFERENCE),  # step 0: extra text
        GARBAGE, REFERENCE,  # step 1: re-asked, then strict
        GARBAGE, GARBAGE,  # step 2: re-asked, still nothing: a forced set-aside
    ]  # fmt: skip
    _served_run(tiny_suite, out, answers, REFERENCE, "prompt=reference", "reask=true")

    steps = _steps(out)
    first = [(s.format_event, s.reasked, s.forced, s.reason) for s in steps[:3]]
    assert first == [
        ("extra_text", False, UNSET, ""),
        ("strict_json", True, UNSET, ""),
        ("parse_fail", True, "parse_fail", "set_aside"),
    ]
    n = len(steps)
    counts = _summary(out).counts["endpoint"].answer_formats
    assert counts == AnswerFormats(n - 2, 1, 1, reasked=2, forced=1)

    label = "endpoint (reference prompt, reask=true)"
    table_md = (out / "table.md").read_text()
    assert _answer_row(table_md, label) == [str(n - 2), "1", "1", "2", "1"]
    assert f"| {label} |" in table_md.split("### Run details")[0]  # the results row too
    page = embedded_data((out / "report.html").read_text())
    (method,) = page["methods"]
    assert method["name"] == label
    assert (method["counts"]["reasked"], method["counts"]["forced"]) == (2, 1)
    recorded = _summary(out).policy_args  # the labels' source
    assert not isinstance(recorded, UnsetType)
    assert {k: recorded["endpoint"][k] for k in ("prompt", "reask")} == {
        "prompt": "reference",
        "reask": True,
    }


def test_rows_of_other_policies_have_no_answer_formats(tiny_suite, tmp_path):
    out = tmp_path / "run"
    argv = ["bench", "--cases", str(tiny_suite), "--backend", "geometric", "--policies", "dblf"]
    argv += ["--seeds", "0", "--workers", "1", "--out", str(out), "--no-progress", "--no-figures"]
    assert main(argv) == EXIT_OK
    assert all(s.format_event is UNSET for s in _steps(out))
    summary = json.loads((out / "summary.json").read_text())
    assert "answer_formats" not in summary["counts"]["dblf"]
    assert "policy_args" not in summary
    assert "Answer format" not in (out / "table.md").read_text()
    assert "details_extra" not in embedded_data((out / "report.html").read_text())


def test_the_label_names_the_prompt_protocol_and_ablations():
    assert policy_label("endpoint", {"prompt": "reference"}) == "endpoint (reference prompt)"
    assert policy_label("endpoint", {"prompt": "packlab", "reask": False}) == "endpoint"
    options = {"prompt": "reference", "max_past_steps": 2, "history": "current_only"}
    assert policy_label("endpoint", {**options, "deadline_s": 9, "base_url": "http://h"}) == (
        "endpoint (reference prompt, history=current_only, max_past_steps=2)"
    )
    assert policy_label("dblf", {"tie_break": "smaller"}) == "DBLF"  # not an ablation option


def test_compare_labels_runs_that_differ_in_a_policy_option(tiny_suite, tmp_path):
    full, blank = tmp_path / "full", tmp_path / "blank"
    with serve(scripted([], default=PACKLAB)) as server:
        _bench(tiny_suite, full, server.base_url)
        _bench(tiny_suite, blank, server.base_url, "image=blank")
    text = compare_markdown([full, blank])
    assert "| full (image=default) |" in text and "| blank (image=blank) |" in text
    assert "### Answer format" in text  # carried through: the counts of both rows
    assert _answer_row(text, "blank (image=blank)")[1:] == ["0", "0", "0", "0"]
    page = embedded_data(compare_html([full, blank], generated="2026-01-01 00:00:00 UTC"))
    assert [m["name"] for m in page["methods"]] == ["full (image=default)", "blank (image=blank)"]
    assert page["methods"][1]["counts"]["strict_json"] > 0

    # The same option in both runs labels them alike (the label every row gets); runs with
    # the same options keep their plain labels.
    same = merge_summaries([_summary(full), _summary(full)], ["a", "b"])
    assert same.policies == ("a", "b")
    other = merge_summaries([_summary(blank), _summary(blank)], ["a", "b"])
    assert other.policies == ("a (image=blank)", "b (image=blank)")


def test_compare_names_the_method_of_multi_method_runs(tiny_suite, tmp_path):
    with serve(scripted([], default=PACKLAB)) as server:
        for name, extra in (("a", ()), ("b", ("image=blank", "deadline_s=4"))):
            argv = ["bench", "--cases", str(tiny_suite), "--backend", "geometric"]
            argv += ["--policies", "endpoint,dblf", "--seeds", "0", "--workers", "1"]
            argv += ["--out", str(tmp_path / name), "--no-progress", "--no-figures", "--no-html"]
            argv += ["--policy-arg", f"endpoint:base_url={server.base_url}"]
            for option in extra:
                argv += ["--policy-arg", f"endpoint:{option}"]
            assert main(argv) == EXIT_OK
    merged = merge_summaries([_summary(tmp_path / "a"), _summary(tmp_path / "b")], ["a", "b"])
    # deadline_s says how the policy runs, not what it does: never named.
    assert merged.policies == (
        "a: endpoint (image=default)",
        "a: DBLF",
        "b: endpoint (image=blank)",
        "b: DBLF",
    )
    table_md = render_markdown(merged)
    assert re.search(r"\| b: endpoint \(image=blank\) \| \d+ \| 0 \| 0 \| 0 \| 0 \|", table_md)
