"""The runner: records per episode, resume without duplicates, failures recorded, report == live."""

from __future__ import annotations

import json

import pytest

from packlab.bench.config import RunConfig
from packlab.bench.records import read_record_file, record_key
from packlab.bench.report import build_report
from packlab.bench.runner import run_bench
from packlab.bench.table import results_table
from packlab.core.errors import ConfigError
from packlab.core.records import RUN_FORMAT

POLICIES = ("dblf", "ffp", "random", "oracle")


def _cfg(cases, out, **kw):
    base = {
        "cases": str(cases),
        "out": str(out),
        "backend": "geometric",
        "policies": POLICIES,
        "seeds": (0, 1),
        "workers": 1,
        "progress": False,
    }
    return RunConfig(**{**base, **kw})


def _keys(run_dir):
    return [record_key(r) for r in read_record_file(run_dir / "episodes.jsonl").records]


class Interrupt(KeyboardInterrupt):
    pass


def test_full_run_writes_every_record_and_outputs(tiny_suite, tmp_path):
    out = run_bench(_cfg(tiny_suite, tmp_path / "run"), figures=False)
    assert out.planned == out.ran == 4 * len(POLICIES) * 2 and out.failed == 0
    keys = _keys(tmp_path / "run")
    assert len(keys) == len(set(keys)) == out.planned
    assert json.loads((tmp_path / "run" / "config.json").read_text())["policies"] == list(POLICIES)
    line = json.loads((tmp_path / "run" / "episodes.jsonl").read_text().splitlines()[0])
    assert list(line)[:2] == ["status", "format"] and line["format"] == RUN_FORMAT
    assert {
        "status",
        "case_id",
        "seed",
        "policy",
        "backend",
        "difficulty",
        "metrics",
        "steps",
        "final_poses",
        "timing",
    } <= set(line)
    # Records stay compact: no heightmaps, no per-step history images.
    assert "heightmap" not in json.dumps(line)
    assert out.summary.table["oracle"]["average"].overall.mean == pytest.approx(1.0)
    for name in ("DBLF", "FFP", "Random", "Oracle"):
        assert name in out.table_md


@pytest.mark.parametrize("workers", [1, 2])
def test_interrupted_run_resumes_without_redoing_or_duplicating(tiny_suite, tmp_path, workers):
    reference = run_bench(_cfg(tiny_suite, tmp_path / "ref"), figures=False)
    run_dir = tmp_path / "run"
    k = 5

    def stop_after_k(record, seen=[]):  # noqa: B006 - counts calls within this test
        seen.append(record)
        if len(seen) == k:
            raise Interrupt

    with pytest.raises(Interrupt):
        run_bench(_cfg(tiny_suite, run_dir, workers=workers), on_record=stop_after_k, figures=False)
    assert len(_keys(run_dir)) == k
    with open(run_dir / "episodes.jsonl", "a") as fh:  # and a kill mid-write on top
        fh.write('{"status":"ok","case_id":"eas')
    resumed = run_bench(_cfg(tiny_suite, run_dir, workers=workers), figures=False)
    assert resumed.already_done == k and resumed.ran == reference.planned - k
    keys = _keys(run_dir)
    assert len(keys) == len(set(keys)) == reference.planned
    # Same results (the run-details table holds timings, which differ between any two runs).
    assert resumed.summary.table == reference.summary.table
    assert results_table(resumed.summary) == results_table(reference.summary)
    again = run_bench(_cfg(tiny_suite, run_dir, workers=workers), figures=False)
    assert again.ran == 0 and again.table_md == resumed.table_md


def test_pool_and_serial_give_the_same_numbers(tiny_suite, tmp_path):
    serial = run_bench(_cfg(tiny_suite, tmp_path / "a", workers=1), figures=False)
    pooled = run_bench(_cfg(tiny_suite, tmp_path / "b", workers=2), figures=False)
    assert serial.summary.table == pooled.summary.table


def test_a_crashing_policy_is_recorded_and_the_rest_goes_on(tiny_suite, tmp_path, crash_policy):
    run_dir = tmp_path / "run"
    out = run_bench(
        _cfg(tiny_suite, run_dir, policies=("dblf", crash_policy), workers=2), figures=False
    )
    records = read_record_file(run_dir / "episodes.jsonl").records
    failed = [r for r in records if r.status == "error"]
    assert out.failed == len(failed) == 2 * 2  # two hard cases x two seeds
    assert all(r.policy == crash_policy and r.difficulty == "hard" for r in failed)
    assert all("deliberate failure" in r.error and "Traceback" in r.traceback for r in failed)
    assert sum(r.status == "ok" for r in records) == out.planned - 4
    assert f"| {crash_policy} * |" in out.table_md
    # A rerun does not retry recorded failures unless asked to.
    assert (
        run_bench(_cfg(tiny_suite, run_dir, policies=("dblf", crash_policy)), figures=False).ran
        == 0
    )
    retry = run_bench(
        _cfg(tiny_suite, run_dir, policies=("dblf", crash_policy), retry_errors=True), figures=False
    )
    assert retry.ran == 4 and retry.failed == 4


