"""What ``packlab bench`` checks from its flags alone, before it imports the engine, the reports
and the policies (2-3.5 s of MuJoCo, matplotlib and plotly) or writes anything.

``RunConfig`` itself checks numbers, seeds, choices and policy names (the registry's entry-point
names, no policy imported); this adds what needs the file system or the policies' option lists:
the case source, the ``--policy-arg`` keys, values and model directories
(:mod:`packlab.cli.policy_options`) and ``--out``. Resolving the run later checks the rest
(difficulties present in the cases, physics fields) and the runner builds each policy once
before the first episode, still before a record is written.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from packlab.bench.options import DEFAULT_POLICIES, RunConfig, check_out_dir
from packlab.cli.policy_options import check_policy_args
from packlab.core.choices import did_you_mean
from packlab.core.errors import ConfigError

#: Suffix of a bundled suite's checksum file (packlab/data/suites/NAME.sha256), one per suite.
SUITE_DIGEST_SUFFIX = ".sha256"


def bundled_suites() -> list[str]:
    """The suite names shipped in the package, read from file names (``packlab.bench.suites``
    loads them; importing it costs the data engine)."""
    folder = resources.files("packlab").joinpath("data", "suites")
    return sorted(
        p.name.removesuffix(SUITE_DIGEST_SUFFIX)
        for p in folder.iterdir()
        if p.name.endswith(SUITE_DIGEST_SUFFIX)
    )


def check_cases(cases: str) -> None:
    """A bundled suite name or an existing path; else one line with the nearest suite name."""
    suites = bundled_suites()
    if cases in suites or Path(cases).exists():
        return
    raise ConfigError(
        f"cases = {cases!r}: no such file or directory, nor a bundled suite"
        f"{did_you_mean(cases, suites)}; suites: {', '.join(suites)}"
    )


def check_policy_arg_targets(config: RunConfig) -> None:
    """Each ``--policy-arg`` names a policy this run plays (the default list when no
    ``--policies``: RunConfig checks the explicit list itself)."""
    if config.policies:
        return
    for name, key, _ in config.policy_args:
        if name not in DEFAULT_POLICIES:
            raise ConfigError(
                f"policy-arg {name}:{key}: policy {name!r} is not among the policies to run"
                f"{did_you_mean(name, DEFAULT_POLICIES)}; add --policies ...,{name} to run it "
                f"(default: {','.join(DEFAULT_POLICIES)})"
            )


def check_before_loading(config: RunConfig) -> None:
    """ConfigError (one line) for anything wrong that the flags alone can show."""
    check_cases(config.cases)
    check_policy_arg_targets(config)
    check_policy_args(config.policy_args)
    if config.out:
        check_out_dir(Path(config.out))


__all__ = ["bundled_suites", "check_before_loading", "check_cases", "check_policy_arg_targets"]
