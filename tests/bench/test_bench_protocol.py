"""``packlab bench --protocol buffer|online --lookahead k``: config round trip, the
resume and compare refusals, and space utilization in the summary and table."""

import json

import msgspec
import pytest
from bench_helpers import run_tiny, tiny_cases

from packlab.bench.compare import merge_summaries
from packlab.bench.config import RunConfig, check_resumable, default_out, resolve
from packlab.bench.records import read_records
from packlab.bench.report import container_volume_mm3
from packlab.core.errors import ConfigError
from packlab.core.packing_protocol import PackingProtocol, saved_protocol
from packlab.core.records import EpisodeOk
from packlab.metrics import AVERAGE


def test_config_round_trip_records_protocol_and_lookahead(tiny_suite, tmp_path):
    online = resolve(
        RunConfig(cases=str(tiny_suite), backend="geometric", protocol="online", lookahead=2)
    )
    saved = json.loads(json.dumps(online.to_json()))
    assert saved["protocol"] == "online" and saved["lookahead"] == 2
    assert saved_protocol(saved) == PackingProtocol("online", 2)
    assert online.episode_modes().protocol == PackingProtocol("online", 2)
    assert "oracle" not in online.policies  # its plan ignores arrival order
    assert default_out("s", online.config).name == "bench-s-online-k2"
    buffer = resolve(RunConfig(cases=str(tiny_suite), backend="geometric"))
    assert buffer.to_json()["protocol"] == "buffer" and "lookahead" not in buffer.to_json()
    # A config.json written before the choice existed reads as buffer and resumes as one.
    older = {k: v for k, v in buffer.to_json().items() if k != "protocol"}
    check_resumable(older, buffer.to_json(), tmp_path)


def test_lookahead_without_online_and_online_perceived_are_refused(tiny_suite):
    with pytest.raises(ConfigError, match="only used with --protocol online"):
        RunConfig(cases=str(tiny_suite), lookahead=3)
    with pytest.raises(ConfigError, match="exact observation only"):
        RunConfig(cases=str(tiny_suite), protocol="online", observation="perceived")


def test_resume_with_another_protocol_is_refused_in_one_line(tiny_suite, tmp_path):
    out = tmp_path / "run"
    run_tiny(tiny_suite, out, protocol="online")
    for other in ({}, {"protocol": "online", "lookahead": 2}):
        with pytest.raises(ConfigError) as info:
            run_tiny(tiny_suite, out, **other)
        message = str(info.value)
        assert "\n" not in message and "protocol online (BPP-1) there" in message
        assert "--protocol online --lookahead 1" in message


def test_online_run_scores_utilization_up_to_the_stop(tiny_suite, tmp_path):
    outcome = run_tiny(tiny_suite, tmp_path / "online", protocol="online", lookahead=2)
    records = [r for r in read_records(tmp_path / "online" / "episodes.jsonl")]
    assert records and all(isinstance(r, EpisodeOk) for r in records)
    by_id = {c.episode_id: c for c in tiny_cases()}
    for r in records:
        assert isinstance(r, EpisodeOk)
        volume = container_volume_mm3(by_id[r.case_id])
        assert r.metrics.space_utilization == pytest.approx(r.metrics.inside_volume_mm3 / volume)
        processed = len(r.steps) + r.metrics.unprocessed
        assert processed == r.n_objects
    cells = outcome.summary.table["dblf"][AVERAGE]
    assert cells.space_utilization.mean is not None
    assert outcome.summary.protocol == "online" and outcome.summary.lookahead == 2
    assert "### Space utilization" in outcome.table_md
    assert "protocol online (BPP-2)" in outcome.table_md


def test_buffer_run_reports_utilization_without_changing_its_records(tiny_suite, tmp_path):
    outcome = run_tiny(tiny_suite, tmp_path / "buffer")
    records = read_records(tmp_path / "buffer" / "episodes.jsonl")
    text = (tmp_path / "buffer" / "episodes.jsonl").read_text()
    assert "space_utilization" not in text and "stopped_at" not in text
    by_id = {c.episode_id: c for c in tiny_cases()}
    case_cells = outcome.summary.per_case["dblf"]
    for r in records:
        assert isinstance(r, EpisodeOk)
        want = r.metrics.inside_volume_mm3 / container_volume_mm3(by_id[r.case_id])
        assert case_cells[r.case_id].space_utilization.mean == pytest.approx(want)
    summary = json.loads((tmp_path / "buffer" / "summary.json").read_text())
    assert summary["intervals"]["policies"]["dblf"]["cells"][AVERAGE]["space_utilization"]
    assert "### Space utilization" in outcome.table_md
    assert "protocol online" not in outcome.table_md


def test_compare_labels_rows_of_different_protocols_with_their_protocol(tiny_suite, tmp_path):
    """The same cases under the buffer, online and offline protocols in one table: what seeing
    only part of the sequence costs (the online gap); each row names its protocol."""
    a = run_tiny(tiny_suite, tmp_path / "a").summary
    b = run_tiny(tiny_suite, tmp_path / "b", protocol="online").summary
    d = run_tiny(tiny_suite, tmp_path / "d", protocol="offline").summary
    merged = merge_summaries([a, b, d], ["a", "b", "d"])
    assert merged.policies == (
        "a (protocol buffer)",
        "b (protocol online (BPP-1))",
        "d (protocol offline (every box shown))",
    )
    assert merged.protocol is msgspec.UNSET
    c = run_tiny(tiny_suite, tmp_path / "c", protocol="online", policies=("sdf",)).summary
    same = merge_summaries([b, c], ["b", "c"])
    assert same.protocol == "online" and same.policies == ("b", "c")


def test_an_online_record_replays_only_under_its_own_protocol(tiny_suite, tmp_path):
    """A recorded object index refers to the buffer the run's protocol showed: replays (bench
    replay, viz episode/rerun) read the protocol from config.json and step under it."""
    from packlab.bench.replay import replay_record
    from packlab.cases.load import load_cases
    from packlab.core.packing_protocol import BUFFER

    out = tmp_path / "online"
    run_tiny(tiny_suite, out, protocol="online", lookahead=3, policies=("sdf",))
    saved = json.loads((out / "config.json").read_text())
    cases = {c.episode_id: c for c in load_cases(tiny_suite)}
    records = [r for r in read_records(out / "episodes.jsonl") if isinstance(r, EpisodeOk)]
    assert records
    protocol = saved_protocol(saved)
    assert all(
        replay_record(cases[r.case_id], r, protocol=protocol).matches_record for r in records
    )
    as_buffer = [replay_record(cases[r.case_id], r, protocol=BUFFER) for r in records]
    assert not all(rep.matches_record for rep in as_buffer)  # the shuffled view differs
