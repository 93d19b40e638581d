"""report.html: deterministic, self-contained, its replays equal to the records (older records
included), and the flags that write it (``packlab bench``, ``bench report``, ``bench compare``)."""

from __future__ import annotations

import json
import random
import re
import sys

import pytest
from report_helpers import as_run1, rewrite_records, sloppy_policy, small_run

from packlab.bench.html_report import REPORT_HTML, compare_html, run_html
from packlab.bench.report import load_run, summary_of
from packlab.bench.summary import run_intervals
from packlab.cli.main import main
from packlab.core.errors import EXIT_OK, EXIT_USAGE, PacklabError
from packlab.core.records import EpisodeOk
from packlab.sim.pose_log import poses_after
from packlab.viz.report_data import POSE_SOURCES
from packlab.viz.report_html import GENERATED_META, embedded_data


@pytest.fixture
def sloppy():
    with sloppy_policy() as name:
        yield name


@pytest.fixture
def run_dir(tiny_suite, tmp_path, sloppy):
    small_run(tiny_suite, tmp_path / "run")
    return tmp_path / "run"


def _page(run_dir, generated="2026-01-01 00:00:00 UTC"):
    run = load_run(run_dir)
    return run_html(run.config, run.records, run.cases, generated=generated)


def _by_key(data):
    """Episodes of the page by (policy, case id, seed)."""
    return {
        (data["methods"][e["m"]]["policy"], data["cases"][e["c"]]["id"], e["s"]): e
        for e in data["episodes"]
    }


# -- the page ---------------------------------------------------------------------------------


def test_same_records_same_page_but_for_the_timestamp_line(run_dir):
    first = _page(run_dir, "2026-01-01 00:00:00 UTC")
    # The same records in another order (as parallel workers finish them), built at another time.
    lines = (run_dir / "episodes.jsonl").read_text().splitlines()
    random.Random(0).shuffle(lines)
    (run_dir / "episodes.jsonl").write_text("\n".join(lines) + "\n")
    second = _page(run_dir, "2027-06-30 12:34:56 UTC")
    a, b = first.splitlines(), second.splitlines()
    assert len(a) == len(b)
    differ = [(x, y) for x, y in zip(a, b) if x != y]
    assert len(differ) == 1 and GENERATED_META in differ[0][0]
    assert "2027-06-30 12:34:56 UTC" in differ[0][1]


def test_the_page_needs_no_network(run_dir):
    html = _page(run_dir)
    assert not re.search(r"<script[^>]*\bsrc\s*=", html, re.IGNORECASE)
    assert not re.search(r"<link[^>]*\bhref\s*=", html, re.IGNORECASE)
    assert not re.search(r"<(img|iframe)[^>]*\bsrc\s*=\s*[\"']?https?:", html, re.IGNORECASE)
    assert "@import" not in html
    assert html.count("plotly.js v") >= 1 and html.count("<script") == 3  # plotly, data, page
    # No string in the data (the sloppy policy's "<left>") can end the data's script element.
    data_part = html.split('id="packlab-data">', 1)[1].split("</script>", 1)[0]
    assert "<" not in data_part


def test_the_page_carries_the_bootstrap_intervals(run_dir):
    run = load_run(run_dir)
    data = embedded_data(_page(run_dir))
    summary = summary_of(run.config, run.records)
    found = run_intervals(summary)
    groups = [*summary.difficulties, "average"] if len(summary.difficulties) > 1 else []
    groups = groups or list(summary.difficulties)
    for m in data["methods"]:
        cell = m["cells"][-1]  # the last group's Overall: [mean, std, low, high]
        low, high = found.bounds(m["policy"], groups[-1], "overall")
        # The page rounds to 6 decimals: half a unit of the last place apart at most.
        assert cell[2:] == [pytest.approx(low, abs=5e-7), pytest.approx(high, abs=5e-7)]
        assert cell[2] <= cell[0] <= cell[3]
    assert data["intervals"][0]["resamples"] == found.resamples
    # One calm headline, the best method with its interval; no note repeats the table.
    mean = summary.table["dblf"][groups[-1]].overall.mean
    low, high = found.bounds("dblf", groups[-1], "overall")
    assert data["headline"] == f"Best: DBLF, Average Overall {mean:.3f} [{low:.3f}, {high:.3f}]."
    assert not any(n.startswith("DBLF") for n in data["notes"])