def test_report_from_records_alone_equals_the_live_table(tiny_suite, tmp_path):
    live = run_bench(_cfg(tiny_suite, tmp_path / "run", workers=2), figures=False)
    (tmp_path / "run" / "table.md").unlink()
    (tmp_path / "run" / "summary.json").unlink()
    summary, table_md, _ = build_report(tmp_path / "run", figures=False)
    assert table_md == live.table_md
    assert summary == live.summary
    assert (tmp_path / "run" / "table.md").read_text() == live.table_md


def test_a_different_configuration_cannot_reuse_a_run_directory(tiny_suite, tmp_path):
    run_bench(_cfg(tiny_suite, tmp_path / "run"), figures=False)
    with pytest.raises(ConfigError, match="field 'seeds'"):
        run_bench(_cfg(tiny_suite, tmp_path / "run", seeds=(0, 1, 2)), figures=False)
    # ... but how it is executed may change.
    assert run_bench(_cfg(tiny_suite, tmp_path / "run", workers=2), figures=False).ran == 0


def test_two_runs_cannot_write_one_directory_at_once(tiny_suite, tmp_path):
    from packlab.bench.runner import RunLock

    with (
        RunLock(tmp_path / "run"),
        pytest.raises(ConfigError, match="another bench run .* is writing there"),
    ):
        run_bench(_cfg(tiny_suite, tmp_path / "run"), figures=False)
    assert run_bench(_cfg(tiny_suite, tmp_path / "run"), figures=False).ran > 0


def test_a_policy_that_cannot_be_built_fails_before_any_work(tiny_suite, tmp_path):
    from packlab.policies.registry import _RUNTIME as _FACTORIES
    from packlab.policies.registry import register_policy

    def broken():
        raise ImportError("needs an extra")

    register_policy("test-broken")(broken)
    try:
        with pytest.raises(ConfigError, match="'test-broken': cannot be created"):
            run_bench(_cfg(tiny_suite, tmp_path / "run", policies=("test-broken",)), figures=False)
    finally:
        _FACTORIES.pop("test-broken", None)
    assert not (tmp_path / "run" / "episodes.jsonl").exists()


@pytest.mark.slow
def test_ray_executor_gives_the_same_numbers(tiny_suite, tmp_path, ray_cluster):
    local = run_bench(_cfg(tiny_suite, tmp_path / "a", workers=1), figures=False)
    remote = run_bench(_cfg(tiny_suite, tmp_path / "b", workers=2, executor="ray"), figures=False)
    assert remote.summary.table == local.summary.table


def test_policy_arguments_reach_the_factory_in_every_worker(tiny_suite, tmp_path):
    from packlab.core.types import Action
    from packlab.policies.registry import _RUNTIME as _FACTORIES
    from packlab.policies.registry import register_policy

    class Corner:
        name = "test-param"

        def __init__(self, rotation):
            self.rotation = rotation

        def reset(self, case, seed):
            pass

        def act(self, observation):
            return Action(0, self.rotation, 0, 0)

    register_policy("test-param")(lambda rotation: Corner(rotation))
    try:
        cfg = _cfg(
            tiny_suite,
            tmp_path / "run",
            policies=("test-param",),
            workers=2,
            policy_args=(("test-param", "rotation", 1),),
        )
        out = run_bench(cfg, figures=False)
    finally:
        _FACTORIES.pop("test-param", None)
    records = read_record_file(tmp_path / "run" / "episodes.jsonl").records
    assert out.failed == 0 and all(s.action.rotation == 1 for r in records for s in r.steps)
    assert json.loads((tmp_path / "run" / "config.json").read_text())["policy_args"] == {
        "test-param": {"rotation": 1}
    }


@pytest.mark.slow
def test_a_killed_cli_run_resumes_to_exactly_the_planned_records(tiny_suite, tmp_path):
    """The real thing: SIGKILL the whole process group mid-run, then rerun the same command."""
    import os
    import signal
    import subprocess
    import sys
    import time

    run_dir = tmp_path / "run"
    argv = [
        sys.executable,
        "-m",
        "packlab.cli.main",
        "bench",
        "--cases",
        str(tiny_suite),
        "--backend",
        "geometric",
        "--policies",
        "dblf,random",
        "--seeds",
        "0-199",
        "--workers",
        "2",
        "--out",
        str(run_dir),
        "--no-progress",
        "--no-figures",
    ]
    planned = 4 * 2 * 200
    proc = subprocess.Popen(
        argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    episodes = run_dir / "episodes.jsonl"
    deadline = time.time() + 60
    while time.time() < deadline and (
        not episodes.exists() or episodes.read_bytes().count(b"\n") < 100
    ):
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    partial = len(read_record_file(episodes).records)
    assert 100 <= partial < planned
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    keys = _keys(run_dir)
    assert len(keys) == len(set(keys)) == planned
