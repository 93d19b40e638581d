"""Runs recorded before a PhysicsConfig field existed resume and replay as they were made."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from packlab.bench.config import PHYSICS_ADDED, check_resumable, physics_from_json
from packlab.core.errors import ConfigError
from packlab.sim.physics.mujoco_backend import PhysicsConfig

SAVED = Path(__file__).resolve().parents[2] / "results" / "packlab-bench-v1" / "config.json"


def _saved() -> dict:
    saved = json.loads(SAVED.read_text())
    assert not set(PHYSICS_ADDED) & set(saved["physics"])  # written before the fields existed
    return saved


def _now(**physics) -> dict:
    current = json.loads(SAVED.read_text())
    current["physics"] = json.loads(json.dumps(dataclasses.asdict(PhysicsConfig(**physics))))
    return current


def test_the_added_fields_default_to_the_settle_the_old_run_was_made_with():
    assert physics_from_json(_saved()["physics"]) == PhysicsConfig()


def test_an_old_run_resumes_under_the_default_physics():
    check_resumable(_saved(), _now(), SAVED.parent)


def test_an_old_run_does_not_resume_under_the_settle_region():
    with pytest.raises(ConfigError, match="physics.freeze"):
        check_resumable(_saved(), _now(freeze=True), SAVED.parent)
