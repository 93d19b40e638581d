"""The oracle's answers as a served model: a serving path that loses nothing scores 1.0."""

from __future__ import annotations

import pytest

from packlab.bench.records import read_record_file
from packlab.cases.load import load_cases
from packlab.cli.main import main
from packlab.core.errors import EXIT_OK
from packlab.sim.env import demo_cases_path
from packlab.vlm.serve.oracle_answers import UNKNOWN_REQUEST, oracle_model, request_key
from packlab.vlm.serve.server import serve


@pytest.mark.parametrize("prompt", ["reference", "packlab"])
def test_the_oracle_served_through_the_endpoint_scores_one(tmp_path, capsys, prompt):
    cases = load_cases(demo_cases_path())
    model = oracle_model(cases, [3], {"prompt": prompt})
    with serve(model) as server:
        argv = ["bench", "--cases", str(demo_cases_path()), "--backend", "geometric"]
        argv += ["--policies", "endpoint", "--seeds", "3", "--workers", "1"]
        argv += ["--out", str(tmp_path / "run"), "--no-progress", "--no-figures", "--no-html"]
        argv += ["--policy-arg", f"endpoint:base_url={server.base_url}"]
        argv += ["--policy-arg", f"endpoint:prompt={prompt}"]
        argv += ["--policy-arg", "endpoint:tag_requests=true"]
        code = main(argv)
    assert code == EXIT_OK, capsys.readouterr().err
    records = list(read_record_file(tmp_path / "run" / "episodes.jsonl").records)
    assert len(records) == len(cases)
    assert [r.metrics.overall for r in records] == pytest.approx([1.0] * len(cases))
    assert model.unknown == 0
    assert model.requests == sum(len(r.steps) for r in records)


def test_a_request_it_did_not_record_gets_a_refusal_that_does_not_parse():
    model = oracle_model(load_cases(demo_cases_path())[:1], [0], {"prompt": "reference"})
    reply = model({"messages": [{"role": "user", "content": "anything"}]})
    assert reply.content == UNKNOWN_REQUEST
    assert (model.requests, model.unknown) == (1, 1)


def test_the_key_reads_texts_only():
    image = {"type": "image_url", "image_url": {"url": "data:image/png;base64,AAAA"}}
    other = {"type": "image_url", "image_url": {"url": "data:image/png;base64,BBBB"}}
    text = {"type": "text", "text": "buffer: [1, 2]"}

    def body(*messages):
        return {"messages": list(messages)}

    system = {"role": "system", "content": "container"}
    a = body(system, {"role": "user", "content": [image, text]})
    b = body(
        system,
        {"role": "user", "content": [other, text]},
        {"role": "assistant", "content": "{}"},
    )
    c = body(system, {"role": "user", "content": [image, {"type": "text", "text": "buffer: [2]"}]})
    assert request_key(a) == request_key(b)  # images and answers follow from the texts
    assert request_key(a) != request_key(c)