def test_replays_hold_what_the_records_hold(run_dir, sloppy):
    run = load_run(run_dir)
    data = embedded_data(_page(run_dir))
    episodes = _by_key(data)
    cases = {c.episode_id: c for c in run.cases}
    ok = [r for r in run.records if isinstance(r, EpisodeOk)]
    assert len(episodes) == len(run.records) == 16
    for rec in ok:
        ep = episodes[(rec.policy, rec.case_id, rec.seed)]
        case = cases[rec.case_id]
        index = {str(b.internal_id): i for i, b in enumerate(case.objects)}
        assert ep["poses"] == "recorded"
        assert ep["metrics"]["overall"] == round(rec.metrics.overall, 6)
        assert len(ep["steps"]) == len(rec.steps) == len(case.objects)
        for step, s in zip(ep["steps"], rec.steps):
            obj, action, reason, shown, poses = step
            assert obj == index[str(s.internal_id)]
            assert shown == [index[str(i)] for i in s.shown]
            assert poses == [list(e) for e in s.poses]
            assert data["reasons"][reason] == s.reason
            if isinstance(s.action.unparsable, str):
                assert action == f"unparsable: {s.action.error}"
            else:
                assert action == [s.action.object_id, s.action.rotation, s.action.x, s.action.y]
        # After the last step, every box the record kept is where the record says.
        last = poses_after([st[4] for st in ep["steps"]], len(rec.steps) - 1)
        for iid, pose in rec.final_poses.items():
            if pose is None:
                assert index[iid] not in last
            else:
                assert last[index[iid]][1:4] == [round(v, 1) for v in pose.position_mm]
    # The sloppy policy's steps are marked: out of bounds, then unparsable.
    sloppy_ep = episodes[(sloppy, "easy-1", 0)]
    assert [data["reasons"][s[2]] for s in sloppy_ep["steps"]][:4] == [
        "",
        "out_of_bounds",
        "",
        "unparsable",
    ]
    assert sloppy_ep["metrics"]["set_aside"] == 2 and sloppy_ep["metrics"]["invalid"] == 2


def test_copied_episodes_say_which_seed_they_copy(run_dir, sloppy):
    """A seed-free policy's episodes of seed 1 are copies of seed 0's (the bench's reuse): the
    page marks each with the seed it copies, in the case browser and the replay's title; a
    played episode carries no mark."""
    data = embedded_data(_page(run_dir))
    episodes = _by_key(data)
    dblf = [e for (policy, _case, seed), e in episodes.items() if policy == "dblf" and seed == 1]
    played = [e for (policy, _case, _seed), e in episodes.items() if policy == sloppy]
    assert dblf and all(e["reused_from"] == 0 for e in dblf)
    assert played and all("reused_from" not in e for e in played)
    assert all("reused_from" not in e for (p, _c, s), e in episodes.items() if s == 0)
    page = _page(run_dir)
    assert '" (copy of "' in page and "do not depend on the run seed" in page


def test_failed_episodes_are_listed_with_their_error(tiny_suite, tmp_path, crash_policy):
    small_run(tiny_suite, tmp_path / "run", policies=("dblf", crash_policy), seeds=(0,))
    data = embedded_data(_page(tmp_path / "run"))
    failed = [e for e in data["episodes"] if "error" in e]
    assert len(failed) == 2 and all("deliberate failure" in e["error"] for e in failed)
    assert "steps" not in failed[0] and any("2 episode(s) failed" in n for n in data["notes"])


