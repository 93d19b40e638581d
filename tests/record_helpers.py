"""Hand-made typed bench records (``packlab.core.records``) for tests that need no engine."""

from __future__ import annotations

from typing import Any

from packlab.core.records import (
    RUN_FORMAT,
    ActionRecord,
    EpisodeError,
    EpisodeOk,
    FinalPose,
    MetricsRecord,
    StepRecord,
    Timing,
)


def metrics(
    overall: float = 0.5,
    sr: float = 1.0,
    n_set_aside: int = 0,
    at_rest: bool = True,
    unsettled_steps: int = 0,
) -> MetricsRecord:
    return MetricsRecord(
        success_ratio=sr,
        compactness=overall / sr if sr else 0.0,
        overall=overall,
        inside_volume_mm3=1000,
        total_volume_mm3=1000,
        max_height_mm=10,
        n_objects=1,
        n_inside=1,
        n_set_aside=n_set_aside,
        invalid_by_reason={},
        settle_steps=0,
        unsettled_steps=unsettled_steps,
        final_settle_steps=0,
        at_rest=at_rest,
        residual_linear_mps=0.0,
        residual_angular_radps=0.0,
        wall_time_s=0.001,
    )


def step(index: int = 0, valid: bool = True) -> StepRecord:
    return StepRecord(
        step=index,
        action=ActionRecord(object_id=0, x=0, y=0, rotation=0),
        valid=valid,
        reason="" if valid else "out_of_bounds",
        internal_id=0,
        shown=(0,),
        drop_mm=(0, 0, 0),
        settle_steps=0,
        settled=True,
        max_linear_speed_mps=0.0,
        max_angular_speed_radps=0.0,
        wall_time_s=0.001,
    )


def ok_record(
    case: str = "c",
    seed: int = 0,
    policy: str = "p",
    difficulty: str = "easy",
    overall: float = 0.5,
    sr: float = 1.0,
    backend: str = "geometric",
    **metric_fields,
) -> EpisodeOk:
    return EpisodeOk(
        format=RUN_FORMAT,
        case_id=case,
        seed=seed,
        policy=policy,
        backend=backend,
        difficulty=difficulty,
        n_objects=1,
        metrics=metrics(overall, sr, **metric_fields),
        policy_time_s=0.002,
        steps=(step(),),
        final_poses={"0": FinalPose((0.0, 0.0, 5.0), (1.0, 0.0, 0.0, 0.0))},
        timing=Timing(episode_s=0.5, policy_s=0.002, env_s=0.001, decisions=1),
    )


def error_record(
    case: str = "c",
    seed: int = 0,
    policy: str = "p",
    difficulty: str = "easy",
    kind: str = "exception",
    error: str = "RuntimeError: boom",
    backend: str = "geometric",
) -> EpisodeError:
    return EpisodeError(
        format=RUN_FORMAT,
        case_id=case,
        seed=seed,
        policy=policy,
        backend=backend,
        difficulty=difficulty,
        n_objects=1,
        error_kind=kind,
        error=error,
        traceback="",
        timing=Timing(episode_s=0.1),
    )


def without_timing(value: Any) -> Any:
    """JSON with every wall-clock field removed (``timing``, durations ``*_s`` and ``*_ms``):
    those differ from run to run; everything else must not."""
    if isinstance(value, dict):
        return {
            k: without_timing(v)
            for k, v in value.items()
            # worst_*: where a run's slowest decision was made, which the clock decides too
            if k != "timing" and not k.endswith(("_s", "_ms")) and not k.startswith("worst_")
        }
    if isinstance(value, (list, tuple)):
        return [without_timing(v) for v in value]
    return value
