"""Training and tuning refuse bench cases by their seeds, whatever name the cases come under
(``packlab.datagen.guard``): a suite by name, the same suite exported to a file, a
PackData directory; generated train-domain cases and hand-made (manual-domain) cases pass."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from packlab.bench.suites import load_suite
from packlab.cases import case_to_dict, load_cases, save_cases
from packlab.cli import train as train_cli
from packlab.cli.main import main
from packlab.cli.train_rl import training_cases
from packlab.core.errors import ConfigError
from packlab.core.types import CaseOrigin
from packlab.datagen import generate_cases
from packlab.datagen.guard import require_training_cases
from packlab.datagen.seeds import seed_domain

BENCH = "packlab-bench-v1"
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench_file(tmp_path_factory):
    """packlab-bench-v1 exported to a JSONL file by ``packlab cases export``."""
    out = tmp_path_factory.mktemp("export") / "renamed.jsonl"
    assert main(["cases", "export", BENCH, "--format", "jsonl", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def train_file(tmp_path_factory):
    cases = [
        c for level in ("easy", "hard") for c in generate_cases(level, 2, 3, False, domain="train")
    ]
    return save_cases(cases, tmp_path_factory.mktemp("train") / "train.jsonl")


def _refusal_line(err: str, source: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    first = load_suite(BENCH)[0]
    assert source in lines[0] and repr(first.episode_id) in lines[0]
    assert f"seed {first.seed}" in lines[0] and "bench seed domain" in lines[0]
    assert "generated cases" in lines[0]  # what to do instead
    return lines[0]


@pytest.mark.parametrize("command", ["rl", "candidate"])
def test_train_refuses_a_bench_suite_by_name(command, tmp_path, capsys):
    argv = ["train", command, "--cases", BENCH, "--out", str(tmp_path / "run")]
    assert main(argv) == 2
    _refusal_line(capsys.readouterr().err, f"suite:{BENCH}")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("command", ["rl", "candidate"])
def test_train_refuses_the_same_suite_as_a_file(command, bench_file, tmp_path, capsys):
    assert all(seed_domain(c.seed) == "bench" for c in load_cases(bench_file))
    argv = ["train", command, "--cases", str(bench_file), "--out", str(tmp_path / "run")]
    assert main(argv) == 2
    _refusal_line(capsys.readouterr().err, str(bench_file))


def test_the_suite_in_the_reference_layout_is_refused_too(tmp_path, capsys):
    out = tmp_path / "ref"
    assert main(["cases", "export", BENCH, "--format", "reference", "--out", str(out)]) == 0
    assert main(["train", "candidate", "--cases", str(out), "--out", str(tmp_path / "r")]) == 2
    assert "bench seed domain" in capsys.readouterr().err


def test_train_rl_accepts_generated_training_cases(train_file):
    cases, source = training_cases(str(train_file))
    assert len(cases) == 4 and source["cases"] == str(train_file)
    assert {seed_domain(c.seed) for c in cases} == {"train"}


def test_train_candidate_hands_generated_cases_to_the_recipe(train_file, tmp_path, monkeypatch):
    seen = []

    def run_dagger(cfg, cases, on_log, named=None):
        seen.extend(cases)
        return Path(cfg.out) / "final"

    monkeypatch.setattr(train_cli, "_torch_side", lambda _: SimpleNamespace(run_dagger=run_dagger))
    argv = ["train", "candidate", "--cases", str(train_file), "--out", str(tmp_path / "run")]
    assert main(argv) == 0
    assert [c.episode_id for c in seen] == [c.episode_id for c in load_cases(train_file)]


def test_hand_made_cases_pass_but_not_a_reference_benchmark_row():
    """Hand-made cases (seeds below 2**50, e.g. test fixtures) may drive a training loop; a
    reference-layout row of the ``test`` split is the reference's benchmark and is refused."""
    case = generate_cases("easy", 1, 17, False, domain="manual")[0]
    assert seed_domain(case.seed) == "manual"
    assert require_training_cases([case], "hand.jsonl") == [case]
    row = dataclasses.replace(case, origin=CaseOrigin("test", 0))
    with pytest.raises(ConfigError, match=r"hand\.jsonl: case .* reference"):
        require_training_cases([row], "hand.jsonl")
    reference = load_cases(ROOT / "tests" / "data" / "reference_bench")
    with pytest.raises(ConfigError, match="content of reference PackLab-Bench case 'easy_000000'"):
        require_training_cases(reference, "reference_bench", "tuning")