# -- older records ----------------------------------------------------------------------------


def _strip_poses(rec):
    for s in rec.get("steps", []):
        s.pop("poses", None)


def test_geometric_records_without_poses_replay_exactly(run_dir):
    before = _by_key(embedded_data(_page(run_dir)))
    rewrite_records(run_dir, _strip_poses)
    after = _by_key(embedded_data(_page(run_dir)))
    assert before.keys() == after.keys()
    for key, ep in after.items():
        assert ep["poses"] == "geometric"
        assert ep["steps"] == before[key]["steps"]  # rebuilt from drop_mm: the very same poses


def test_old_mujoco_records_show_final_poses_and_say_so(run_dir):
    """Records of a physics run written before per-step poses: each box appears at its final
    pose from the step it was placed, and the page says so."""

    def as_old_mujoco(rec):
        _strip_poses(rec)
        rec["backend"] = "mujoco"

    rewrite_records(run_dir, as_old_mujoco)
    config = json.loads((run_dir / "config.json").read_text())
    (run_dir / "config.json").write_text(json.dumps({**config, "backend": "mujoco"}))
    run = load_run(run_dir)
    data = embedded_data(_page(run_dir))
    assert any("before records kept per-step poses" in n for n in data["notes"])
    cases = {c.episode_id: c for c in run.cases}
    episodes = _by_key(data)
    for rec in run.records:
        ep = episodes[(rec.policy, rec.case_id, rec.seed)]
        assert ep["poses"] == "final" and data["pose_sources"]["final"] == POSE_SOURCES["final"]
        ids = [str(b.internal_id) for b in cases[rec.case_id].objects]
        for step, s in zip(ep["steps"], rec.steps):
            if not s.valid:
                assert step[4] == []
                continue
            (entry,) = step[4]
            final = rec.final_poses[ids[entry[0]]]
            assert entry[1:4] == [round(v, 1) for v in final.position_mm]


def test_run1_records_still_render(run_dir):
    """A run-1 directory (records without format, steps with ``capped``) migrates and renders."""

    as_run1(run_dir)
    data = embedded_data(_page(run_dir))
    assert len(data["episodes"]) == 16
    assert {e["poses"] for e in data["episodes"]} == {"geometric"}


