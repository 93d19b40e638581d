"""A robot cell's packing loop on ONNX Runtime: perceive, decide, command the robot, repeat.

Only the decision here is real: a learned policy shipped with packlab (``irbpp`` by default)
plays its ONNX graph on ONNX Runtime, from the core install, without torch. Two parts are
STAND-INS that packlab's simulator plays:

- perception: the heightmap of the container and the boxes waiting in the buffer, which a real
  cell reads from its depth camera and its order;
- the robot: it executes each pick-and-place command (here the simulator drops the box).

Replace ``SimulatedCell`` by your cell's own camera and robot driver and the loop stays the same.

    python examples/robot_cell_onnx/robot_cell.py                      # irbpp, 3 demo cases
    python examples/robot_cell_onnx/robot_cell.py --policy tapnet --limit 1
    python examples/robot_cell_onnx/robot_cell.py --model runs/rl-irbpp/best   # your own export
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import packlab
from packlab.cases import load_cases
from packlab.core.feasibility import footprint_cells, placement_height
from packlab.core.protocols import Policy
from packlab.core.types import Action, Case, Observation, Unparsable
from packlab.metrics import EpisodeMetrics
from packlab.policies import make_policy
from packlab.sim.env import demo_cases_path
from packlab.sim.episode import Episode

#: Learned policies shipped with packlab that play on ONNX Runtime.
POLICIES = ("irbpp", "tapnet", "vlm-small")
SHIPPED_MODELS = Path(packlab.__file__).resolve().parent / "data" / "models"


@dataclass(frozen=True)
class PlaceCommand:
    """What the robot is told: which box, how to turn it, where its lower corner goes (mm)."""

    box_id: int | str  # the box's id in the order (the simulator's internal id)
    yaw_deg: int  # 0, or 90: the box's length then lies along y
    min_corner_mm: tuple[int, int, int]  # the footprint's lower corner on the surface below
    footprint_mm: tuple[int, int]  # extent along x and y after the yaw
    action: Action  # the policy's answer, kept for the simulated robot


class SimulatedCell:
    """STAND-IN for the cell's perception and robot: packlab's simulator plays both."""

    def __init__(self, backend: str) -> None:
        self._episode = Episode(backend=backend)

    def start(self, case: Case, seed: int) -> None:
        self._episode.reset(case, seed)

    @property
    def done(self) -> bool:
        return self._episode.done

    def perceive(self) -> Observation:
        """Stand-in for the depth camera and the order: the heightmap and the shown boxes."""
        return self._episode.observe()

    def robot(self, command: PlaceCommand | None, answer: Action | Unparsable) -> str:
        """Stand-in for the robot: execute one command; returns what happened, in words."""
        step = self._episode.step(answer)  # the simulator drops the box and lets it settle
        if command is None or not step.valid:
            return f"no placement: the box is set aside (reason: {step.reason or 'none'})"
        return f"box {command.box_id} yaw {command.yaw_deg} placed at {step.drop_mm} mm"

    def metrics(self) -> EpisodeMetrics:
        return self._episode.metrics()


def to_command(observation: Observation, answer: Action | Unparsable) -> PlaceCommand | None:
    """The robot command for a policy's answer (None when it names no box on the floor)."""
    if not isinstance(answer, Action) or not observation.placeable(answer.object_id):
        return None
    item = observation.shown[answer.object_id]
    fx, fy = footprint_cells(item, answer.rotation)
    hm = observation.heightmap
    if answer.x < 0 or answer.y < 0 or answer.x + fx > hm.shape[0] or answer.y + fy > hm.shape[1]:
        return None
    cell = observation.container.cell_xy_mm
    z = placement_height(hm, answer.x, answer.y, fx, fy)  # rests on the highest cell under it
    return PlaceCommand(
        box_id=item.internal_id,
        yaw_deg=90 * answer.rotation,
        min_corner_mm=(answer.x * cell, answer.y * cell, z),
        footprint_mm=(fx * cell, fy * cell),
        action=answer,
    )


def pack_one(
    cell: SimulatedCell, policy: Policy, case: Case, seed: int, quiet: bool
) -> list[float]:
    """One order packed to the end; returns each decision's time in seconds."""
    cell.start(case, seed)
    policy.reset(case, seed)
    decision_s = []
    while not cell.done:
        observation = cell.perceive()
        started = time.perf_counter()
        answer = policy.act(observation)
        decision_s.append(time.perf_counter() - started)
        command = to_command(observation, answer)
        outcome = cell.robot(command, answer)
        if not quiet:
            print(f"  step {observation.step_index}: {outcome}")
    return decision_s


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", choices=POLICIES, default="irbpp", help="default irbpp")
    parser.add_argument("--model", help="another exported model directory (packlab export onnx)")
    parser.add_argument("--cases-file", default=demo_cases_path(), help="default: demo cases")
    parser.add_argument("--limit", type=int, default=3, help="pack the first N cases (default 3)")
    parser.add_argument("--backend", default="geometric", choices=("geometric", "mujoco"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quiet", action="store_true", help="no line per step")
    args = parser.parse_args(argv)

    options = {"runtime": "onnx", "threads": 1}  # ONNX Runtime on one CPU thread
    if args.model:
        options["model"] = args.model
    policy = make_policy(args.policy, **options)  # the model loads on the first reset
    model_dir = Path(args.model) if args.model else SHIPPED_MODELS / args.policy
    graphs = ", ".join(sorted(p.name for p in model_dir.glob("*.onnx")))
    print(f"policy {args.policy}: {model_dir} ({graphs}) on ONNX Runtime")

    cell = SimulatedCell(args.backend)
    decisions: list[float] = []
    for case in load_cases(args.cases_file)[: args.limit]:
        print(f"order {case.episode_id}: {len(case.objects)} boxes, buffer {case.buffer_size}")
        decisions += pack_one(cell, policy, case, args.seed, args.quiet)
        m = cell.metrics()
        print(
            f"  packed {m.n_inside}/{m.n_objects}, success ratio {m.success_ratio:.3f}, "
            f"compactness {m.compactness:.3f}, overall {m.overall:.3f}"
        )
    if decisions:
        ms = [1000 * s for s in decisions]
        print(f"decisions: {len(ms)}, median {statistics.median(ms):.1f} ms, max {max(ms):.1f} ms")
    print(f"torch imported: {'yes' if 'torch' in sys.modules else 'no'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
