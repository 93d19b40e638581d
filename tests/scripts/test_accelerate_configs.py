"""configs/accelerate/*.yaml as ``accelerate launch`` reads them: each must stay a config the
launcher accepts, keep the settings the recipe depends on (distribution, bf16, process count,
FSDP2 with full state dicts, ZeRO-3 with 16-bit saves), and carry a launch command that
``packlab train sft`` accepts with the paper's global batch of 8. Nothing here needs a GPU or
DeepSpeed: the launcher's own parsing turns each file into the environment its processes get,
and the FSDP and DeepSpeed plugins are built from that environment as a rank builds them."""

from __future__ import annotations

import os
import re
import shlex
from pathlib import Path
from unittest import mock

import pytest
import yaml

pytest.importorskip("accelerate")

from accelerate.commands.config.config_args import ClusterConfig, load_config_from_file
from accelerate.commands.launch import _validate_launch_command, launch_command_parser
from accelerate.utils import DeepSpeedPlugin, DistributedType, FullyShardedDataParallelPlugin
from accelerate.utils.launch import prepare_deepspeed_cmd_env, prepare_multi_gpu_env
from torch.distributed.fsdp import CPUOffloadPolicy

from packlab.cli.main import build_parser
from packlab.cli.train import config_from_args

pytestmark = pytest.mark.torch

CONFIGS = Path(__file__).resolve().parents[2] / "configs" / "accelerate"
FILES = ("single_gpu.yaml", "fsdp_8gpu.yaml", "deepspeed_zero3_8gpu.yaml")
#: The paper's global batch: 1 example per GPU x 8 GPUs.
GLOBAL_BATCH = 8


def _launch(path: Path):
    """The launcher's reading of a config file: (args, the loaded config)."""
    args = launch_command_parser().parse_args(["--config_file", str(path), "-m", "x"])
    args, config, _ = _validate_launch_command(args)
    return args, config


def _fsdp_plugin(path: Path) -> FullyShardedDataParallelPlugin:
    args, _ = _launch(path)
    with mock.patch.dict(os.environ, prepare_multi_gpu_env(args)):
        return FullyShardedDataParallelPlugin()


def _deepspeed_plugin(path: Path) -> tuple[DeepSpeedPlugin, dict[str, str]]:
    args, config = _launch(path)
    # What `accelerate launch` sets before it calls the DeepSpeed launcher.
    args.deepspeed_fields_from_accelerate_config = ",".join(config.deepspeed_config)
    _, env = prepare_deepspeed_cmd_env(args)
    with mock.patch.dict(os.environ, env):
        return DeepSpeedPlugin(), env


def _variant(path: Path, tmp_path: Path, key: str) -> Path:
    """The file with its commented ``key: ...`` lines in place of the active ones: the variant
    the comments offer, which must stay as valid as the file itself."""
    lines = path.read_text().splitlines()
    commented = {
        m.group(1): line.replace("# ", "", 1)
        for line in lines
        if (m := re.match(rf"\s+# ({key}\w*): \S+$", line))
    }
    assert commented, f"{path.name}: no commented {key}... lines"
    out = []
    for line in lines:
        m = re.match(r"\s+(\w+): ", line)
        if m and m.group(1) in commented:
            line = commented[m.group(1)]
        out.append(line)
    variant = tmp_path / path.name
    variant.write_text("\n".join(out) + "\n")
    return variant


def _header_command(path: Path) -> list[str]:
    """The ``train sft`` arguments of the file's ``accelerate launch`` comment."""
    text, taking = [], False
    for line in path.read_text().splitlines():
        body = line.lstrip("#").strip()
        taking = taking or body.startswith("accelerate launch")
        if taking:
            text.append(body.rstrip("\\"))
            if not body.endswith("\\"):
                break
    words = shlex.split(" ".join(text))
    assert words[:4] == ["accelerate", "launch", "--config_file", f"configs/accelerate/{path.name}"]
    return words[words.index("packlab.cli.main") + 1 :]


@pytest.mark.parametrize("name", FILES)
def test_each_file_is_a_local_bf16_config_the_launcher_reads(name):
    path = CONFIGS / name
    assert isinstance(yaml.safe_load(path.read_text()), dict)
    config = load_config_from_file(str(path))  # unknown top-level keys raise here
    assert isinstance(config, ClusterConfig)
    assert config.mixed_precision == "bf16" and config.use_cpu is False
    args, _ = _launch(path)
    assert args.mixed_precision == "bf16"


