"""Frozen benchmark suites: case files shipped inside the package, verified by checksum on load.

A suite is a JSONL case file under ``packlab/data/suites/`` plus a ``NAME.sha256`` file in
``sha256sum`` format. Loading recomputes the digest and refuses a file that does not match:
the cases behind a published number must never change silently, so a changed file is a new
suite version (a new name here), never an edit of an old one.

Each suite's provenance is its ``SuiteSpec``: the data engine's ``generate_cases`` run with a
fixed user seed and arrival order (``CaseConfig.order``) in the ``bench`` seed domain, which is
disjoint from every training seed by construction (see ``packlab.datagen.seeds``).
``scripts/make_bench_suite.py`` rebuilds the file from the spec, and ``--check`` proves the
bundled bytes are what the spec produces.
"""

from __future__ import annotations

import os
import sys
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from packlab.bench.options import DEFAULT_SUITE
from packlab.cases import cases_sha256, load_cases, save_cases
from packlab.core.choices import ArrivalOrder, CaseSizes, LayoutFamily, require_choice
from packlab.core.errors import ConfigError, PacklabError
from packlab.core.fileio import file_sha256
from packlab.core.types import Case
from packlab.datagen import CaseConfig, generate_cases
from packlab.datagen.config import ValidationConfig
from packlab.datagen.stats import dataset_cases

#: Where the bundled suites live inside the installed package.
SUITE_PACKAGE_DIR = ("data", "suites")


class SuiteIntegrityError(PacklabError):
    """A bundled suite file does not match its recorded checksum (or its spec)."""


@dataclass(frozen=True, slots=True)
class SuiteSpec:
    """How a suite was made: per difficulty the number of cases, from one fixed user seed, of
    one layout family in one arrival order (``CaseConfig.layout`` / ``CaseConfig.order``; every
    other case setting is the default)."""

    name: str
    counts: tuple[tuple[str, int], ...]  # (difficulty, number of cases), in file order
    seed: int  # user seed of datagen.generate_cases in the ``domain`` seed space
    domain: str = "bench"
    description: str = ""
    order: ArrivalOrder = "removal"
    layout: LayoutFamily = "layered"
    #: ``CaseConfig.sizes``: every shipped suite's boxes fill their layout (``grid``); a fresh
    #: set may take ``off-grid`` cartons, each a drawn clearance smaller than its slot.
    sizes: CaseSizes = "grid"

    def __post_init__(self) -> None:
        require_choice(self.order, ArrivalOrder, f"suite {self.name!r}: order")
        require_choice(self.layout, LayoutFamily, f"suite {self.name!r}: layout")
        require_choice(self.sizes, CaseSizes, f"suite {self.name!r}: sizes")
        if not self.counts or any(n < 1 for _, n in self.counts):
            raise ConfigError(
                f"suite {self.name!r}: counts = {self.counts!r}: "
                "need at least one case per difficulty"
            )

    @property
    def n_cases(self) -> int:
        return sum(n for _, n in self.counts)

    @property
    def case_config(self) -> CaseConfig:
        """The data engine's case settings of this suite."""
        return CaseConfig(layout=self.layout, order=self.order, sizes=self.sizes)


#: The registered suites. Never edit an entry whose file has shipped: add a new version.
SUITES: dict[str, SuiteSpec] = {
    "packlab-bench-v1": SuiteSpec(
        "packlab-bench-v1",
        counts=(("easy", 20), ("medium", 20), ("hard", 20)),
        seed=0,
        description=(
            "PackLab-Bench v1: 20 easy (buffer 3), 20 medium (buffer 5), 20 hard (buffer 10)"
        ),
    ),
    "packlab-bench-layers-v1": SuiteSpec(
        "packlab-bench-layers-v1",
        counts=(("easy", 20), ("medium", 20), ("hard", 20)),
        seed=1,
        order="layers",
        description=(
            "PackLab-Bench v1's recipe with the reference benchmark's arrival order: objects "
            "arrive layer by layer, shuffled within a layer (20 easy, 20 medium, 20 hard)"
        ),
    ),
    "packlab-bench-cut-v1": SuiteSpec(
        "packlab-bench-cut-v1",
        counts=(("easy", 20), ("medium", 20), ("hard", 20)),
        seed=2,
        layout="cut",
        order="support",
        description=(
            "Cut layouts (Zhao et al., AAAI 2021: the stack cuboid cut recursively, boxes of many "
            "heights, no flat layers), arriving in their support order (CUT-2: a box arrives "
            "once the surface under its footprint stands at its base); 20 easy (buffer 3), 20 "
            "medium (buffer 5), 20 hard (buffer 10)"
        ),
    ),
}


