"""``packlab policies``: every policy a bench can run, its options with their defaults, and what
it needs; one policy in detail; JSON; an unknown name is a one-line error with exit code 2."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from importlib.metadata import entry_points

import pytest

from packlab.cli.main import main
from packlab.cli.policies_run import BUILTINS, describe, describe_all
from packlab.policies import registry
from packlab.policies.plan.policy import FAST_BUDGET
from packlab.policies.registry import ENTRY_POINT_GROUP, register_policy, unregister_policy

#: Modules that neither the help nor the listing may load (the listing makes every policy,
#: which must open no model runtime but ONNX Runtime's package metadata, and never torch).
HEAVY_FOR_HELP = ("torch", "mujoco", "scipy", "onnxruntime", "packlab.policies.plan")
_PROBE = """
import contextlib, io, json, sys
from packlab.cli.main import main
with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
    main(json.loads(sys.argv[1]))
print(json.dumps(sorted(sys.modules)))
"""


def _modules_after(argv: list[str]) -> set[str]:
    done = subprocess.run(
        [sys.executable, "-c", _PROBE, json.dumps(argv)],
        capture_output=True,
        text=True,
        check=True,
    )
    return set(json.loads(done.stdout.splitlines()[-1]))


def _loaded(modules: set[str], names: tuple[str, ...]) -> list[str]:
    return sorted(m for m in modules if any(m == n or m.startswith(n + ".") for n in names))


def _json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict:
    assert main(["policies", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _options(policy: dict) -> dict:
    return {o["key"]: o["default"] for o in policy["options"]}


def test_help_loads_no_policy_family_and_the_listing_no_torch():
    assert _loaded(_modules_after(["policies", "--help"]), HEAVY_FOR_HELP) == []
    assert _loaded(_modules_after(["policies"]), ("torch", "transformers")) == []


def test_listing_names_every_policy_with_its_options(capsys):
    assert main(["policies"]) == 0
    out = capsys.readouterr().out
    listed = {line.split()[0] for line in out.splitlines() if line and not line[0].isspace()}
    assert {"dblf", "plan-fast", "vlm", "irbpp"} <= listed
    assert "options: tie_break=larger_volume overflow=place" in out
    assert "needs: core install" in out


def test_json_lists_every_declared_policy(capsys):
    data = _json(capsys)
    assert data["format"] == "packlab-policies-1"
    names = [p["name"] for p in data["policies"]]
    declared = {ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)}
    assert {"dblf", "plan-fast", "vlm", "irbpp"} <= set(names) == declared
    rows = {p["name"]: p["default_row"] for p in data["policies"]}
    assert rows["plan-fast"] and rows["irbpp"] and not rows["plan"]


def test_one_policy_shows_its_options_with_defaults(capsys):
    assert main(["policies", "dblf"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("dblf: Deepest-Bottom-Left-Fill")
    assert "options (--policy-arg dblf:KEY=VALUE), default:" in out
    assert "tie_break  larger_volume" in out and "overflow   place" in out

    (fast,) = _json(capsys, "plan-fast")["policies"]
    assert fast["source"] == "packlab" and fast["extra"] is None
    options = _options(fast)
    assert {k: options[k] for k in FAST_BUDGET} == FAST_BUDGET  # the factory's own defaults
    assert options["overflow"] == "score" and options["complete"] is True

    (irbpp,) = _json(capsys, "irbpp")["policies"]
    assert _options(irbpp)["runtime"] == "onnx" and irbpp["extra"] == "rl"
    assert _options(irbpp)["model"].endswith("models/irbpp")


def test_unknown_name_exits_2_naming_the_nearest(capsys):
    assert main(["policies", "dbfl"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("packlab policies: error: no policy 'dbfl'")
    assert "did you mean 'dblf'?" in err and len(err.splitlines()) == 1


def test_every_builtin_has_a_description_and_readable_defaults():
    declared = {
        ep.name for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.dist.name == "packlab"
    }
    assert set(BUILTINS) == declared, "describe a new built-in in cli/policies_run.BUILTINS"
    for info in describe_all():
        assert info.error == "", (info.name, info.error)
        unread = [o.key for o in info.options if not o.known]
        assert unread == [], f"{info.name}: no attribute path for {unread} (Builtin.paths)"


_PLUGIN_SOURCE = '''\
from packlab.core.types import Action


class CornerPolicy:
    """Every box into the corner cell."""

    name = "test-corner"

    def __init__(self, rotation: int = 0, label: str | None = None) -> None:
        self.rotation = rotation

    def reset(self, case, seed):
        pass

    def act(self, observation):
        return Action(object_id=0, rotation=self.rotation, x=0, y=0)


def make(**kwargs):
    return CornerPolicy(**kwargs)
'''


def test_another_package_shows_its_class_options(tmp_path, monkeypatch, capsys):
    site = tmp_path / "site"
    dist_info = site / "corner_pkg-0.1.dist-info"
    dist_info.mkdir(parents=True)
    (dist_info / "METADATA").write_text("Metadata-Version: 2.1\nName: corner-pkg\nVersion: 0.1\n")
    (dist_info / "entry_points.txt").write_text(
        "[packlab.policies]\ntest-corner = corner_mod:make\n"
    )
    (site / "corner_mod.py").write_text(textwrap.dedent(_PLUGIN_SOURCE))
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(registry, "_LOADED", {})  # the factory is not kept past this test

    (corner,) = _json(capsys, "test-corner")["policies"]
    assert corner["source"] == "corner-pkg" and corner["factory"] == "corner_mod:make"
    assert corner["description"] == "Every box into the corner cell."
    assert _options(corner) == {"rotation": 0, "label": None}
    assert main(["policies"]) == 0
    assert "test-corner" in capsys.readouterr().out
    monkeypatch.delitem(sys.modules, "corner_mod")


def test_a_package_that_does_not_load_is_one_entry_not_a_crash(tmp_path, monkeypatch, capsys):
    dist_info = tmp_path / "broken_pkg-0.1.dist-info"
    dist_info.mkdir()
    (dist_info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-pkg\nVersion: 0.1\n")
    (dist_info / "entry_points.txt").write_text(
        "[packlab.policies]\ntest-broken = no_such_mod:make\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(["policies"]) == 0
    out = capsys.readouterr().out
    assert "test-broken     (not loadable)" in out
    assert "cannot load no_such_mod:make: ModuleNotFoundError" in out


def test_a_policy_registered_at_run_time_is_described():
    @register_policy("test-runtime")
    def make_runtime(depth: int = 3):
        """A policy made in this process."""
        return object()

    try:
        info = describe("test-runtime")
    finally:
        unregister_policy("test-runtime")
    assert info.source == "run time" and info.description == "A policy made in this process."
    assert [(o.key, o.default) for o in info.options] == [("depth", 3)]