@pytest.mark.parametrize("name", FILES)
def test_each_section_names_only_keys_the_launcher_knows(name):
    # accelerate copies fsdp_config and deepspeed_config keys onto its arguments without
    # checking them: a misspelt key would be dropped without a word.
    known = {a.dest for a in launch_command_parser()._actions}
    config = load_config_from_file(str(CONFIGS / name))
    for key in config.deepspeed_config:
        assert key in known, f"{name}: deepspeed_config.{key} is no launcher option"
    for key in config.fsdp_config:
        assert (key if key.startswith("fsdp_") else f"fsdp_{key}") in known, key


@pytest.mark.parametrize("name", FILES)
def test_the_header_command_is_a_valid_train_sft_with_global_batch_8(name):
    path = CONFIGS / name
    argv = _header_command(path)
    assert argv[:2] == ["train", "sft"]
    cfg = config_from_args(build_parser().parse_args(argv))  # unknown flags exit here
    processes = load_config_from_file(str(path)).num_processes
    assert cfg.micro_batch * cfg.grad_accum * processes == GLOBAL_BATCH
    assert cfg.lr == 1e-5 and cfg.dtype == "bf16" and cfg.gradient_checkpointing
    assert cfg.max_length == 24_576 and cfg.truncation == "error"


def test_single_gpu_is_one_plain_process():
    config = load_config_from_file(str(CONFIGS / "single_gpu.yaml"))
    # A bare NO in YAML is the boolean false, which accelerate would not take for "NO".
    assert config.distributed_type == DistributedType.NO
    assert config.num_processes == 1 and config.num_machines == 1
    args, _ = _launch(CONFIGS / "single_gpu.yaml")
    assert not (args.multi_gpu or args.use_fsdp or args.use_deepspeed)


def test_fsdp_is_fsdp2_full_shard_with_full_state_dicts():
    path = CONFIGS / "fsdp_8gpu.yaml"
    config = load_config_from_file(str(path))
    assert config.distributed_type == DistributedType.FSDP and config.num_processes == 8
    plugin = _fsdp_plugin(path)
    assert plugin.fsdp_version == 2
    assert plugin.reshard_after_forward is True  # full shard
    assert plugin.state_dict_type.name == "FULL_STATE_DICT"
    assert plugin.auto_wrap_policy.__name__ == "transformer_auto_wrap_policy"
    assert plugin.cpu_ram_efficient_loading is True
    assert not isinstance(plugin.cpu_offload, CPUOffloadPolicy)
    # The trainer refuses FSDP's activation checkpointing next to --gradient-checkpointing.
    assert plugin.activation_checkpointing is False


def test_fsdp_offload_variant_offloads_to_the_cpu(tmp_path):
    plugin = _fsdp_plugin(_variant(CONFIGS / "fsdp_8gpu.yaml", tmp_path, "fsdp_offload"))
    assert isinstance(plugin.cpu_offload, CPUOffloadPolicy)
    assert plugin.fsdp_version == 2 and plugin.state_dict_type.name == "FULL_STATE_DICT"


def test_deepspeed_is_zero3_saving_16bit_weights():
    path = CONFIGS / "deepspeed_zero3_8gpu.yaml"
    config = load_config_from_file(str(path))
    assert config.distributed_type == DistributedType.DEEPSPEED and config.num_processes == 8
    plugin, env = _deepspeed_plugin(path)
    assert env["ACCELERATE_MIXED_PRECISION"] == "bf16"
    zero = plugin.deepspeed_config["zero_optimization"]
    assert zero["stage"] == 3
    assert zero["stage3_gather_16bit_weights_on_model_save"] is True
    assert zero["offload_optimizer"]["device"] == zero["offload_param"]["device"] == "none"
    # Left to the trainer, which fills them from --grad-accum and the max grad norm.
    assert plugin.deepspeed_config["gradient_accumulation_steps"] == "auto"
    assert plugin.deepspeed_config["gradient_clipping"] == "auto"


def test_deepspeed_offload_variant_offloads_to_the_cpu(tmp_path):
    path = _variant(CONFIGS / "deepspeed_zero3_8gpu.yaml", tmp_path, "offload")
    plugin, _ = _deepspeed_plugin(path)
    zero = plugin.deepspeed_config["zero_optimization"]
    assert zero["offload_optimizer"]["device"] == zero["offload_param"]["device"] == "cpu"
    assert zero["stage"] == 3
