"""The optional Ray backend: the same shards, each a Ray task, on a local ray.init()."""

from __future__ import annotations

import pytest
from datagen_helpers import tiny_config, tree_bytes

from packlab.datagen.engine import RunOptions, generate_dataset


@pytest.mark.slow
def test_ray_backend_matches_local_output(tiny_dataset, tmp_path, ray_cluster):
    generate_dataset(
        tiny_config(),
        RunOptions(str(tmp_path / "ray"), workers=2, executor="ray", progress=False),
    )
    assert tree_bytes(tmp_path / "ray") == tree_bytes(tiny_dataset)
