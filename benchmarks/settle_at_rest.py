"""Are boxes at rest when an episode is scored? Settling caps, residual motion, time per placement.

    python benchmarks/settle_at_rest.py [--policies random,dblf] [--per-level 5] [--seeds 0]
                                        [--levels easy,medium,hard] [--physics KEY=VALUE ...]
                                        [--diagnose]

Runs each policy on the first ``--per-level`` cases of every level of ``packlab-bench-v1`` on
the MuJoCo backend and prints, per policy:

* ``placements`` and ``% unsettled``: placements whose settle hit the per-placement cap;
* ``not at rest``: episodes scored while boxes still moved (the final settle hit its cap; for
  code older than the ``at_rest`` record, the engine's velocities at scoring decide);
* ``qvel lin`` / ``qvel ang``: the largest instantaneous speed of any box at scoring, read
  from the engine (m/s, rad/s), so it includes the solver's vibration in place;
* ``moved mm``: independent of any record, the simulation is run on for 1 s after scoring and
  this is the largest distance any box's centre then travels: how far the scored poses were
  from final. ``>1 mm`` counts the episodes where some box travelled more than 1 mm, and
  ``dOverall`` is the largest change of an episode's Overall had it been scored 1 s later;
* ``final steps``: mean steps of the final settle; ``ms/placement`` and ``p95 ms``: wall time
  per placement (the last step of an episode includes the final settle).

``--physics`` overrides ``PhysicsConfig`` fields as ``packlab bench --physics`` does.
``--diagnose`` prints, for every unsettled placement, where the fastest box is (inside the
container, above the rim, outside the walls) and how it moves.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field

import mujoco
import numpy as np

from packlab.bench.config import parse_physics
from packlab.bench.suites import load_suite
from packlab.metrics import score_final_state
from packlab.policies import make_policy
from packlab.sim.episode import Episode
from packlab.sim.heightmap import quat_to_matrix
from packlab.sim.physics.mujoco_backend import PhysicsConfig

AFTER_STEPS = 500  # 1 s at the default 2 ms step
MOVED_MM = 1.0


@dataclass
class Tally:
    placements: int = 0
    unsettled: int = 0
    episodes: int = 0
    not_at_rest: int = 0
    qvel_lin: float = 0.0
    qvel_ang: float = 0.0
    moved_mm: float = 0.0
    moved_episodes: int = 0
    overall_change: float = 0.0
    step_s: list[float] = field(default_factory=list)
    final_steps: list[int] = field(default_factory=list)


def engine_speeds(backend) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indices, linear m/s, angular rad/s) of every placed box, straight from MuJoCo's qvel."""
    placed = np.flatnonzero(backend._placed)
    qvel = backend._data.qvel
    lin = np.array([np.linalg.norm(qvel[backend._qvel_slice(i)][:3]) for i in placed])
    ang = np.array([np.linalg.norm(qvel[backend._qvel_slice(i)][3:]) for i in placed])
    return placed, lin, ang


def centres_mm(backend) -> np.ndarray:
    return np.array(
        [
            backend._data.qpos[backend._qpos_slice(i)][:3] * 1e3
            for i in np.flatnonzero(backend._placed)
        ]
    )


def run_on(ep: Episode) -> tuple[float, float]:
    """Run the simulation on for 1 s after scoring: (largest distance any box's centre
    travels, mm; |change of Overall| had the episode been scored then)."""
    backend = ep.backend
    if not backend._placed.any():
        return 0.0, 0.0
    before, overall = centres_mm(backend), ep.metrics().overall
    for _ in range(AFTER_STEPS):
        mujoco.mj_step(backend._model, backend._data)
    positions, _ = backend.poses()
    centres = [None if np.isnan(p).any() else p for p in positions]
    volumes = [b.volume_mm3 for b in ep.case.objects]
    later = score_final_state(ep.case.container, volumes, centres, backend._rasterise())[2]
    return float(np.linalg.norm(centres_mm(backend) - before, axis=1).max()), abs(later - overall)


def where(backend, index: int) -> str:
    """A short description of a box's place and posture relative to the container."""
    pos = backend._data.qpos[backend._qpos_slice(index)]
    centre_mm, quat = pos[:3] * 1e3, pos[3:]
    sx, sy, sz = backend._container.size_mm
    tilt = float(np.degrees(np.arccos(np.clip(quat_to_matrix(quat)[2, 2], -1, 1))))
    if not (0 <= centre_mm[0] <= sx and 0 <= centre_mm[1] <= sy):
        place = "outside the walls"
    elif centre_mm[2] > sz:
        place = "above the rim"
    else:
        place = "inside"
    return f"{place}, centre z {centre_mm[2]:.0f} mm (rim {sz}), tilt {tilt:.1f} deg"