def suite_spec(name: str) -> SuiteSpec:
    try:
        return SUITES[name]
    except KeyError:
        raise ConfigError(f"suite = {name!r}: unknown; available: {', '.join(SUITES)}") from None


def suite_dir() -> Path:
    """The directory of the bundled suite files (inside the installed package)."""
    return Path(str(resources.files("packlab").joinpath(*SUITE_PACKAGE_DIR)))


def suite_files(name: str, directory: str | os.PathLike[str] | None = None) -> tuple[Path, Path]:
    """(case file, checksum file) of a suite, in ``directory`` or the bundled location."""
    base = Path(directory) if directory is not None else suite_dir()
    return base / f"{name}.jsonl", base / f"{name}.sha256"


def read_checksum(path: Path, expected_name: str) -> str:
    """The digest recorded in a ``sha256sum``-format file for ``expected_name``."""
    if not path.is_file():
        raise SuiteIntegrityError(
            f"{path}: checksum file missing; a suite without one cannot be verified"
        )
    for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        parts = line.split()
        if len(parts) == 2 and parts[1].lstrip("*") == expected_name:
            digest = parts[0].lower()
            if len(digest) != 64 or any(ch not in "0123456789abcdef" for ch in digest):
                raise SuiteIntegrityError(f"{path}:{lineno}: '{parts[0]}' is not a sha256 digest")
            return digest
    raise SuiteIntegrityError(f"{path}: no checksum line for {expected_name!r}")


def verify_suite_file(cases_path: Path, checksum_path: Path) -> str:
    """Raise ``SuiteIntegrityError`` unless the case file's sha256 is the recorded one."""
    if not cases_path.is_file():
        raise SuiteIntegrityError(f"{cases_path}: suite file missing")
    recorded = read_checksum(checksum_path, cases_path.name)
    actual = file_sha256(cases_path)
    if actual != recorded:
        raise SuiteIntegrityError(
            f"{cases_path}: sha256 {actual[:12]}... does not match the recorded {recorded[:12]}... "
            f"in {checksum_path.name}; the suite file was changed. A changed case file is a new "
            f"suite version: restore the original or register the new file under a new suite name"
        )
    return actual


def _check_counts(spec: SuiteSpec, cases: Sequence[Case], source: Path) -> None:
    # A checksum proves the bytes are the recorded ones; this proves the recorded file is the
    # suite the spec describes (a mix-up of files with valid checksums would pass the first).
    have = Counter(c.difficulty for c in cases)
    want = dict(spec.counts)
    if dict(have) != want:
        raise SuiteIntegrityError(
            f"{source}: cases per difficulty {dict(have)} differ from the spec {want}"
        )


def load_suite(
    name: str = DEFAULT_SUITE, directory: str | os.PathLike[str] | None = None
) -> list[Case]:
    """The verified cases of a registered suite (``SuiteIntegrityError`` if the file changed)."""
    spec = suite_spec(name)
    cases_path, checksum_path = suite_files(name, directory)
    verify_suite_file(cases_path, checksum_path)
    cases = load_cases(cases_path)
    _check_counts(spec, cases, cases_path)
    return cases


def suite_digest(name: str, directory: str | os.PathLike[str] | None = None) -> str:
    """The recorded sha256 of a suite's case file (for run configs and provenance)."""
    cases_path, checksum_path = suite_files(name, directory)
    return read_checksum(checksum_path, cases_path.name)


def build_suite(
    spec: SuiteSpec, progress: bool = False, validation: ValidationConfig | None = None
) -> list[Case]:
    """Regenerate a suite's cases from its spec (deterministic; slow: replays every plan, under
    MuJoCo unless ``validation`` names another backend)."""
    cases: list[Case] = []
    for difficulty, n in spec.counts:
        if progress:
            print(
                f"{spec.name}: generating {n} {difficulty} cases ...", file=sys.stderr, flush=True
            )
        cases += generate_cases(
            difficulty,
            n,
            spec.seed,
            validate=True,
            config=spec.case_config,
            validation=validation,
            domain=spec.domain,
        )
    return cases