def test_a_newer_record_format_is_refused_naming_file_line_and_field(run_dir, capsys):
    path = run_dir / "episodes.jsonl"
    lines = path.read_text().splitlines()
    lines[0] = lines[0].replace('"format":"packlab-bench-run-2"', '"format":"packlab-bench-run-9"')
    path.write_text("\n".join(lines) + "\n")
    assert main(["bench", "report", str(run_dir), "--html", "--no-figures"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "episodes.jsonl:1: field 'format' = 'packlab-bench-run-9'" in err
    assert not (run_dir / REPORT_HTML).exists()


def test_without_cases_file_the_page_scores_but_does_not_replay(run_dir):
    (run_dir / "cases.jsonl").unlink()
    data = embedded_data(_page(run_dir))
    assert all(c["boxes"] is None for c in data["cases"]) and len(data["cases"]) == 4
    assert all("steps" not in e for e in data["episodes"])
    assert any("no cases.jsonl" in n for n in data["notes"])


# -- commands ---------------------------------------------------------------------------------


def _bench_argv(tiny_suite, out, *extra):
    return [
        "bench",
        "--cases",
        str(tiny_suite),
        "--policies",
        "dblf,random",
        "--seeds",
        "0",
        "--backend",
        "geometric",
        "--workers",
        "1",
        "--no-progress",
        "--no-figures",
        "--out",
        str(out),
        *extra,
    ]


def test_bench_writes_report_html_unless_told_not_to(tiny_suite, tmp_path, capsys):
    assert main(_bench_argv(tiny_suite, tmp_path / "a")) == EXIT_OK
    written = (tmp_path / "a" / REPORT_HTML).read_text()
    assert [m["policy"] for m in embedded_data(written)["methods"]] == ["dblf", "random"]
    # bench report --html rebuilds the same page from the files alone (but for the timestamp)
    assert main(["bench", "report", str(tmp_path / "a"), "--html", "--no-figures"]) == EXIT_OK
    assert f"wrote {tmp_path / 'a' / REPORT_HTML}" in capsys.readouterr().err
    rebuilt = (tmp_path / "a" / REPORT_HTML).read_text()
    differ = [a for a, b in zip(written.splitlines(), rebuilt.splitlines()) if a != b]
    assert len(written.splitlines()) == len(rebuilt.splitlines()) and len(differ) <= 1
    assert all(GENERATED_META in line for line in differ)
    assert main(_bench_argv(tiny_suite, tmp_path / "b", "--no-html")) == EXIT_OK
    assert not (tmp_path / "b" / REPORT_HTML).exists()


def test_without_plotly_bench_skips_the_html_with_one_note(
    tiny_suite, tmp_path, capsys, monkeypatch
):
    monkeypatch.setitem(sys.modules, "plotly", None)  # makes `import plotly...` fail
    monkeypatch.setitem(sys.modules, "plotly.offline", None)
    assert main(_bench_argv(tiny_suite, tmp_path / "a")) == EXIT_OK
    err = capsys.readouterr().err
    notes = [line for line in err.splitlines() if "report.html" in line]
    note = (
        "report.html skipped: the HTML report needs plotly, a core dependency that is missing "
        "here: pip install plotly"
    )
    assert notes == [f"packlab bench: note: {note}"]
    assert not (tmp_path / "a" / REPORT_HTML).exists() and (tmp_path / "a" / "table.md").exists()
    # Asked for explicitly, it is an error instead.
    assert main(["bench", "report", str(tmp_path / "a"), "--html"]) == EXIT_USAGE


def test_compare_html_has_one_row_per_run_and_method(tiny_suite, tmp_path, capsys):
    for name in ("base", "other"):
        assert main(_bench_argv(tiny_suite, tmp_path / name, "--no-html")) == EXIT_OK
    out = tmp_path / "cmp" / "table.md"
    argv = ["bench", "compare", str(tmp_path / "base"), str(tmp_path / "other")]
    assert main([*argv, "--labels", "A,B", "--out", str(out), "--html"]) == EXIT_OK
    data = embedded_data((tmp_path / "cmp" / "table.html").read_text())
    assert [m["name"] for m in data["methods"]] == ["A: DBLF", "A: Random", "B: DBLF", "B: Random"]
    assert [m["run"] for m in data["methods"]] == [0, 0, 1, 1]
    assert [r["label"] for r in data["runs"]] == ["A", "B"]
    assert all(len(c) == 4 for m in data["methods"] for c in m["cells"] if c is not None)
    # every row after the first against the first, with its verdict
    assert sum("minus A: DBLF" in n for n in data["differences"]) == 3
    assert len(data["episodes"]) == 2 * 2 * 4 and len(data["cases"]) == 4
    assert main([*argv, "--html", str(tmp_path / "x.html")]) == EXIT_OK
    assert (tmp_path / "x.html").is_file()


def test_compare_html_refuses_runs_on_other_seeds(tiny_suite, tmp_path):
    assert main(_bench_argv(tiny_suite, tmp_path / "a", "--no-html")) == EXIT_OK
    argv = _bench_argv(tiny_suite, tmp_path / "b", "--no-html")
    argv[argv.index("--seeds") + 1] = "1"
    assert main(argv) == EXIT_OK
    with pytest.raises(PacklabError, match="differ in seeds \\(--seeds\\): 0 in 'a', 1 in 'b'"):
        compare_html([tmp_path / "a", tmp_path / "b"])