def _unsettled(step) -> bool:
    """A placement whose settle ran out of steps (``settled: false``; ``capped`` before that)."""
    settled = getattr(step, "settled", None)
    return (not settled) if settled is not None else bool(step.capped)


def run_one(case, policy_name: str, seed: int, tally: Tally, diagnose: bool, physics) -> None:
    ep = Episode("mujoco", physics)
    obs = ep.reset(case, seed)
    policy = make_policy(policy_name)
    policy.reset(case, seed)
    while not ep.done:
        step = ep.step(policy.act(obs))
        if step.valid:
            tally.placements += 1
            tally.step_s.append(step.wall_time_s)
            unsettled = _unsettled(step)
            tally.unsettled += unsettled
            if diagnose and unsettled:
                idx, lin, ang = engine_speeds(ep.backend)
                k = int(np.argmax(lin + ang))
                print(
                    f"  {case.episode_id} seed {seed} {policy_name} step {step.step_index}: "
                    f"fastest box {idx[k]} lin {lin[k]:.4f} m/s ang {ang[k]:.3f} rad/s, "
                    f"{where(ep.backend, int(idx[k]))}"
                )
        if not ep.done:
            obs = ep.observe()
    tally.episodes += 1
    metrics = ep.metrics()
    _, lin, ang = engine_speeds(ep.backend)
    lin_max = float(lin.max()) if lin.size else 0.0
    ang_max = float(ang.max()) if ang.size else 0.0
    tally.qvel_lin, tally.qvel_ang = max(tally.qvel_lin, lin_max), max(tally.qvel_ang, ang_max)
    recorded = getattr(metrics, "at_rest", None)
    if recorded is None:  # code before the at-rest record: the velocities at scoring decide
        cfg = ep.backend.config
        recorded = lin_max < cfg.linear_speed_threshold and ang_max < cfg.angular_speed_threshold
    tally.not_at_rest += not recorded
    tally.final_steps.append(getattr(metrics, "final_settle_steps", 0))
    moved, change = run_on(ep)
    tally.moved_mm = max(tally.moved_mm, moved)
    tally.moved_episodes += moved > MOVED_MM
    tally.overall_change = max(tally.overall_change, change)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policies", default="random,dblf")
    parser.add_argument("--per-level", type=int, default=5, help="first N cases of each level")
    parser.add_argument("--levels", default="easy,medium,hard")
    parser.add_argument("--seeds", default="0", help="comma-separated run seeds")
    parser.add_argument(
        "--physics", nargs="*", default=[], help="PhysicsConfig overrides, KEY=VALUE"
    )
    parser.add_argument(
        "--diagnose",
        action="store_true",
        help="describe the fastest box of every unsettled placement",
    )
    args = parser.parse_args()

    overrides = dict(parse_physics(args.physics))
    physics = PhysicsConfig(**overrides)
    levels = args.levels.split(",")
    seeds = [int(s) for s in args.seeds.split(",")]
    suite = load_suite()
    cases = [
        c for level in levels for c in [c for c in suite if c.difficulty == level][: args.per_level]
    ]
    print(
        f"packlab-bench-v1 on mujoco: {len(cases)} cases "
        f"({args.per_level} per level: {','.join(levels)}), "
        f"seeds {','.join(map(str, seeds))}; physics overrides {overrides or 'none'}"
    )
    tallies = {}
    for name in args.policies.split(","):
        tally = tallies[name] = Tally()
        t0 = time.perf_counter()
        for case in cases:
            for seed in seeds:
                run_one(case, name, seed, tally, args.diagnose, physics)
        print(f"  {name}: {time.perf_counter() - t0:.1f} s")

    header = (
        f"{'policy':8s} {'placements':>10s} {'% unsettled':>11s} {'episodes':>8s} "
        f"{'not at rest':>11s} "
        f"{'qvel lin':>8s} {'qvel ang':>8s} {'moved mm':>8s} {'>1 mm':>5s} {'final steps':>11s} "
        f"{'dOverall':>8s} {'ms/placement':>12s} {'p95 ms':>7s}"
    )
    print(header)
    print("-" * len(header))
    for name, t in tallies.items():
        pct = 100.0 * t.unsettled / t.placements if t.placements else 0.0
        print(
            f"{name:8s} {t.placements:10d} {pct:10.1f}% {t.episodes:8d} {t.not_at_rest:11d} "
            f"{t.qvel_lin:8.4f} {t.qvel_ang:8.3f} {t.moved_mm:8.2f} {t.moved_episodes:5d} "
            f"{np.mean(t.final_steps):11.0f} {t.overall_change:8.4f} "
            f"{1e3 * np.mean(t.step_s):12.2f} "
            f"{1e3 * np.percentile(t.step_s, 95):7.1f}"
        )


if __name__ == "__main__":
    main()