def test_a_seed_outside_every_domain_is_refused():
    case = dataclasses.replace(generate_cases("easy", 1, 2, False, domain="manual")[0], seed=-5)
    with pytest.raises(ConfigError, match="in no packlab seed domain, refused for tuning"):
        require_training_cases([case], "odd.jsonl", "tuning")


def _with_case(dataset: Path, case) -> None:
    """Put ``case`` in place of the first episode of the dataset's first episode shard."""
    shard = min((dataset / "data" / "episodes").glob("*.parquet"))
    table = pq.read_table(shard)
    texts = table.column("case_json").to_pylist()
    texts[0] = json.dumps(case_to_dict(case))
    i = table.schema.get_field_index("case_json")
    pq.write_table(table.set_column(i, "case_json", pa.array(texts, pa.string())), shard)


def test_train_sft_refuses_a_dataset_holding_a_bench_case(tmp_path, capsys):
    data = tmp_path / "data"
    argv = ["generate", "--difficulty", "easy", "--episodes", "2", "--seed", "5"]
    argv += ["--validation", "geometric", "--sft", "none", "--out", str(data), "--no-progress"]
    assert main(argv) == 0
    train_cli.check_sft_data(str(data))  # as generated: train seed domain
    _with_case(data, load_suite(BENCH)[0])
    assert main(["train", "sft", "--data", str(data), "--out", str(tmp_path / "run")]) == 2
    _refusal_line(capsys.readouterr().err, str(data))


def _benchmark(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses resolve their module by name
    spec.loader.exec_module(module)
    return module


def test_tuning_benchmarks_refuse_bench_cases(bench_file, train_file):
    ceiling = _benchmark("proposer_ceiling")
    with pytest.raises(ConfigError, match="bench seed domain, refused for tuning"):
        ceiling.tuning_cases(str(bench_file), 0, 1)
    with pytest.raises(ConfigError, match="bench seed domain"):
        ceiling.tuning_cases(BENCH, 0, 1)
    cases, label = ceiling.tuning_cases(None, 4, 1)
    assert len(cases) == 3 and "seed 4" in label
    assert {seed_domain(c.seed) for c in cases} == {"train"}
    ablations = _benchmark("vlm_ablations")
    with pytest.raises(ConfigError, match="bench seed domain"):
        ablations.training_cases(str(bench_file))
    train = ablations.training_cases(str(train_file))
    held = ablations.heldout_cases(train, 3, 2)  # same user seed: the shared cases drop out
    assert len(held) == 2 and not {c.seed for c in held} & {c.seed for c in train}


def test_the_proposer_choice_rule_prefers_the_smaller_k_on_a_tie():
    ceiling = _benchmark("proposer_ceiling")
    configs = (
        ceiling.ProposerConfig(8, "lowest"),
        ceiling.ProposerConfig(16, "lowest"),
        ceiling.ProposerConfig(8, "lowest+largest"),
    )

    def results(k16: float) -> list[dict]:
        scores = {(8, "lowest"): 0.80, (16, "lowest"): k16, (8, "lowest+largest"): 0.70}
        return [
            {"kind": "restricted", "teacher": "plan", "level": level, "overall": v,
             "config": [rule, k]}
            for (k, rule), v in scores.items()
            for level in ("easy", "medium", "hard")
        ]  # fmt: skip

    assert ceiling.choose(results(0.82), configs) == configs[1]  # clearly better: K=16
    assert ceiling.choose(results(0.803), configs) == configs[0]  # within the tie: smaller K


def test_plan_sweep_plays_training_cases_of_the_families_asked_with_valid_variants(monkeypatch):
    from packlab.policies import make_policy

    sweep = _benchmark("plan_sweep")
    for label, (policy, options) in sweep.VARIANTS.items():
        assert make_policy(policy, **options) is not None, label  # a renamed option fails here
    # Two cases per level keep the test fast; the families and seeds are the sweep's own.
    small = tuple((f, config, seed, 2) for f, config, seed, _ in sweep.FAMILIES)
    monkeypatch.setattr(sweep, "FAMILIES", small)
    cases = sweep.training_cases(("random", "cut-base-height"))
    assert {family for family, _ in cases} == {"random", "cut-base-height"}
    assert len(cases) == 2 * 3 * 2
    assert {seed_domain(c.seed) for _, c in cases} == {"train"}
    assert {c.generator["layout"] for _, c in cases} == {"random", "cut"}