def fresh_spec(
    name: str, seed: int, per_level: int | None = None, sizes: CaseSizes = "grid"
) -> SuiteSpec:
    """A set made like suite ``name`` (its layout family, arrival order and cases per level, or
    ``per_level`` of each) from user ``seed`` of the training seed domain: cases the suite has
    never held, to see whether a figure measured on the suite holds on the distribution it was
    drawn from. Its ids carry the seed (``train-s4721-easy-00000``). ``sizes="off-grid"``
    makes the same layouts with cartons off the grid (``CaseConfig.sizes``)."""
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"seed = {seed!r}: must be a whole number >= 0")
    if per_level is not None and (isinstance(per_level, bool) or per_level < 1):
        raise ConfigError(f"per_level = {per_level!r}: must be a whole number >= 1")
    like = suite_spec(name)
    counts = like.counts if per_level is None else tuple((d, per_level) for d, _ in like.counts)
    require_choice(sizes, CaseSizes, "sizes")
    off = "-off-grid" if sizes == "off-grid" else ""
    return SuiteSpec(
        f"fresh-{name}-s{seed}{off}",
        counts=counts,
        seed=seed,
        domain="train",
        description=f"made like {name} from training-domain user seed {seed}"
        + (", boxes off the grid" if off else ""),
        order=like.order,
        layout=like.layout,
        sizes=sizes,
    )


def write_suite(
    spec: SuiteSpec, cases: Sequence[Case], directory: str | os.PathLike[str]
) -> tuple[Path, str]:
    """Write ``NAME.jsonl`` and ``NAME.sha256`` into ``directory``; returns (case file, digest)."""
    cases_path, checksum_path = suite_files(spec.name, directory)
    _check_counts(spec, cases, cases_path)
    save_cases(cases, cases_path)
    digest = file_sha256(cases_path)
    tmp = checksum_path.with_name(checksum_path.name + ".tmp")
    tmp.write_text(f"{digest}  {cases_path.name}\n", encoding="utf-8")
    os.replace(tmp, checksum_path)
    return cases_path, digest


@dataclass(frozen=True, slots=True)
class CaseSource:
    """The cases a run uses and where they came from (a suite name, a file or a directory)."""

    label: str  # suite name, or the case file's (directory's) stem
    origin: str  # "suite:NAME" or the path as given
    sha256: str  # the cases' checksum (``packlab.cases.cases_sha256``), for the run's config
    cases: tuple[Case, ...]


def resolve_cases(cases: str | None = None) -> CaseSource:
    """A registered suite by name (default ``packlab-bench-v1``), or a case source by path: a
    case file (JSON, JSONL, parquet), a reference benchmark directory (see ``packlab.cases``) or
    a dataset directory written by ``packlab generate`` (its kept cases, in shard order).

    The checksum is of the cases, not of the file's bytes (``cases_sha256``): the same cases
    give the same digest whatever file they came in, so a suite and its export to the
    reference layout are one identity for runs and comparisons. For a bundled suite it is the
    recorded file digest (that file is packlab's canonical JSONL).
    """
    if cases is None or cases in SUITES:
        name = cases or DEFAULT_SUITE
        loaded = load_suite(name)
        return CaseSource(name, f"suite:{name}", suite_digest(name), tuple(loaded))
    path = Path(cases)
    if not path.exists():
        raise ConfigError(
            f"cases = {cases!r}: neither a registered suite ({', '.join(SUITES)}) nor an existing "
            f"file or directory"
        )
    is_dataset = (path / "meta" / "info.json").is_file()
    loaded = list(dataset_cases(path)) if is_dataset else load_cases(path)
    if not loaded:
        raise ConfigError(f"cases = {cases!r}: the file holds no cases")
    return CaseSource(
        path.stem or path.resolve().name, str(path), cases_sha256(loaded), tuple(loaded)
    )


__all__ = [
    "DEFAULT_SUITE",
    "SUITES",
    "CaseSource",
    "SuiteIntegrityError",
    "SuiteSpec",
    "build_suite",
    "file_sha256",
    "fresh_spec",
    "load_suite",
    "resolve_cases",
    "suite_digest",
    "suite_dir",
    "suite_files",
    "suite_spec",
    "verify_suite_file",
    "write_suite",
]
