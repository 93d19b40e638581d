"""The MuJoCo backend: rigid boxes under gravity in an open container, settled after each drop.

Design choices (measured on a 2-core CPU; see benchmarks/physics_placement.py):

* One model per case with every box pre-allocated as a free body. Boxes not yet placed are
  *parked* far away with collisions off and gravity compensated, so they never move and fall
  asleep; placing one switches its collisions and gravity on and teleports it. This avoids
  recompiling the model at every placement.
* Island sleeping (MuJoCo >= 3.3) puts settled stacks to sleep, so a placement costs about the
  same whatever the number of boxes already packed.
* Stiff contacts (``solref`` 5 ms time constant, ``solimp`` 0.95/0.99/1 mm) with 2 ms steps keep
  stacks still; friction 0.5 is a cardboard-on-cardboard value.
* Collision boxes are shrunk horizontally by ``collision_inset_mm`` per side so boxes placed flush
  against a neighbour or a wall touch without interpenetrating (touching is not overlapping);
  heights are exact, so supports are unaffected. The heightmap uses the true sizes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from packlab.errors import ConfigError
from packlab.sim.heightmap import box_top_region, compose_regions, yaw_quaternion
from packlab.sim.physics.base import Transition
from packlab.types import Box, Container

_MM = 1e-3  # metres per millimetre
_REUSE_MM = 0.02  # see MujocoBackend._rasterise
_REUSE_QUAT = 1e-5


@dataclass(frozen=True, slots=True)
class PhysicsConfig:
    """Engine and settling parameters of the MuJoCo backend (SI units unless the name says)."""

    timestep_s: float = 0.002
    gravity: float = -9.8
    friction: float = 0.5
    solref: tuple[float, float] = (0.005, 1.0)
    solimp: tuple[float, float, float] = (0.95, 0.99, 0.001)
    density_kg_m3: float = 250.0  # a packed carton; only ratios between boxes matter here
    #: A body counts as still below these speeds (DESIGN.md section 4 defaults).
    linear_speed_threshold: float = 0.01
    angular_speed_threshold: float = 0.05
    #: ... held for this many consecutive steps after a placement ...
    settle_window_steps: int = 5
    #: ... and, once the last object is in, for this many, so a slow topple still shows.
    final_settle_window_steps: int = 50
    #: Hard cap on steps per placement (2 s of simulated time); reaching it is reported as
    #: ``capped``. Stable stacks settle in a few steps; what reaches the cap is a messy pile
    #: creeping at about 1 cm/s (soft-contact slip), which a longer wait barely changes: on the
    #: bench, 2500 instead of 1000 moved no method's average Overall by more than 0.004.
    max_settle_steps: int = 1000
    clearance_mm: float = 0.5
    collision_inset_mm: float = 0.5
    wall_thickness_mm: float = 50.0
    sleep: bool = True
    solver: str = "Newton"
    cone: str = "pyramidal"
    solver_iterations: int = 50
    solver_tolerance: float = 1e-8
    #: Post-solve no-slip passes: soft contacts otherwise let leaning piles creep for seconds.
    noslip_iterations: int = 0
    impratio: float = 1.0

    def __post_init__(self) -> None:
        positive = {
            "timestep_s": self.timestep_s,
            "friction": self.friction,
            "density_kg_m3": self.density_kg_m3,
            "linear_speed_threshold": self.linear_speed_threshold,
            "angular_speed_threshold": self.angular_speed_threshold,
            "settle_window_steps": self.settle_window_steps,
            "final_settle_window_steps": self.final_settle_window_steps,
            "max_settle_steps": self.max_settle_steps,
            "wall_thickness_mm": self.wall_thickness_mm,
            "solver_iterations": self.solver_iterations,
        }
        for name, value in positive.items():
            if not value > 0:
                raise ConfigError(f"PhysicsConfig.{name} = {value!r}: must be positive")
        if self.clearance_mm < 0 or self.collision_inset_mm < 0:
            raise ConfigError("PhysicsConfig.clearance_mm and collision_inset_mm must not be negative")


def _fmt(values: Sequence[float]) -> str:
    return " ".join(f"{v:.9g}" for v in values)


def build_model_xml(container: Container, boxes: Sequence[Box], cfg: PhysicsConfig) -> str:
    """MJCF of the container (floor + four walls up to the rim) and one parked body per box."""
    sx, sy, sz = (v * _MM for v in container.size_mm)
    t = cfg.wall_thickness_mm * _MM
    half_h = sz / 2
    walls = [
        (-t / 2, sy / 2, half_h, t / 2, sy / 2 + t, half_h),
        (sx + t / 2, sy / 2, half_h, t / 2, sy / 2 + t, half_h),
        (sx / 2, -t / 2, half_h, sx / 2 + t, t / 2, half_h),
        (sx / 2, sy + t / 2, half_h, sx / 2 + t, t / 2, half_h),
    ]
    wall_xml = "\n".join(
        f'    <geom name="wall{i}" type="box" pos="{_fmt(w[:3])}" size="{_fmt(w[3:])}" rgba=".6 .6 .7 .3"/>'
        for i, w in enumerate(walls)
    )
    inset = cfg.collision_inset_mm
    body_xml = []
    for i, box in enumerate(boxes):
        l, w, h = box.size_mm
        half = ((l / 2 - inset) * _MM, (w / 2 - inset) * _MM, h / 2 * _MM)
        park = (-100.0 - 2.0 * i, -100.0, 10.0)  # far from the container and from each other
        body_xml.append(
            f'    <body name="box{i}" pos="{_fmt(park)}" gravcomp="1">\n'
            f'      <freejoint name="j{i}"/>\n'
            f'      <geom name="g{i}" type="box" size="{_fmt(half)}" density="{cfg.density_kg_m3:g}"'
            f' contype="0" conaffinity="0"/>\n'
            f"    </body>"
        )
    sleep_flag = '<flag sleep="enable"/>' if cfg.sleep else ""
    return f"""<mujoco model="packlab">
  <option timestep="{cfg.timestep_s:g}" gravity="0 0 {cfg.gravity:g}" integrator="implicitfast"
          solver="{cfg.solver}" cone="{cfg.cone}" iterations="{cfg.solver_iterations}" tolerance="{cfg.solver_tolerance:g}"
          noslip_iterations="{cfg.noslip_iterations}" impratio="{cfg.impratio:g}">
    {sleep_flag}
  </option>
  <default>
    <geom friction="{cfg.friction:g} 0.005 0.0001" solref="{_fmt(cfg.solref)}" solimp="{_fmt(cfg.solimp)}" condim="3"/>
  </default>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 1" rgba=".8 .8 .8 1"/>
{wall_xml}
{chr(10).join(body_xml)}
  </worldbody>
