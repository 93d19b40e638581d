"""``packlab serve --engine vllm``: the ``vllm serve`` command line it builds and the ``packlab
bench`` command it prints (no vLLM needed: ``--print-command`` starts nothing)."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest

from packlab import executors
from packlab.bench.suites import SUITES, load_suite
from packlab.cli.main import build_parser, main
from packlab.core.errors import EXIT_OK, EXIT_USAGE, ConfigError
from packlab.vlm.serve import command, endpoint, vllm_command
from packlab.vlm.serve.vllm_command import (
    BUNDLED_MAX_STEPS,
    PROMPTS,
    VllmSettings,
    bench_argv,
    images_per_prompt,
    shell_text,
    vllm_argv,
)


def flag(argv: list[str], name: str) -> str:
    """The value after ``name`` in ``argv``."""
    assert argv.count(name) == 1, (name, argv)
    return argv[argv.index(name) + 1]


def policy_args(argv: list[str]) -> dict[str, str]:
    pairs = [argv[i + 1] for i, a in enumerate(argv) if a == "--policy-arg"]
    return dict(p.removeprefix("endpoint:").split("=", 1) for p in pairs)


@pytest.fixture
def checkpoint(tmp_path):
    ckpt = tmp_path / "runs" / "sft-final"
    ckpt.mkdir(parents=True)
    (ckpt / "config.json").write_text("{}")
    return ckpt


def print_command(capsys, *argv: str) -> tuple[list[str], list[str]]:
    """(vllm argv, bench argv) that ``packlab serve --engine vllm ... --print-command`` prints."""
    assert main(["serve", "--engine", "vllm", *argv, "--print-command"]) == EXIT_OK
    out = capsys.readouterr().out
    # Shell text to copy: comment lines, and each command over lines joined by a backslash.
    lines = [line for line in out.replace("\\\n", " ").splitlines() if not line.startswith("#")]
    assert len(lines) == 2, out
    return shlex.split(lines[0]), shlex.split(lines[1])


# -- images per request ------------------------------------------------------------------------
def test_a_full_history_shows_one_image_per_step_plus_the_current_one():
    assert images_per_prompt("full", "heightmap", 20, None) == 21
    assert images_per_prompt("no_actions", "blank", 20, None) == 21
    assert images_per_prompt("full", "heightmap", 20, 4) == 5  # endpoint:max_past_steps=4
    assert images_per_prompt("full", "heightmap", 20, 0) == 1
    assert images_per_prompt("current_only", "heightmap", 20, None) == 1
    assert images_per_prompt("full", "none", 20, None) == 0


def test_the_default_step_bound_covers_every_bundled_suite():
    longest = max(len(c.objects) for name in SUITES for c in load_suite(name))
    assert longest == BUNDLED_MAX_STEPS


def test_limits_are_the_ones_the_endpoint_and_the_bench_use():
    assert PROMPTS == endpoint.PROMPTS
    assert vllm_command.MAX_CONCURRENCY == executors.MAX_CONCURRENCY


# -- the vllm serve command --------------------------------------------------------------------
def test_packlab_prompt_command(checkpoint, capsys):
    serve, bench = print_command(capsys, str(checkpoint))
    assert serve[:3] == ["vllm", "serve", str(checkpoint)]
    assert flag(serve, "--served-model-name") == "sft-final"  # never the path
    assert (flag(serve, "--host"), flag(serve, "--port")) == ("127.0.0.1", "8000")
    assert json.loads(flag(serve, "--limit-mm-per-prompt")) == {
        "image": BUNDLED_MAX_STEPS + 1,
        "video": 0,
    }
    assert flag(serve, "--max-model-len") == "65536"
    assert flag(serve, "--max-num-seqs") == "32"  # 4 workers x 8 episodes in flight
    assert flag(serve, "--seed") == "0"
    assert "--enable-prefix-caching" in serve
    assert flag(serve, "--generation-config") == "vllm"  # greedy as the vlm policy decodes
    assert flag(serve, "--chat-template-content-format") == "openai"
    assert "--default-chat-template-kwargs" not in serve and "--trust-remote-code" not in serve
    # The bench command parses, and asks for the served name at the served address.
    build_parser().parse_args(bench[1:])
    assert bench[:4] == ["packlab", "bench", "--policies", "endpoint"]
    assert policy_args(bench) == {"base_url": "http://127.0.0.1:8000/v1", "model": "sft-final"}
    assert (flag(bench, "--workers"), flag(bench, "--concurrency")) == ("4", "8")


def test_reference_prompt_serves_as_the_reference_does(capsys):
    serve, bench = print_command(capsys, "donghao-zhou/PackLab-VLM-9B", "--prompt", "reference")
    assert serve[2] == "donghao-zhou/PackLab-VLM-9B"  # a Hub id goes to vLLM as it is
    assert flag(serve, "--served-model-name") == "PackLab-VLM-9B"
    assert flag(serve, "--max-model-len") == "65536"
    assert flag(serve, "--gpu-memory-utilization") == "0.85"
    assert json.loads(flag(serve, "--default-chat-template-kwargs")) == {"enable_thinking": False}
    assert {"--trust-remote-code", "--disable-custom-all-reduce"} <= set(serve)
    assert flag(serve, "--gdn-prefill-backend") == "triton"
    assert "--generation-config" not in serve
    build_parser().parse_args(bench[1:])
    assert flag(bench, "--sides") == "catalogue"
    assert policy_args(bench) == {
        "base_url": "http://127.0.0.1:8000/v1",
        "model": "PackLab-VLM-9B",
        "prompt": "reference",
        "deadline_s": "120",
    }


def test_options_reach_both_commands(checkpoint, capsys):
    serve, bench = print_command(
        capsys,
        str(checkpoint),
        "--served-name",
        "packer",
        "--host",
        "0.0.0.0",
        "--port",
        "9001",
        "--max-past-steps",
        "6",
        "--history",
        "no_actions",
        "--workers",
        "2",
        "--concurrency",
        "16",
        "--max-model-len",
        "32768",
        "--seed",
        "7",
        "--no-prefix-caching",
        "--template-kwargs",
        '{"enable_thinking": false}',
        "--vllm-args=--tensor-parallel-size 2 --enforce-eager",
    )
    assert json.loads(flag(serve, "--limit-mm-per-prompt"))["image"] == 7
    assert (flag(serve, "--max-num-seqs"), flag(serve, "--max-model-len")) == ("32", "32768")
    assert (flag(serve, "--served-model-name"), flag(serve, "--seed")) == ("packer", "7")
    assert "--no-enable-prefix-caching" in serve
    assert json.loads(flag(serve, "--default-chat-template-kwargs")) == {"enable_thinking": False}
    assert serve[-3:] == ["--tensor-parallel-size", "2", "--enforce-eager"]  # passed last
    assert policy_args(bench) == {
        "base_url": "http://127.0.0.1:9001/v1",  # a server on every interface, reached locally
        "model": "packer",
        "history": "no_actions",
        "max_past_steps": "6",
    }
    assert (flag(bench, "--workers"), flag(bench, "--concurrency")) == ("2", "16")


def test_a_packlab_checkpoint_brings_its_training_settings(checkpoint, capsys):
    sft = {"history": "current_only", "image": "blank", "template_kwargs": {"x": 1}}
    card = {"action_format": "json", "sft_config": sft}
    (checkpoint / command.PACKLAB_META).write_text(json.dumps(card))
    serve, bench = print_command(capsys, str(checkpoint))
    assert json.loads(flag(serve, "--limit-mm-per-prompt"))["image"] == 1
    assert json.loads(flag(serve, "--default-chat-template-kwargs")) == {"x": 1}
    assert policy_args(bench)["history"] == "current_only"
    assert policy_args(bench)["image"] == "blank"
    # What the command line says wins over the card.
    serve, bench = print_command(capsys, str(checkpoint), "--history", "full")
    assert json.loads(flag(serve, "--limit-mm-per-prompt"))["image"] == BUNDLED_MAX_STEPS + 1
    assert "history" not in policy_args(bench)


def test_shell_text_is_one_command():
    s = VllmSettings(model="dir with space", served_name="m")
    assert shlex.split(shell_text(vllm_argv(s)).replace("\\\n", " ")) == vllm_argv(s)
    assert bench_argv(s)[-4:] == ["--workers", "4", "--concurrency", "8"]


# -- mistakes ----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "argv, message",
    [
        ([], "--engine vllm needs the model"),
        (["tiny:qwen3_5:tiny"], "tiny random models are served by --engine packlab"),
        (["{tmp}"], "not a checkpoint directory (no config.json)"),
        (["{ckpt}", "--max-new-tokens", "32"], "--max-new-tokens 32: an option of --engine"),
        (["{ckpt}", "--model", "other"], "name the model once"),
        (["{ckpt}", "--port", "0"], "--port 0: must be a whole number in [1, 65535]"),
        (["{ckpt}", "--concurrency", "65"], "--concurrency 65: must be a whole number"),
        (["{ckpt}", "--max-past-steps", "-1"], "--max-past-steps -1"),
        (["{ckpt}", "--gpu-memory-utilization", "1.5"], "--gpu-memory-utilization 1.5"),
        (["{ckpt}", "--template-kwargs", "[1]"], "--template-kwargs '[1]': must be a JSON object"),
        (["{ckpt}", "--template-kwargs", "{"], "--template-kwargs '{': not JSON"),
        (["{ckpt}", "--vllm-args", "'unclosed"], "--vllm-args"),
    ],
)
def test_bad_input_is_one_line_naming_the_option(tmp_path, checkpoint, capsys, argv, message):
    argv = [a.replace("{tmp}", str(tmp_path)).replace("{ckpt}", str(checkpoint)) for a in argv]
    assert main(["serve", "--engine", "vllm", *argv, "--print-command"]) == EXIT_USAGE
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err


def test_candidate_mode_checkpoints_are_refused(checkpoint, capsys):
    (checkpoint / command.PACKLAB_META).write_text(json.dumps({"action_format": "candidate"}))
    assert main(["serve", "--engine", "vllm", str(checkpoint), "--print-command"]) == EXIT_USAGE
    assert "candidate-mode checkpoint" in capsys.readouterr().err


def test_vllm_options_need_the_vllm_engine(capsys):
    assert main(["serve", "--max-model-len", "4096", "--print-command"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "--print-command, --max-model-len: options of --engine vllm" in err


def test_without_vllm_the_error_names_the_extra(checkpoint, capsys, monkeypatch):
    monkeypatch.setattr(command.shutil, "which", lambda name: None)
    assert main(["serve", "--engine", "vllm", str(checkpoint)]) == EXIT_USAGE
    err = capsys.readouterr().err.strip()
    assert "pip install -e '.[vllm]'" in err and len(err.splitlines()) == 1


def test_vllm_takes_the_process_place_with_the_printed_command(checkpoint, capsys, monkeypatch):
    started = []
    monkeypatch.setattr(command.shutil, "which", lambda name: "/opt/bin/vllm")
    monkeypatch.setattr(command.os, "execv", lambda exe, argv: started.append((exe, argv)))
    assert main(["serve", "--engine", "vllm", str(checkpoint)]) == EXIT_OK
    [(exe, argv)] = started
    assert exe == "/opt/bin/vllm" and argv[:3] == ["vllm", "serve", str(checkpoint)]
    assert "packlab bench" in capsys.readouterr().out


def test_settings_check_their_fields():
    with pytest.raises(ConfigError, match="--prompt 'other'"):
        VllmSettings(model="m", served_name="m", prompt="other")
    with pytest.raises(ConfigError, match="--history = 'all'"):
        VllmSettings(model="m", served_name="m", history="all")  # type: ignore[arg-type]


def test_the_docs_show_what_the_command_prints(tmp_path, capsys, monkeypatch):
    page = (Path(__file__).resolve().parents[2] / "docs" / "vlm.md").read_text(encoding="utf-8")
    shown = re.search(r"```bash\n(# serve the model \(vLLM\):\n.*?)```", page, re.DOTALL)
    assert shown, "docs/vlm.md no longer shows the printed commands"
    (tmp_path / "runs" / "sft" / "final").mkdir(parents=True)
    (tmp_path / "runs" / "sft" / "final" / "config.json").write_text("{}")
    monkeypatch.chdir(tmp_path)
    argv = ["serve", "--engine", "vllm", "runs/sft/final", "--print-command"]
    assert main(argv) == EXIT_OK
    assert capsys.readouterr().out == shown.group(1)
