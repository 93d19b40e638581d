"""The bench plays a seed-free policy once per case and copies the episode to the other seeds.

Every copy must be exactly what playing its seed writes, times and the ``reused_from_seed``
marker aside: the main check replays every reused row of the default bench with ``--no-reuse``
on a sample of the frozen suite (geometric; two rows on mujoco) and compares record by record.
The rest covers resuming at either side of a copy, failed leads, the summary's counts and times,
reports, comparisons, replays and the modes where nothing is reused.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

import pytest
from bench_helpers import tiny_cases
from msgspec import UNSET

from packlab.bench.compare import compare_markdown
from packlab.bench.config import RunConfig, default_policies
from packlab.bench.records import EPISODES_FILE, read_records
from packlab.bench.replay import replay_record
from packlab.bench.report import build_report
from packlab.bench.reuse import reuse_mode, timeless
from packlab.bench.runner import BenchOutcome, run_bench
from packlab.bench.suites import load_suite
from packlab.bench.table import results_table
from packlab.bench.terminal import terminal_text
from packlab.cases import save_cases
from packlab.cli.main import main
from packlab.core.records import EpisodeOk, EpisodeRecord
from packlab.core.types import Action, Case, Observation
from packlab.policies.registry import (
    declare_seed_free,
    register_policy,
    seed_free_always,
    seed_free_modes,
    unregister_policy,
)

SEEDS = (0, 1, 2)


class Interrupt(Exception):
    """Stands for a kill at a chosen record."""


@cache
def suite_sample() -> tuple[Case, ...]:
    """The first two cases of each level of the default suite."""
    cases = load_suite("packlab-bench-v1")
    return tuple(
        c for d in ("easy", "medium", "hard") for c in [x for x in cases if x.difficulty == d][:2]
    )


def _cases_file(directory: Path, cases: tuple[Case, ...] | list[Case]) -> str:
    path = directory / "cases.jsonl"
    save_cases(list(cases), path)
    return str(path)


def _run(cases: str, out: Path, policies, reuse: bool = True, **config) -> BenchOutcome:
    fields = {"backend": "geometric", "seeds": SEEDS, "workers": 1, "progress": False}
    full = RunConfig(
        cases=cases, out=str(out), policies=tuple(policies), reuse=reuse, **{**fields, **config}
    )
    return run_bench(full, figures=False, html=False)


def _records(run_dir: Path) -> dict[tuple, EpisodeRecord]:
    return {r.key: r for r in read_records(run_dir / EPISODES_FILE)}


def assert_same_records(reused: Path, played: Path) -> None:
    """Both run directories hold the same records, times and reuse markers aside."""
    a, b = _records(reused), _records(played)
    assert a.keys() == b.keys()
    for key in a:
        assert isinstance(a[key], EpisodeOk) and isinstance(b[key], EpisodeOk), key
        assert timeless(a[key]) == timeless(b[key]), key


def _marked(run_dir: Path) -> dict[tuple, int]:
    """The copies of a run: their keys and the seed each was copied from."""
    return {
        k: r.reused_from_seed
        for k, r in _records(run_dir).items()
        if isinstance(r, EpisodeOk) and r.reused_from_seed is not UNSET
    }


def reused_defaults(cases) -> list[str]:
    """The default bench rows that are seed-free in the default (exact, buffer) run."""
    return [p for p in default_policies(cases) if "shuffled" in seed_free_modes(p)]


# -- every reused default row, replayed with --no-reuse ------------------------------------


def test_every_reused_default_row_equals_a_full_rerun(tmp_path):
    cases = suite_sample()
    reused = reused_defaults(cases)
    assert {"dblf", "hm", "mta", "ffp", "sdf", "oracle"} <= set(reused)
    policies = [*reused, "random"]  # random: a row that is always played
    source = _cases_file(tmp_path, cases)
    fast = _run(source, tmp_path / "reuse", policies)
    full = _run(source, tmp_path / "full", policies, reuse=False)
    assert_same_records(tmp_path / "reuse", tmp_path / "full")
    copies = _marked(tmp_path / "reuse")
    assert set(copies.values()) == {0}
    assert {(k[1], k[2]) for k in copies} == {(s, p) for s in (1, 2) for p in reused}
    assert len(copies) == 2 * len(reused) * len(cases) == fast.reused
    assert fast.ran == full.ran == full.planned and full.reused == 0
    assert _marked(tmp_path / "full") == {}
    # The numbers are the same; the counts say what was copied; times count played episodes.
    assert fast.summary.table == full.summary.table
    assert fast.summary.per_case == full.summary.per_case
    assert results_table(fast.summary) == results_table(full.summary)
    for p in reused:
        counts = fast.summary.counts[p]
        assert counts.reused_episodes == 2 * len(cases) and counts.episodes == 3 * len(cases)
        assert full.summary.counts[p].reused_episodes is UNSET
        steps = sum(len(r.steps) for r in _records(tmp_path / "reuse").values() if r.policy == p)
        assert counts.decision_times["all"].decisions == steps // 3
    assert fast.summary.counts["random"].reused_episodes is UNSET


@pytest.mark.physics
def test_two_reused_rows_equal_a_full_rerun_on_mujoco(tmp_path):
    easy = [c for c in suite_sample() if c.difficulty == "easy"]
    source = _cases_file(tmp_path, easy)
    _run(source, tmp_path / "reuse", ["dblf", "sdf"], backend="mujoco")
    _run(source, tmp_path / "full", ["dblf", "sdf"], backend="mujoco", reuse=False)
    assert_same_records(tmp_path / "reuse", tmp_path / "full")
    assert len(_marked(tmp_path / "reuse")) == 2 * 2 * len(easy)


def test_online_runs_reuse_the_planner_too(tmp_path):
    """In arrival order (the online protocol) the planner is seed-free as well."""
    source = _cases_file(tmp_path, tiny_cases())
    online = {"protocol": "online", "lookahead": 2}
    fast = _run(source, tmp_path / "reuse", ["plan-fast", "dblf"], **online)
    _run(source, tmp_path / "full", ["plan-fast", "dblf"], reuse=False, **online)
    assert_same_records(tmp_path / "reuse", tmp_path / "full")
    assert fast.reused == 2 * 2 * len(tiny_cases())


def test_a_copy_replays_to_its_record(tmp_path):
    """A copy's actions name shown indices in its own seed's order: stepping them again under
    its seed gives the recorded episode."""
    source = _cases_file(tmp_path, tiny_cases())
    _run(source, tmp_path / "run", ["sdf"])
    cases = {c.episode_id: c for c in tiny_cases()}
    copies = [r for r in _records(tmp_path / "run").values() if r.reused_from_seed is not UNSET]
    assert copies
    for record in copies:
        assert replay_record(cases[record.case_id], record).matches_record


# -- resuming ------------------------------------------------------------------------------


def test_a_run_stopped_between_a_lead_and_its_copies_writes_them_on_resume(tmp_path):
    source = _cases_file(tmp_path, tiny_cases())
    _run(source, tmp_path / "full", ["dblf"], reuse=False)

    def stop_at_first(record):
        raise Interrupt

    with pytest.raises(Interrupt):
        run_bench(
            RunConfig(
                cases=source,
                out=str(tmp_path / "cut"),
                policies=("dblf",),
                seeds=SEEDS,
                backend="geometric",
                workers=1,
                progress=False,
            ),
            on_record=stop_at_first,
            figures=False,
            html=False,
        )
    assert len(_records(tmp_path / "cut")) == 1
    resumed = _run(source, tmp_path / "cut", ["dblf"])
    assert resumed.already_done == 1
    # Its two copies come from the record already there; the other cases play one seed each.
    assert resumed.reused == 2 * len(tiny_cases())
    assert resumed.ran - resumed.reused == len(tiny_cases()) - 1
    assert_same_records(tmp_path / "cut", tmp_path / "full")


def test_copies_without_their_lead_resume_by_playing_the_lead_alone(tmp_path):
    source = _cases_file(tmp_path, tiny_cases())
    _run(source, tmp_path / "full", ["dblf"], reuse=False)
    run_dir = tmp_path / "run"
    _run(source, run_dir, ["dblf"])
    lines = (run_dir / EPISODES_FILE).read_text().splitlines()
    first_case = tiny_cases()[0].episode_id
    kept = [
        line
        for line in lines
        if not (json.loads(line)["case_id"] == first_case and json.loads(line)["seed"] == 0)
    ]
    assert len(kept) == len(lines) - 1
    (run_dir / EPISODES_FILE).write_text("\n".join(kept) + "\n")
    resumed = _run(source, run_dir, ["dblf"])
    assert (resumed.ran, resumed.reused) == (1, 0)
    assert_same_records(run_dir, tmp_path / "full")


def test_a_run_played_without_reuse_resumes_with_it(tmp_path):
    source = _cases_file(tmp_path, tiny_cases())
    _run(source, tmp_path / "full", ["hm"], reuse=False)
    k = 5

    def stop_after_k(record, seen=[]):  # noqa: B006 - counts calls within this test
        seen.append(record)
        if len(seen) == k:
            raise Interrupt

    with pytest.raises(Interrupt):
        run_bench(
            RunConfig(
                cases=source,
                out=str(tmp_path / "run"),
                policies=("hm",),
                seeds=SEEDS,
                backend="geometric",
                workers=1,
                progress=False,
                reuse=False,
            ),
            on_record=stop_after_k,
            figures=False,
            html=False,
        )
    resumed = _run(source, tmp_path / "run", ["hm"])  # --no-reuse is not part of the identity
    assert resumed.already_done == k and resumed.reused > 0
    assert_same_records(tmp_path / "run", tmp_path / "full")


# -- errors are never copied ---------------------------------------------------------------

FAILS_ON_LEAD = "test-fails-on-seed-0"


class FailsOnSeedZero:
    """Claims seed freedom; fails its seed-0 episode (as a crash of the played episode would)."""

    name = FAILS_ON_LEAD

    def reset(self, case: Case, seed: int) -> None:
        self._fail = seed == 0

    def act(self, observation: Observation) -> Action:
        if self._fail:
            raise RuntimeError("deliberate failure of the played seed")
        return Action(0, 0, 0, 0)


@pytest.fixture
def fails_on_lead():
    register_policy(FAILS_ON_LEAD)(declare_seed_free(seed_free_always)(lambda: FailsOnSeedZero()))
    try:
        yield FAILS_ON_LEAD
    finally:
        unregister_policy(FAILS_ON_LEAD)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failed_lead_is_not_copied_and_its_seeds_are_played(tmp_path, fails_on_lead, workers):
    source = _cases_file(tmp_path, tiny_cases())
    out = _run(source, tmp_path / "run", [fails_on_lead, "dblf"], workers=workers)
    records = _records(tmp_path / "run")
    mine = [r for r in records.values() if r.policy == fails_on_lead]
    assert sorted(r.status for r in mine) == ["error"] * 4 + ["ok"] * 8
    assert all(r.seed == 0 for r in mine if r.status == "error")
    assert not any(r.reused_from_seed is not UNSET for r in mine if isinstance(r, EpisodeOk))
    assert out.reused == 2 * len(tiny_cases())  # dblf's copies only
    assert out.ran == out.planned and out.failed == 4


# -- reports, comparisons, the terminal and the flag ---------------------------------------


def test_reports_and_comparisons_read_copies_as_any_record(tmp_path):
    source = _cases_file(tmp_path, tiny_cases())
    live = _run(source, tmp_path / "reuse", ["dblf", "random"])
    _run(source, tmp_path / "full", ["dblf", "random"], reuse=False)
    (tmp_path / "reuse" / "summary.json").unlink()
    summary, table_md, _ = build_report(tmp_path / "reuse", figures=False)
    assert summary == live.summary and table_md == live.table_md
    assert "Reused: 8 of 24 episodes (DBLF 8)" in table_md
    assert "--no-reuse plays every seed" in terminal_text(summary)
    # Same per-case scores, so the same intervals.
    intervals = [json.loads((tmp_path / d / "summary.json").read_text()) for d in ("reuse", "full")]
    assert intervals[0]["intervals"] == intervals[1]["intervals"]
    both = compare_markdown([tmp_path / "reuse", tmp_path / "full"], ["reuse", "full"])
    assert "reuse: DBLF" in both and "full: DBLF" in both


def test_no_reuse_flag_and_config(tmp_path, capsys):
    source = _cases_file(tmp_path, tiny_cases()[:2])

    def argv(out: str, *extra: str) -> list[str]:
        flags = ["--backend", "geometric", "--policies", "dblf", "--workers", "1"]
        flags += ["--no-progress", "--no-figures", "--no-html"]
        return ["bench", "--cases", source, *flags, "--out", str(tmp_path / out), *extra]

    assert main(argv("played", "--no-reuse")) == 0
    assert "6 episodes run in" in capsys.readouterr().err
    saved = json.loads((tmp_path / "played" / "config.json").read_text())
    assert saved["execution"]["reuse"] is False
    assert main(argv("reused")) == 0
    assert "6 episodes run (4 copied from another seed) in" in capsys.readouterr().err
    assert_same_records(tmp_path / "reused", tmp_path / "played")


@pytest.mark.parametrize(
    ("fields", "mode"),
    [
        ({}, "shuffled"),
        ({"protocol": "offline"}, "shuffled"),
        ({"protocol": "online"}, "arrival"),
        ({"reuse": False}, None),
        ({"seeds": (3,)}, None),
        ({"observation": "perceived", "sides": "longer-first"}, None),
        ({"execution": "noisy"}, None),
    ],
)
def test_reuse_mode(fields, mode):
    assert reuse_mode(RunConfig(**fields)) == mode


def test_perceived_runs_play_every_seed(tmp_path):
    source = _cases_file(tmp_path, tiny_cases()[:1])
    out = _run(source, tmp_path / "run", ["dblf"], observation="perceived", sides="longer-first")
    assert out.reused == 0 and _marked(tmp_path / "run") == {}
