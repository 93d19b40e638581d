"""A third-party policy package plugs in through the ``packlab.policies`` entry-point group.

The package is "installed" without pip: a ``*.dist-info`` directory (METADATA and
entry_points.txt) and the module are written into a directory put on ``sys.path``, which is all
``importlib.metadata`` looks at. Nothing in packlab names the package.
"""

from __future__ import annotations

import json
import sys
import textwrap

import pytest
from layered_cases import make_layered_case

from packlab.bench.config import RunConfig
from packlab.bench.runner import run_bench
from packlab.cases import save_cases
from packlab.policies import available_policies, make_policy
from packlab.sim.episode import run_episode

PLUGIN_MODULE = "my_policy_pkg"
PLUGIN_POLICY = "my-corner"

_MODULE_SOURCE = '''\
"""A user's own policy: the first shown object into the corner cell (0, 0)."""

from packlab.core.types import Action


class CornerPolicy:
    name = "my-corner"

    def __init__(self, rotation: int = 0) -> None:
        self.rotation = rotation

    def reset(self, case, seed: int) -> None:
        pass

    def act(self, observation) -> Action:
        return Action(object_id=0, rotation=self.rotation, x=0, y=0)


def make(**kwargs):
    return CornerPolicy(**kwargs)
'''


@pytest.fixture
def installed_plugin(tmp_path, monkeypatch):
    """``fake_pkg 0.1`` (module ``my_policy_pkg``) installed into a directory on sys.path."""
    site = tmp_path / "site"
    dist_info = site / "fake_pkg-0.1.dist-info"
    dist_info.mkdir(parents=True)
    (dist_info / "METADATA").write_text("Metadata-Version: 2.1\nName: fake-pkg\nVersion: 0.1\n")
    (dist_info / "entry_points.txt").write_text(
        f"[packlab.policies]\n{PLUGIN_POLICY} = {PLUGIN_MODULE}:make\n"
    )
    (site / f"{PLUGIN_MODULE}.py").write_text(textwrap.dedent(_MODULE_SOURCE))
    monkeypatch.syspath_prepend(str(site))  # also invalidates the import caches
    yield site
    sys.modules.pop(PLUGIN_MODULE, None)


def test_plugin_is_not_there_without_its_distribution():
    assert PLUGIN_POLICY not in available_policies()


def test_plugin_policy_is_listed_made_and_runs_an_episode(installed_plugin):
    assert PLUGIN_POLICY in available_policies()
    assert PLUGIN_MODULE not in sys.modules  # listing a policy imports nothing
    policy = make_policy(PLUGIN_POLICY, rotation=1)
    assert type(policy).__module__ == PLUGIN_MODULE and policy.rotation == 1

    case = make_layered_case(3, cells=(12, 10), layer_heights_mm=(100, 80), pieces=3)
    result = run_episode(case, make_policy(PLUGIN_POLICY), seed=0, backend="geometric")
    assert result.policy == PLUGIN_POLICY
    assert len(result.steps) == len(case.objects)
    assert all(s.valid for s in result.steps)  # the corner cell always takes the footprint
    assert 0.0 < result.metrics.success_ratio <= 1.0


def test_plugin_policy_runs_in_the_bench(installed_plugin, tmp_path):
    cases_path = tmp_path / "cases.jsonl"
    save_cases(
        [
            make_layered_case(s, cells=(12, 10), layer_heights_mm=(100, 80), pieces=3)
            for s in range(2)
        ],
        cases_path,
    )
    config = RunConfig(
        cases=str(cases_path),
        policies=(PLUGIN_POLICY,),
        seeds=(0,),
        backend="geometric",
        workers=1,
        progress=False,
        out=str(tmp_path / "run"),
    )
    outcome = run_bench(config, figures=False)
    assert outcome.ran == 2 and outcome.failed == 0
    lines = (outcome.run_dir / "episodes.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]  # the file format, not a reader's types
    assert {r["policy"] for r in records} == {PLUGIN_POLICY}
    assert all(r["status"] == "ok" for r in records)


def test_a_loaded_factory_is_reused_without_scanning_the_installed_packages(monkeypatch):
    """The bench makes a policy per episode; reading every distribution's metadata each time
    cost more than a whole geometric episode."""
    from packlab.policies import registry

    make_policy("dblf")
    monkeypatch.setattr(registry, "entry_points", lambda **kw: pytest.fail("scanned again"))
    assert make_policy("dblf") is not None
