"""``packlab cell``: the OpenAPI document, the serve options, and a clear line without the
extra."""

from __future__ import annotations

import importlib.util
import json

from packlab.cli.main import build_parser, main


def test_schema_writes_the_openapi_document(tmp_path, capsys):
    out = tmp_path / "openapi.json"
    assert main(["cell", "schema", "--out", str(out)]) == 0
    assert capsys.readouterr().out == f"wrote {out}\n"
    document = json.loads(out.read_text(encoding="utf-8"))
    assert set(document["paths"]) == {
        "/v1/sessions",
        "/v1/sessions/{session_id}/step",
        "/v1/sessions/{session_id}",
        "/v1/plan",
        "/v1/health",
        "/v1/policies",
    }
    schemas = document["components"]["schemas"]
    for name in ("SessionRequest", "StepRequest", "PlanRequest", "StepAnswer", "ErrorAnswer"):
        assert name in schemas
    step = document["paths"]["/v1/sessions/{session_id}/step"]["post"]["responses"]
    assert {"200", "404", "413", "422"} <= set(step)
    assert main(["cell", "schema"]) == 0
    assert json.loads(capsys.readouterr().out) == document


def test_serve_options_and_their_checks(capsys):
    args = build_parser().parse_args(["cell", "serve", "--workers", "2", "--port", "9000"])
    assert (args.workers, args.port, args.policy) == (2, 9000, "plan-fast")
    assert main(["cell", "serve", "--max-sessions", "0"]) == 2
    assert "max_sessions = 0: need at least 1" in capsys.readouterr().err


def test_without_the_extra_the_command_says_how_to_install_it(monkeypatch, capsys):
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "uvicorn" else real(name, *a)
    )
    assert main(["cell", "schema"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        "packlab cell: error: packlab cell needs the cell extra (uvicorn not installed): "
        'pip install -e ".[cell]"'
    )


def test_an_unknown_default_policy_stops_the_server_before_it_starts(capsys):
    assert main(["cell", "serve", "--policy", "nope", "--port", "1"]) == 2
    assert "policy = 'nope': unknown" in capsys.readouterr().err