</mujoco>
"""


class MujocoBackend:
    """Transitions by rigid-body simulation; see the module docstring for the design."""

    name = "mujoco"

    def __init__(self, config: PhysicsConfig | None = None) -> None:
        self.config = config or PhysicsConfig()
        self._model: mujoco.MjModel | None = None
        self._data: mujoco.MjData | None = None
        self._container: Container | None = None
        self._sizes_mm = np.zeros((0, 3))
        self._placed = np.zeros(0, dtype=bool)
        self._body_ids = np.zeros(0, dtype=int)
        self._geom_ids = np.zeros(0, dtype=int)

    def reset(self, container: Container, boxes: Sequence[Box]) -> np.ndarray:
        model = mujoco.MjModel.from_xml_string(build_model_xml(container, boxes, self.config))
        self._model, self._data = model, mujoco.MjData(model)
        self._container = container
        self._sizes_mm = np.array([b.size_mm for b in boxes], dtype=np.float64).reshape(-1, 3)
        self._placed = np.zeros(len(boxes), dtype=bool)
        self._regions: dict[int, tuple[np.ndarray, np.ndarray, object]] = {}
        self._body_ids = np.array([model.body(f"box{i}").id for i in range(len(boxes))], dtype=int)
        self._geom_ids = np.array([model.geom(f"g{i}").id for i in range(len(boxes))], dtype=int)
        mujoco.mj_forward(model, self._data)
        return np.zeros(container.cells, dtype=np.int32)

    def _qpos_slice(self, index: int) -> slice:
        adr = self._model.jnt_qposadr[self._model.body_jntadr[self._body_ids[index]]]
        return slice(adr, adr + 7)

    def _qvel_slice(self, index: int) -> slice:
        adr = self._model.jnt_dofadr[self._model.body_jntadr[self._body_ids[index]]]
        return slice(adr, adr + 6)

    def place(self, index: int, rotation: int, min_corner_mm: tuple[int, int, int]) -> Transition:
        model, data, cfg = self._model, self._data, self.config
        assert model is not None and data is not None and self._container is not None, "reset() first"
        l, w, h = self._sizes_mm[index]
        fx, fy = (w, l) if rotation == 1 else (l, w)
        x, y, z = min_corner_mm
        centre = np.array([x + fx / 2, y + fy / 2, z + h / 2 + cfg.clearance_mm]) * _MM

        body, geom = self._body_ids[index], self._geom_ids[index]
        model.body_gravcomp[body] = 0.0
        model.geom_contype[geom] = model.geom_conaffinity[geom] = 1
        # The broad phase filters on the per-body masks, which compile from the geoms.
        model.body_contype[body] = model.body_conaffinity[body] = 1
        qpos = self._qpos_slice(index)
        data.qpos[qpos] = np.concatenate([centre, yaw_quaternion(rotation)])
        data.qvel[self._qvel_slice(index)] = 0.0
        self._placed[index] = True

        steps, capped = self._settle(self.config.settle_window_steps)
        return Transition(self._rasterise(), settle_steps=steps, capped=capped)

    def finish(self) -> Transition:
        """Settle once more with the longer final window before the episode is scored."""
        if not self._placed.any():
            return Transition(np.zeros(self._container.cells, dtype=np.int32), 0, False)
        steps, capped = self._settle(self.config.final_settle_window_steps)
        return Transition(self._rasterise(), settle_steps=steps, capped=capped)

    def _settle(self, window: int) -> tuple[int, bool]:
        """Step until every placed body stays under the speed thresholds for ``window`` steps."""
        model, data, cfg = self._model, self._data, self.config
        dofs = np.concatenate([np.arange(6) + model.jnt_dofadr[model.body_jntadr[b]]
                               for b in self._body_ids[self._placed]])
        lin_idx = dofs.reshape(-1, 6)[:, :3]
        ang_idx = dofs.reshape(-1, 6)[:, 3:]
        lin2 = cfg.linear_speed_threshold**2
        ang2 = cfg.angular_speed_threshold**2
        still_for = 0
        for step in range(1, cfg.max_settle_steps + 1):
            mujoco.mj_step(model, data)
            qvel = data.qvel
            lin = (qvel[lin_idx] ** 2).sum(axis=1)
            ang = (qvel[ang_idx] ** 2).sum(axis=1)
            if lin.max() < lin2 and ang.max() < ang2:
                still_for += 1
                if still_for >= window:
                    return step, False
            else:
                still_for = 0
        return cfg.max_settle_steps, True

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        n = len(self._placed)
        positions = np.full((n, 3), np.nan)
        quats = np.full((n, 4), np.nan)
        for i in np.flatnonzero(self._placed):
            q = self._data.qpos[self._qpos_slice(i)]
            positions[i] = q[:3] / _MM
            quats[i] = q[3:]
        return positions, quats

    def _rasterise(self) -> np.ndarray:
        """The heightmap of all placed boxes, re-sampling only boxes that moved.

        A box's region is recomputed when it moved more than ``_REUSE_MM`` or turned more than
        ``_REUSE_QUAT`` since it was last sampled; smaller motions cannot change a whole-mm
        heightmap by more than rounding.
        """
        positions, quats = self.poses()
        grid, cell = self._container.cells, self._container.cell_xy_mm
        for i in np.flatnonzero(self._placed):
            cached = self._regions.get(i)
            if (cached is None or np.abs(cached[0] - positions[i]).max() > _REUSE_MM
                    or np.abs(cached[1] - quats[i]).max() > _REUSE_QUAT):
                region = box_top_region(grid, cell, self._sizes_mm[i], positions[i], quats[i])
                self._regions[i] = (positions[i].copy(), quats[i].copy(), region)
        return compose_regions(grid, (r[2] for r in self._regions.values()))
