"""The MuJoCo backend: rigid boxes under gravity in an open container, settled after each drop.

Design choices (measured on a 2-core CPU; see benchmarks/physics_placement.py):

* One model per case with every box pre-allocated as a free body. Boxes not yet placed are
  *parked* far away with collisions off and gravity compensated, so they never move and fall
  asleep; placing one switches its collisions and gravity on and teleports it. This avoids
  recompiling the model at every placement.
* Island sleeping (MuJoCo >= 3.3) puts settled stacks to sleep, so a placement costs about the
  same whatever the number of boxes already packed. A messy pile never sleeps (it is one
  contact island and some box in it always moves). ``--physics freeze=true`` has a placement's
  settle simulate only the settle region around the motion and freeze the rest of the pile in
  place (``_SettleRegion``; off by default: it changes messy piles' outcomes, docs/physics.md).
* Stiff contacts (``solref`` 5 ms time constant, ``solimp`` 0.95/0.99/1 mm) with 2 ms steps keep
  stacks still; friction 0.5 is a cardboard-on-cardboard value, on elliptic friction cones: on
  messy piles the pyramidal approximation kept more boxes vibrating in place and creeping.
* Settling (``PhysicsConfig``): a placement settles until every box is still, capped at 2 s
  (``settled: false`` in the step record beyond); the final settle before scoring runs to
  rest under its own 10 s cap (``at_rest: false`` in the record beyond). "Still" is judged on
  velocity or on net motion over 20 ms, so contact-solver vibration in place is not motion;
  the test runs after every step by default (``rest_check_steps``; more lets the engine step
  alone in between).
* A box is never dropped inside another: Eq. 2 heights come from a heightmap sampled at cell
  centres, which can miss the edge of a tilted neighbour, so the drop is raised until clear.
* Asking whether and how deep one box touches anything (the drop's clearance, the place
  skill's guarded moves) runs MuJoCo's collision detection on that box's pairs alone
  (``_collide_with``): the same contacts, bit for bit, without the pile's own. The heightmap
  re-samples only the boxes that moved and keeps the maximum over the others
  (``_rasterise``). Neither changes a result: an episode is the same, step for step, as with
  the whole scene collided and the heightmap composed afresh.
* Collision boxes are shrunk horizontally by ``collision_inset_mm`` per side so boxes placed flush
  against a neighbour or a wall touch without interpenetrating (touching is not overlapping);
  heights are exact, so supports are unaffected. The heightmap uses the true sizes.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from packlab.core.errors import ConfigError
from packlab.core.protocols import Transition
from packlab.core.types import Box, Container
from packlab.sim.heightmap import (
    box_top_region,
    max_regions_into,
    round_heightmap,
    yaw_quaternion,
)
from packlab.sim.physics.place_skill import LIFT_TOLERANCE_MM, PlaceCommand, SkillReport
from packlab.sim.physics.place_skill import place as run_place_skill

_MM = 1e-3  # metres per millimetre
_REUSE_MM = 0.02  # see MujocoBackend._rasterise
_REUSE_QUAT = 1e-5
#: A box may touch this deep (mm) and count as clear (the place skill's tolerance too).
_LIFT_TOLERANCE_MM = LIFT_TOLERANCE_MM


@dataclass(frozen=True, slots=True)
class _SolvedContacts:
    """The contacts on one geom after a solve (``MujocoBackend._solved_contacts``), in
    ``data.contact``'s order: what the wrist readings sum."""

    normal: np.ndarray  # (n,) float64 normal force, N (``mj_contactForce``'s first entry)
    frames: np.ndarray  # (n, 9) float64 contact frames (first row: the normal, geom1 to geom2)
    positions: np.ndarray  # (n, 2) float64 contact points x and y, m
    sign: np.ndarray  # (n, 1) float64 +1 where the geom is geom2 (pushed along the normal), -1


class _Unread:
    """Marks a wrist reading's contacts as not read yet (the reading collides and solves)."""


_UNREAD = _Unread()


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
    #: A box also counts as still when its net motion over this many steps (20 ms) is under
    #: the thresholds. A box resting on another's edge can sit in a contact-solver limit
    #: cycle (its contact set flips every few steps, period about 14 ms) that keeps its
    #: velocity above the thresholds for ever while it moves less than 0.1 mm: by velocity
    #: alone such a pile never comes to rest, by net motion it is still. Anything that
    #: really moves (falling, sliding, toppling, rocking with more than a fraction of a
    #: millimetre) exceeds the thresholds by both measures.
    rest_motion_steps: int = 10
    #: The rest test runs every this many steps, not after each one: between checks the
    #: engine steps with no Python in the loop (the test cost about as much as the steps once
    #: the settle region made them cheap). The settle stops at the first check where the
    #: still checks in a row span the window: two checks 4 steps apart cover the 5-step
    #: window (a drop onto a flat stack settles in 12 steps, 11 tested step by step), fourteen
    #: the final 50-step one; the net motion is measured from the check ``rest_motion_steps``
    #: or more steps before (12 steps). 1 (the default, the records every bundled result was
    #: measured with) is the test after every step; 4 suits ``freeze``.
    rest_check_steps: int = 1
    #: Cap on steps per placement (2 s of simulated time), so one placement's cost stays
    #: bounded; reaching it is recorded on the step (``settled: false`` with the residual
    #: speeds) and the next placement starts from a pile that may still move.
    max_settle_steps: int = 1000
    #: Cap on the final settle after the last object (10 s simulated): the episode is scored
    #: once every box is at rest, or at this cap with ``at_rest: false`` in its record.
    final_max_settle_steps: int = 5000
    clearance_mm: float = 0.5
    collision_inset_mm: float = 0.5
    wall_thickness_mm: float = 50.0
    sleep: bool = True
    solver: str = "Newton"
    #: Elliptic friction cones: same cost as pyramidal here, and on random piles (30 bench
    #: cases) they left fewer boxes vibrating or creeping once scored (see
    #: benchmarks/settle_at_rest.py and the robustness notes).
    cone: str = "elliptic"
    solver_iterations: int = 50
    solver_tolerance: float = 1e-8
    #: Soft (regularised) friction lets a loaded contact slip slowly: boxes leaning on slopes in
    #: messy piles creep at a few mm/s, under the rest threshold. Post-solve no-slip passes or
    #: a higher ``impratio`` stiffen friction and cut that creep, at a cost: impratio 3 took
    #: 37% more time per placement on hard oracle stacks (more solver iterations), so both
    #: stay off by default; ``packlab bench --physics impratio=3`` trades speed for less creep.
    noslip_iterations: int = 0
    impratio: float = 1.0
    #: The settle region (``_SettleRegion``). A messy pile is one contact island: one box
    #: sliding kept every box in the container awake, and the solver paid for all of them at
    #: every step (over three quarters of a random policy's time). With ``freeze`` on, a
    #: placement's settle simulates only the boxes that moved in the last ``freeze_still_steps``
    #: steps (faster than ``freeze_speed_fraction`` of the rest thresholds; the dropped box
    #: from the start), the boxes within ``freeze_margin_mm`` of them (plus how far they can
    #: travel before the next check) and every box resting on those; every other box is frozen
    #: in place: a static copy of its collision box takes its place, the box stops colliding
    #: and sleeps. It thaws, in place and at rest, when motion comes near, and every box thaws
    #: when the settle ends, so the heightmap, the place skill and the next drop see the pile
    #: as it is. The final settle before scoring simulates every box. Off by default: in messy
    #: piles a frozen box is rigid and does not give under a drop, so outcomes differ from the
    #: full settle more than the engine's own chaos does (docs/physics.md has the measurements).
    freeze: bool = False
    freeze_still_steps: int = 10
    freeze_margin_mm: float = 10.0
    #: "Still" for freezing is stricter than for the rest test: speeds (by velocity or net
    #: motion) under this fraction of the rest thresholds, 3 mm/s and 0.015 rad/s. MuJoCo's
    #: soft friction lets a messy pile slump at a few mm/s, under the rest thresholds; frozen
    #: at the rest thresholds, such a pile was held up through the episode and slumped all at
    #: once in the final settle (random policy: from a fifth to 60 % of its time).
    freeze_speed_fraction: float = 0.3

    def __post_init__(self) -> None:
        positive = {
            "timestep_s": self.timestep_s,
            "friction": self.friction,
            "density_kg_m3": self.density_kg_m3,
            "linear_speed_threshold": self.linear_speed_threshold,
            "angular_speed_threshold": self.angular_speed_threshold,
            "settle_window_steps": self.settle_window_steps,
            "final_settle_window_steps": self.final_settle_window_steps,
            "rest_motion_steps": self.rest_motion_steps,
            "rest_check_steps": self.rest_check_steps,
            "max_settle_steps": self.max_settle_steps,
            "final_max_settle_steps": self.final_max_settle_steps,
            "wall_thickness_mm": self.wall_thickness_mm,
            "solver_iterations": self.solver_iterations,
            "freeze_still_steps": self.freeze_still_steps,
        }
        for name, value in positive.items():
            if not value > 0:
                raise ConfigError(f"PhysicsConfig.{name} = {value!r}: must be positive")
        if not 0 < self.freeze_speed_fraction <= 1:
            raise ConfigError(
                f"PhysicsConfig.freeze_speed_fraction = {self.freeze_speed_fraction!r}: must be "
                "in (0, 1]"
            )
        if self.clearance_mm < 0 or self.collision_inset_mm < 0 or self.freeze_margin_mm < 0:
            raise ConfigError(
                "PhysicsConfig.clearance_mm, collision_inset_mm and freeze_margin_mm must not be "
                "negative"
            )


def _rest_test(
    speed2: np.ndarray,
    motion: tuple[np.ndarray, np.ndarray, float] | None,
    limits: np.ndarray,
    calm: np.ndarray,
    region: _SettleRegion | None,
    steps: int,
) -> np.ndarray:
    """Which placed boxes move at a settle check (``MujocoBackend._settle``), from their squared
    speeds ``speed2`` and, where ``motion`` (poses then, poses now, seconds between) is known,
    their net motion; the settle region learns which boxes are restless over the last
    ``steps`` steps (moving, or not calm enough to freeze: a superset)."""
    moving = (speed2 >= limits).any(axis=1)
    restless = moving if region is None else (speed2 >= calm).any(axis=1)
    if motion is not None and restless.any():
        # Every box's (the others' are moot: still by velocity already).
        net2 = _net_squared_speeds(*motion)
        moving &= (net2 >= limits).any(axis=1)
        if region is not None:
            restless &= (net2 >= calm).any(axis=1)
    if region is not None:
        region.moved(np.asarray(restless), steps)
    return np.asarray(moving)


def _squared_speeds(
    qvel: np.ndarray, dof_idx: np.ndarray, work: np.ndarray | None = None
) -> np.ndarray:
    """(n, 2) squared linear (m/s)^2 and angular (rad/s)^2 speeds of n free bodies, from qvel.

    ``dof_idx`` (n, 6) holds each body's free-joint dofs: 3 linear, then 3 angular; ``work``
    (float64, its shape), if given, holds the velocities in between instead of a new array.
    """
    v = qvel.take(dof_idx, out=work)
    np.multiply(v, v, out=v)
    return v.reshape(-1, 2, 3).sum(axis=2)


#: ``_surely_moving`` counts a box as moving only past the thresholds by this factor, so
#: that the rounding of sums added in another order than numpy's cannot change its answer.
_SURELY = 1.0 + 1e-9


def _surely_moving(
    velocity: np.ndarray,
    position: np.ndarray,
    before: np.ndarray | None,
    span_s: float,
    limits: tuple[float, float],
) -> bool:
    """True only where the settle's rest test (velocity, then net motion) would find this
    box moving: its free-joint ``velocity`` (6,: linear, angular) and, with ``before``
    (the position, m, ``span_s`` seconds ago; None while no net motion is known), its net
    linear motion to ``position`` (3,) both past the squared ``limits`` (linear, angular) by
    ``_SURELY``. False says nothing: the full test decides then. The net turn is left to the
    full test (an arccos near 1 amplifies rounding far beyond any margin)."""
    vx, vy, vz, wx, wy, wz = velocity.tolist()
    linear, angular = limits
    if not (vx * vx + vy * vy + vz * vz >= linear * _SURELY) and not (
        wx * wx + wy * wy + wz * wz >= angular * _SURELY
    ):
        return False
    if before is None:
        return True
    (x, y, z), (x0, y0, z0) = position.tolist(), before.tolist()
    dx, dy, dz = x - x0, y - y0, z - z0
    return (dx * dx + dy * dy + dz * dz) / (span_s * span_s) >= linear * _SURELY


def _stillest(speed2: np.ndarray, net2: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """Per box, the squared speeds by the measure (velocity or net motion) under which it looks
    stillest: the one the rest test accepts."""
    net_is_stiller = (net2 / limits).max(axis=1) < (speed2 / limits).max(axis=1)
    return np.where(net_is_stiller[:, None], net2, speed2)


def _net_squared_speeds(before: np.ndarray, after: np.ndarray, span_s: float) -> np.ndarray:
    """(n, 2) squared mean linear and angular speeds of n free bodies between two poses.

    ``before`` and ``after`` are (n, 7) free-joint poses (position m, unit quaternion wxyz)
    ``span_s`` seconds apart; the angle is the one rotation that turns one into the other.
    (Written out element by element: numpy's ``clip`` and ``stack`` cost more than the sums.)
    """
    out = np.empty((len(before), 2))
    out[:, 0] = ((after[:, :3] - before[:, :3]) ** 2).sum(axis=1)
    cos_half = np.minimum(np.abs((after[:, 3:] * before[:, 3:]).sum(axis=1)), 1.0)
    out[:, 1] = (2.0 * np.arccos(cos_half)) ** 2
    out /= span_s**2
    return out


def _added_in_order(values: np.ndarray) -> np.ndarray:
    """The sum over the first axis of ``values`` (n, ...), added one at a time to 0.0 in
    order, as a loop of ``+=`` over contacts adds them: bit for bit that loop's result, which
    numpy's pairwise ``sum`` is not. Zeros (of the other axes' shape) when n = 0."""
    if len(values) == 0:
        return np.zeros(values.shape[1:])
    # A running sum from 0.0 and numpy's running sum from the first value differ only where
    # the first value is -0.0 and every one after it a zero (-0.0 there, +0.0 in the loop):
    # adding +0.0 settles that and changes nothing else.
    return np.cumsum(values, axis=0)[-1] + 0.0


def _rotation_matrices(quats: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotation matrices of n unit quaternions (n, 4, wxyz)."""
    w, x, y, z = quats.T
    rot = np.empty((len(quats), 3, 3))
    rot[:, 0] = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], 1)
    rot[:, 1] = np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], 1)
    rot[:, 2] = np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1)
    return rot


def _yawed_quaternion(rotation: int, yaw_deg: float) -> np.ndarray:
    """Quaternion (wxyz) of the action's yaw (0 or 90 degrees) plus ``yaw_deg`` about z."""
    angle = math.radians(90.0 * rotation + yaw_deg)
    return np.array([math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)])


def _turned(quat: np.ndarray, angle: float) -> np.ndarray:
    """Quaternion (wxyz) ``quat`` turned about the world z axis by ``angle`` radians."""
    out = np.empty(4)
    rot = np.array([math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)])
    mujoco.mju_mulQuat(out, rot, np.asarray(quat, dtype=np.float64))
    return out


def _pivoted(pose: np.ndarray, pivot: np.ndarray, angle: float) -> np.ndarray:
    """Free-joint ``pose`` (7,: position m, quaternion wxyz) turned about the vertical line
    through ``pivot`` (x, y in m) by ``angle`` radians."""
    c, s = math.cos(angle), math.sin(angle)
    out = pose.copy()
    dx, dy = pose[0] - pivot[0], pose[1] - pivot[1]
    out[0], out[1] = pivot[0] + c * dx - s * dy, pivot[1] + s * dx + c * dy
    out[3:] = _turned(pose[3:], angle)
    return out


def _park_position(index: int) -> tuple[float, float, float]:
    """Where box ``index`` waits off stage (m): far from the container and from the others."""
    return (-100.0 - 2.0 * index, -100.0, 10.0)


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
        f'    <geom name="wall{i}" type="box" pos="{_fmt(w[:3])}" size="{_fmt(w[3:])}" '
        'rgba=".6 .6 .7 .3"/>'
        for i, w in enumerate(walls)
    )
    inset = cfg.collision_inset_mm
    body_xml, frozen_xml = [], []
    for i, box in enumerate(boxes):
        l, w, h = box.size_mm
        half = ((l / 2 - inset) * _MM, (w / 2 - inset) * _MM, h / 2 * _MM)
        park = _park_position(i)
        # The box's static stand-in while it is frozen (MujocoBackend._freeze), off until then.
        frozen_xml.append(
            f'    <geom name="f{i}" type="box" size="{_fmt(half)}" pos="{_fmt(park)}" '
            'contype="0" conaffinity="0" group="4" rgba="0 0 0 0"/>'
        )
        body_xml.append(
            f'    <body name="box{i}" pos="{_fmt(park)}" gravcomp="1">\n'
            f'      <freejoint name="j{i}"/>\n'
            f'      <geom name="g{i}" type="box" size="{_fmt(half)}" '
            f'density="{cfg.density_kg_m3:g}"'
            f' contype="0" conaffinity="0"/>\n'
            f"    </body>"
        )
    sleep_flag = '<flag sleep="enable"/>' if cfg.sleep else ""
    solver = (
        f'solver="{cfg.solver}" cone="{cfg.cone}" iterations="{cfg.solver_iterations}" '
        f'tolerance="{cfg.solver_tolerance:g}"'
    )
    geom_default = (
        f'friction="{cfg.friction:g} 0.005 0.0001" solref="{_fmt(cfg.solref)}" '
        f'solimp="{_fmt(cfg.solimp)}" condim="3"'
    )
    return f"""<mujoco model="packlab">
  <option timestep="{cfg.timestep_s:g}" gravity="0 0 {cfg.gravity:g}" integrator="implicitfast"
          {solver}
          noslip_iterations="{cfg.noslip_iterations}" impratio="{cfg.impratio:g}">
    {sleep_flag}
  </option>
  <default>
    <geom {geom_default}/>
  </default>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 1" rgba=".8 .8 .8 1"/>
{wall_xml}
{chr(10).join(frozen_xml)}
{chr(10).join(body_xml)}
  </worldbody>
</mujoco>
"""


class MujocoBackend:
    """Transitions by rigid-body simulation; see the module docstring for the design."""

    name = "mujoco"

    def __init__(self, config: PhysicsConfig | None = None) -> None:
        self.config = config or PhysicsConfig()
        # The episode's simulation, set by ``reset`` (read through the properties below).
        self._model_or_none: mujoco.MjModel | None = None
        self._data_or_none: mujoco.MjData | None = None
        self._container_or_none: Container | None = None
        self._sizes_mm = np.zeros((0, 3))
        self._placed = np.zeros(0, dtype=bool)
        self._body_ids = np.zeros(0, dtype=int)
        self._geom_ids = np.zeros(0, dtype=int)
        self._frozen_geom_ids = np.zeros(0, dtype=int)
        self._frozen = np.zeros(0, dtype=bool)
        #: The box geom whose pairs alone collide while ``_collide_with`` masks the others
        #: (None: the whole scene collides), and the masks it replaced.
        self._colliding_only: int | None = None
        self._unmasked = np.zeros(0, dtype=np.int32)
        self._pose_idx = np.zeros((0, 7), dtype=int)
        self._dof_idx = np.zeros((0, 6), dtype=int)
        #: Elliptic friction cones (``_normal_forces`` reads the normal forces as one gather).
        self._elliptic = False

    def reset(self, container: Container, boxes: Sequence[Box]) -> np.ndarray:
        model = mujoco.MjModel.from_xml_string(build_model_xml(container, boxes, self.config))
        self._model_or_none, self._data_or_none = model, mujoco.MjData(model)
        self._container_or_none = container
        self._sizes_mm = np.array([b.size_mm for b in boxes], dtype=np.float64).reshape(-1, 3)
        self._placed = np.zeros(len(boxes), dtype=bool)
        # The heightmap's per-box regions (``_rasterise``): each box's region and the pose
        # (mm, wxyz) it was sampled at, and the regions' maximum so far (None: recompose).
        self._regions: dict[int, tuple[int, int, int, int, np.ndarray] | None] = {}
        self._sampled = np.zeros(len(boxes), dtype=bool)
        self._sampled_pose = np.zeros((len(boxes), 7))
        self._composed: np.ndarray | None = None
        self._body_ids = np.array([model.body(f"box{i}").id for i in range(len(boxes))], dtype=int)
        self._geom_ids = np.array([model.geom(f"g{i}").id for i in range(len(boxes))], dtype=int)
        self._frozen_geom_ids = np.array(
            [model.geom(f"f{i}").id for i in range(len(boxes))], dtype=int
        )
        self._frozen = np.zeros(len(boxes), dtype=bool)
        self._colliding_only = None
        # Each box's free-joint entries: (n, 7) into qpos, (n, 6) into qvel.
        joints = model.body_jntadr[self._body_ids]
        self._pose_idx = model.jnt_qposadr[joints][:, None] + np.arange(7)
        self._dof_idx = model.jnt_dofadr[joints][:, None] + np.arange(6)
        self._elliptic = model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
        mujoco.mj_forward(model, self._data)
        return np.zeros(container.cells, dtype=np.int32)

    @property
    def _model(self) -> mujoco.MjModel:
        """The episode's model (``reset`` first)."""
        assert self._model_or_none is not None, "reset() first"
        return self._model_or_none

    @property
    def _data(self) -> mujoco.MjData:
        """The episode's state (``reset`` first)."""
        assert self._data_or_none is not None, "reset() first"
        return self._data_or_none

    @property
    def _container(self) -> Container:
        """The episode's container (``reset`` first)."""
        assert self._container_or_none is not None, "reset() first"
        return self._container_or_none

    def _qpos_slice(self, index: int) -> slice:
        adr = self._model.jnt_qposadr[self._model.body_jntadr[self._body_ids[index]]]
        return slice(adr, adr + 7)

    def _qvel_slice(self, index: int) -> slice:
        adr = self._model.jnt_dofadr[self._model.body_jntadr[self._body_ids[index]]]
        return slice(adr, adr + 6)

    #: ``execute`` runs a noisy placement through the robot's place skill.
    supports_noisy_execution = True

    def place(self, index: int, rotation: int, min_corner_mm: tuple[int, int, int]) -> Transition:
        """Drop box ``index`` exactly as planned and settle (exact execution)."""
        data, cfg = self._data, self.config
        l, w, h = self._sizes_mm[index]
        fx, fy = (w, l) if rotation == 1 else (l, w)
        x, y, z = min_corner_mm
        centre = np.array([x + fx / 2, y + fy / 2, z + h / 2 + cfg.clearance_mm]) * _MM
        self._activate(index)
        data.qpos[self._qpos_slice(index)] = np.concatenate([centre, yaw_quaternion(rotation)])
        data.qvel[self._qvel_slice(index)] = 0.0
        self._lift_clear(index, rotation)
        return self._settle(cfg.settle_window_steps, cfg.max_settle_steps, dropped=index)

    def execute(
        self,
        index: int,
        rotation: int,
        command: PlaceCommand,
        offset_mm: tuple[float, float],
        yaw_deg: float,
        redraw: Callable[[], tuple[tuple[float, float], float]] | None = None,
    ) -> tuple[Transition, SkillReport]:
        """Execute a robot's placement of box ``index`` (noisy execution) and settle.

        The command is the robot's belief (``PlaceCommand``); this maps it onto the true box,
        which is physics, not a decision: the gripper puts the box's estimated centre at the
        commanded one, so the true centre lands off by ``offset_mm`` (arm noise minus the grasp
        error, ``packlab.sim.execution.perturb_drop``), turned by ``yaw_deg`` beyond the box's
        own ``rotation``; it
        holds the top face, lowered to ``command.bottom_mm + command.height_mm +
        command.release_mm`` (plus ``PhysicsConfig.clearance_mm``), so a box truly taller or
        shorter than perceived hangs lower or higher. Then the place skill
        (``packlab.sim.physics.place_skill``) runs on the held box, reading only its
        command and the wrist's sensing (``_HeldBox``), and the box is let go. A box the skill
        leaves pressed into something (its slide budget spent) is raised clear first: a box
        never starts inside another (``_lift_clear``).

        ``redraw`` (the episode's: a fresh draw of the arm's noise, the same grasp error, as
        ``offset_mm`` and ``yaw_deg``) lets the skill try a placement again whose descent
        stopped high: the box goes back over the command, held as at the start, off by the new
        draw (``place_skill.place``). Without it the skill does not retry."""
        model, data, cfg = self._model, self._data, self.config
        top = command.bottom_mm + command.height_mm + command.release_mm + cfg.clearance_mm
        true_height = float(self._sizes_mm[index, 2])
        qpos = self._qpos_slice(index)

        def hold(offset: tuple[float, float], yaw: float) -> None:
            """The box held at the command's release pose, off by the arm's and grasp's errors."""
            centre = np.array(
                [
                    command.centre_mm[0] + offset[0],
                    command.centre_mm[1] + offset[1],
                    top - true_height / 2,
                ]
            )
            data.qpos[qpos] = np.concatenate([centre * _MM, _yawed_quaternion(rotation, yaw)])
            data.qvel[self._qvel_slice(index)] = 0.0

        def retry() -> None:
            assert redraw is not None
            hold(*redraw())

        self._activate(index)
        body = self._body_ids[index]
        model.body_gravcomp[body] = 1.0  # held: the gripper carries its weight
        hold(offset_mm, yaw_deg)
        report = run_place_skill(_HeldBox(self, index), command, None if redraw is None else retry)
        if report.set_aside:  # the robot took it back out: nothing to release
            self._park(index)
            return self._settle(cfg.settle_window_steps, cfg.max_settle_steps), report
        model.body_gravcomp[body] = 0.0  # released
        yaw = math.degrees(2 * math.atan2(data.qpos[qpos.start + 6], data.qpos[qpos.start + 3]))
        z = float(data.qpos[qpos.start + 2])
        self._lift_clear(index, 0, yaw)
        # Counted: the simulator's guard, not the robot's decision (see SkillReport.lifted).
        report.lifted = int(float(data.qpos[qpos.start + 2]) != z)
        return self._settle(cfg.settle_window_steps, cfg.max_settle_steps, dropped=index), report

    def _park(self, index: int) -> None:
        """Take box ``index`` back out (the place skill set it aside): parked as before it was
        placed, collisions off, weight carried; it no longer counts as placed."""
        self._whole_scene()
        model, data = self._model, self._data
        body, geom = self._body_ids[index], self._geom_ids[index]
        model.body_gravcomp[body] = 1.0
        model.geom_contype[geom] = model.geom_conaffinity[geom] = 0
        model.body_contype[body] = model.body_conaffinity[body] = 0
        data.qpos[self._qpos_slice(index)] = (*_park_position(index), 1.0, 0.0, 0.0, 0.0)
        data.qvel[self._qvel_slice(index)] = 0.0
        self._placed[index] = False
        if self._regions.pop(index, None) is not None:
            self._composed = None  # its region is no longer part of the heightmap
        self._sampled[index] = False

    def _activate(self, index: int) -> None:
        """Un-park box ``index``: collisions and gravity on; it counts as placed."""
        self._whole_scene()
        model = self._model
        body, geom = self._body_ids[index], self._geom_ids[index]
        model.body_gravcomp[body] = 0.0
        model.geom_contype[geom] = model.geom_conaffinity[geom] = 1
        # The broad phase filters on the per-body masks, which compile from the geoms.
        model.body_contype[body] = model.body_conaffinity[body] = 1
        self._placed[index] = True

    def finish(self) -> Transition:
        """Settle until at rest (longer window, own larger cap) before the episode is scored."""
        if not self._placed.any():
            return Transition(np.zeros(self._container.cells, dtype=np.int32), 0, False)
        return self._settle(
            self.config.final_settle_window_steps, self.config.final_max_settle_steps
        )

    def _lift_clear(self, index: int, rotation: int, yaw_deg: float = 0.0) -> None:
        """Raise a just-placed box out of any box it would start inside.

        Eq. 2 heights come from a heightmap sampled at cell centres, so the edge of a tilted or
        shifted box can reach between two centres above the sampled height; a box dropped there
        would start up to centimetres deep inside it and be shot out by the contact solver
        (on random-policy piles nearly half the drops started over 0.5 mm deep, up to 20 mm). A
        gripper lowering the box would stop on that edge instead, so the box goes to the lowest
        height (to ``_LIFT_TOLERANCE_MM``) where it touches nothing, found by bisection between
        the drop height and the top of the highest box, plus the usual clearance. Drops onto
        flat stacks start clear and are unchanged.
        """
        cfg = self.config
        geom = self._geom_ids[index]
        z_adr = self._qpos_slice(index).start + 2
        tol = _LIFT_TOLERANCE_MM * _MM
        if self._clear_below(index, rotation, yaw_deg) or self._penetration(geom) <= tol:
            return
        low = self._data.qpos[z_adr]
        high = self._highest_top(index) + self._sizes_mm[index, 2] / 2 * _MM
        while high - low > tol:
            self._data.qpos[z_adr] = mid = (low + high) / 2
            if self._penetration(geom) <= tol:
                high = mid
            else:
                low = mid
        self._data.qpos[z_adr] = high + cfg.clearance_mm * _MM

    def _contacts_with(self, geom: int) -> np.ndarray:
        """Whether each current contact (``data.contact``, as last collided) involves ``geom``.
        The contact list's fields are read as arrays: iterating its entries one Python object
        at a time was a third of an honest episode's wall time."""
        contact = self._data.contact
        return (contact.geom1 == geom) | (contact.geom2 == geom)

    def _touching(self, geom: int) -> set[int]:
        """The geoms ``geom`` touches across a side (horizontal normal), as last collided."""
        contact = self._data.contact
        side = self._contacts_with(geom) & (np.abs(contact.frame[:, 2]) <= 0.5)
        g1, g2 = contact.geom1[side], contact.geom2[side]
        return {int(g) for g in np.where(g1 == geom, g2, g1)}

    def _touching_back(self, geom: int, axis: int, collided: bool = False) -> float:
        """How far (m) a box pressed into what it met along ``axis`` must back off for its true
        faces to touch: its deepest collision penetration across the axis plus the collision
        insets between (``PhysicsConfig.collision_inset_mm``: one for a wall, two for a box).
        The insets are a simulator device, so stopping at the collision boxes' contact would
        leave every seated box that much too far (1 mm against a box), and rows seated one box
        after another would creep into the room planned for later boxes. ``collided``: as
        ``_deepest_across``."""
        deepest, _ = self._deepest_across(geom, axis, collided)
        contact = self._data.contact
        across = self._contacts_with(geom) & (np.abs(contact.frame[:, axis]) > 0.5)
        g1, g2 = contact.geom1[across], contact.geom2[across]
        others = np.where(g1 == geom, g2, g1)
        # Two insets against a box, one against the floor or a wall (body 0).
        insets = 2 if (self._model.geom_bodyid[others] != 0).any() else 1
        return deepest + insets * self.config.collision_inset_mm * _MM

    def _wrench(
        self,
        geom: int,
        address: int,
        axis_xy: np.ndarray,
        contacts: _SolvedContacts | None | _Unread = _UNREAD,
    ) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
        """Force (N, world x, y, z) of every contact on ``geom``, their torque about the
        vertical line through ``axis_xy`` (m: the wrist's axis; N m) and the centres of
        pressure (m, x and y) of its side contacts (normal mostly horizontal) and of its
        support contacts (mostly vertical), at the current positions: what a wrist force-torque
        sensor resolves of a held box (its weight carried), as ``_side_load`` reads side
        contacts apart from the support. A centre with no contact of its kind is the box's
        centre; no solve when the box touches nothing. ``contacts``: the box's contacts as
        ``_touch_solved`` gives them at the current positions, if already read."""
        centre = self._data.qpos[address : address + 2].copy()
        force, torque = np.zeros(3), 0.0
        pressure, total = np.zeros((2, 2)), np.zeros(2)  # rows: side, support
        if isinstance(contacts, _Unread):
            contacts = self._touch_solved(geom)
        if contacts is None:
            return force, torque, centre, centre.copy()
        normal, frames, positions = contacts.normal, contacts.frames, contacts.positions
        on_box = normal[:, None] * frames[:, :3] * contacts.sign
        force = _added_in_order(on_box)
        r = positions - axis_xy
        torque = float(_added_in_order(r[:, 0] * on_box[:, 1] - r[:, 1] * on_box[:, 0]))
        support_kind = np.abs(frames[:, 2]) > 0.5
        for kind, rows in enumerate((~support_kind, support_kind)):
            pressure[kind] = _added_in_order(np.abs(normal[rows])[:, None] * positions[rows])
            total[kind] = _added_in_order(np.abs(normal[rows]))
        side, support = (pressure[k] / total[k] if total[k] > 0 else centre for k in (0, 1))
        return force, torque, side, support

    def _deepest_across(self, geom: int, axis: int, collided: bool = False) -> tuple[float, float]:
        """Deepest penetration (m) of ``geom`` in a contact whose normal lies along ``axis``,
        and the sign (+1, -1) of the way out of it along the axis (0, 0 if none).
        ``collided``: ``data.contact`` already lists ``geom``'s contacts at the current
        positions (a collision or a solve there was the last), so it is not collided again."""
        if not collided:
            self._penetration(geom)  # runs the collision
        contact = self._data.contact
        depth = -contact.dist
        across = self._contacts_with(geom) & (np.abs(contact.frame[:, axis]) > 0.5) & (depth > 0.0)
        if not across.any():
            return 0.0, 0.0
        i = int(np.flatnonzero(across)[np.argmax(depth[across])])  # the first of the deepest
        # The normal points from geom1 to geom2: geom2 goes out along it.
        side = 1.0 if contact.geom2[i] == geom else -1.0
        out = math.copysign(1.0, contact.frame[i, axis]) * side
        return float(depth[i]), out

    def _side_load(
        self, geom: int, address: int, contacts: _SolvedContacts | None | _Unread = _UNREAD
    ) -> tuple[np.ndarray, float, np.ndarray]:
        """Force (N, world x and y), torque about z (N m, about the box's centre) and centre
        of pressure (m, x and y) of the contacts on ``geom`` whose normal is mostly horizontal
        (what it is pushed against, not its support), at the current positions, with every
        velocity as it is: what a wrist force sensor would read. Zero force and torque (and
        the box's centre), without solving, when the box touches nothing or nothing across a
        side (what the solve's side contacts would sum then). ``contacts``: as ``_wrench``;
        None also when the box touches nothing across a side."""
        centre = self._data.qpos[address : address + 2].copy()
        force, torque, pressure, total = np.zeros(2), 0.0, np.zeros(2), 0.0
        if isinstance(contacts, _Unread):
            contacts = None
            if self._penetration(geom) > 0.0:
                if self._side_contact(geom):
                    contacts = self._solved_contacts(geom)
                else:
                    self._position_stage()  # what the solve leaves that matters: see there
        if contacts is None:
            return force, torque, centre
        side = np.abs(contacts.frames[:, 2]) <= 0.5
        normal, positions = contacts.normal[side], contacts.positions[side]
        # The normal points from geom1 to geom2; the force pushes geom2 along it.
        on_box = normal[:, None] * contacts.frames[side, :2] * contacts.sign[side]
        force = _added_in_order(on_box)
        r = positions - centre
        torque = float(_added_in_order(r[:, 0] * on_box[:, 1] - r[:, 1] * on_box[:, 0]))
        pressure = _added_in_order(np.abs(normal)[:, None] * positions)
        total = float(_added_in_order(np.abs(normal)))
        return force, torque, pressure / total if total > 0 else centre

    def _side_contact(self, geom: int) -> bool:
        """Whether ``geom`` touches anything across a side (a contact normal mostly
        horizontal), as last collided. A contact's frame comes from the collision, so a solve
        there lists the same side contacts: without one, ``_side_load`` reads nothing."""
        contact = self._data.contact
        return bool((self._contacts_with(geom) & (np.abs(contact.frame[:, 2]) <= 0.5)).any())

    def _touch_solved(self, geom: int) -> _SolvedContacts | None:
        """``geom``'s contacts solved at the current positions (``_solved_contacts``), or None
        without a solve when it touches nothing (penetration 0 or less)."""
        if self._penetration(geom) <= 0.0:
            return None
        return self._solved_contacts(geom)

    def _position_stage(self) -> None:
        """What a solve (``mj_forward``) leaves behind that anything later reads, without the
        solve: MuJoCo's position stage (``mj_fwdPosition``), which wakes the sleeping boxes
        that the awake ones touch. The rest a solve writes (accelerations, constraint forces)
        the next step or solve computes afresh; none of it is state (``qacc_warmstart`` is
        written by ``mj_step`` only). A reading answered without a solve calls this in its
        place, so the sleep state, and with it every later step, is the one the solve leaves."""
        self._whole_scene()
        mujoco.mj_fwdPosition(self._model, self._data)

    def _solved_contacts(self, geom: int) -> _SolvedContacts:
        """Solve the whole scene at the current positions (``mj_forward``) and read the
        contacts on ``geom``, in ``data.contact``'s order: what the wrist readings sum."""
        model, data = self._model, self._data
        self._whole_scene()
        mujoco.mj_forward(model, data)
        contacts = data.contact
        mine = np.flatnonzero(self._contacts_with(geom))
        # The normal points from geom1 to geom2; the force pushes geom2 along it.
        sign = np.where(contacts.geom2[mine] == geom, 1.0, -1.0)[:, None]
        return _SolvedContacts(
            self._normal_forces(mine), contacts.frame[mine], contacts.pos[mine, :2], sign
        )

    def _normal_forces(self, contacts: np.ndarray) -> np.ndarray:
        """The normal force (N) of each of ``contacts`` (indices into ``data.contact``), as
        ``mj_contactForce`` gives it after a solve (``mj_forward``). On elliptic cones that is
        the contact's first constraint force (``efc_force`` at its ``efc_address``; 0 for a
        contact without constraints), read here as one gather; on pyramidal cones the
        function decodes the pyramid, one contact at a time."""
        model, data = self._model, self._data
        if self._elliptic:
            address = data.contact.efc_address[contacts]
            if not (address >= 0).any():
                return np.zeros(len(contacts))
            return np.where(address >= 0, data.efc_force[np.maximum(address, 0)], 0.0)
        wrench = np.zeros(6)
        out = np.empty(len(contacts))
        for k, i in enumerate(contacts.tolist()):
            mujoco.mj_contactForce(model, data, i, wrench)
            out[k] = wrench[0]
        return out

    def _clear_below(self, index: int, rotation: int, yaw_deg: float = 0.0) -> bool:
        """Cheap sufficient test that box ``index`` starts clear: every placed box whose planar
        extent overlaps its footprint tops out below its bottom (the usual drop onto a flat
        stack). Uses the poses of the last step; ``_LIFT_TOLERANCE_MM`` covers their lag.
        A noisy drop's extra ``yaw_deg`` widens the footprint to its axis-aligned bound."""
        model, data = self._model, self._data
        others = self._geom_ids[self._placed & (np.arange(len(self._placed)) != index)]
        if others.size == 0:
            return True
        centre = self._data.qpos[self._qpos_slice(index)][:3]
        half = model.geom_size[self._geom_ids[index]]
        half_x, half_y = (half[1], half[0]) if rotation == 1 else (half[0], half[1])
        if yaw_deg != 0.0:
            c, s = abs(math.cos(math.radians(yaw_deg))), abs(math.sin(math.radians(yaw_deg)))
            half_x, half_y = c * half_x + s * half_y, s * half_x + c * half_y
        pos = data.geom_xpos[others]
        extent = np.einsum(
            "nij,nj->ni", np.abs(data.geom_xmat[others].reshape(-1, 3, 3)), model.geom_size[others]
        )
        overlap = (np.abs(pos[:, 0] - centre[0]) < extent[:, 0] + half_x) & (
            np.abs(pos[:, 1] - centre[1]) < extent[:, 1] + half_y
        )
        if not overlap.any():
            return True
        top = float((pos[overlap, 2] + extent[overlap, 2]).max())
        return top <= centre[2] - half[2] - _LIFT_TOLERANCE_MM * _MM

    def _penetration(self, geom: int) -> float:
        """Deepest penetration (m) of ``geom`` into anything, at the current positions."""
        model, data = self._model, self._data
        mujoco.mj_kinematics(model, data)  # also wakes a tree whose qpos was just set
        self._collide_with(geom)  # every contact listed is one of geom's
        # ``np.minimum.reduce``: ``ndarray.min`` without its Python layer (one call per move).
        return float(-np.minimum.reduce(data.contact.dist)) if data.ncon else 0.0

    def _collide_with(self, geom: int) -> None:
        """MuJoCo's collision detection for the pairs that involve box geom ``geom`` only.

        ``data.contact`` then lists exactly the contacts of ``geom`` that a full
        ``mj_collision`` lists, in the same order and bit for bit (each pair's contacts come
        from that pair's geometry alone), without the pile's own contacts, which in a messy
        pile were most of a guarded move's cost. A box's ``contype`` and ``conaffinity`` (geom
        and body) are both 1 while it collides and both 0 otherwise, and the walls and the
        floor collide through that bit too; here the other colliding boxes keep only an
        affinity, moved to bit 1, which ``geom`` alone (given both bits) matches, so no pair
        without ``geom`` passes MuJoCo's filter and every pair with it passes as before. The
        masks stay so over a run of such calls for one geom (the place skill's guarded moves)
        and are restored (``_whole_scene``) before anything else reads or changes them: the
        settle, the force readings (``mj_forward``), placing, parking, freezing.
        """
        if self._colliding_only != geom:
            self._whole_scene()
            model, geoms, bodies = self._model, self._geom_ids, self._body_ids
            self._unmasked = active = model.geom_contype[geoms].copy()  # 1: the box collides
            mine = geoms == geom
            only_type = np.where(mine, 3 * active, 0)
            only_affinity = np.where(mine, 3, 2) * active
            self._colliding_only = geom
            model.geom_contype[geoms] = model.body_contype[bodies] = only_type
            model.geom_conaffinity[geoms] = model.body_conaffinity[bodies] = only_affinity
        mujoco.mj_collision(self._model, self._data)

    def _whole_scene(self) -> None:
        """Undo ``_collide_with``'s masks: every box collides as its state says again."""
        if self._colliding_only is None:
            return
        model, geoms, bodies, active = self._model, self._geom_ids, self._body_ids, self._unmasked
        model.geom_contype[geoms] = model.geom_conaffinity[geoms] = active
        model.body_contype[bodies] = model.body_conaffinity[bodies] = active
        self._colliding_only = None

    def _highest_top(self, skip: int) -> float:
        """Height (m) of the highest point of any placed box but ``skip`` (0 if none)."""
        data, top = self._data, 0.0
        for i in np.flatnonzero(self._placed):
            if i != skip:
                g = self._geom_ids[i]
                half_z = np.abs(data.geom_xmat[g].reshape(3, 3)[2]) @ self._model.geom_size[g]
                top = max(top, float(data.geom_xpos[g, 2] + half_z))
        return top

    def _settle(self, window: int, cap: int, dropped: int | None = None) -> Transition:
        """Step until every placed box stays still for ``window`` consecutive steps: its speed
        under the thresholds by its velocity now or by its net motion over the last
        ``rest_motion_steps`` steps (``PhysicsConfig``). The test runs every
        ``rest_check_steps`` steps; the settle stops at the first check where the still checks
        in a row span ``window`` steps, or at ``cap`` steps with ``capped`` set. The transition
        carries the largest speeds of any box, each measured by whichever of the two is stiller.

        With ``PhysicsConfig.freeze`` and a ``dropped`` box (just let go) only the settle
        region is simulated: boxes away from the motion are frozen while it lasts
        (``_SettleRegion``). Without one (the final settle, a box set aside) every box is.
        """
        self._whole_scene()
        model, data, cfg = self._model, self._data, self.config
        placed = np.flatnonzero(self._placed)
        dof_idx, pose_idx = self._dof_idx[placed], self._pose_idx[placed]
        qpos, qvel = data.qpos, data.qvel  # views of the state the steps update in place
        velocity = np.empty(dof_idx.shape)  # the placed boxes' velocities at a check
        limits = np.array([cfg.linear_speed_threshold, cfg.angular_speed_threshold]) ** 2
        every, k, dt = cfg.rest_check_steps, cfg.rest_motion_steps, cfg.timestep_s
        lag = -(-k // every)  # checks back to the poses the net motion is measured from
        # Poses at the last lag + 1 checks (a ring) and the step of each.
        history = np.empty((lag + 1, len(placed), 7))
        history_step = np.zeros(lag + 1, dtype=int)
        history[0] = qpos[pose_idx]
        speed2 = _squared_speeds(qvel, dof_idx)
        calm = limits * cfg.freeze_speed_fraction**2  # under these a box may be frozen
        region = self._region(placed, dropped, np.all(speed2 < calm, axis=1), every * dt)
        step, check, still_checks, steps, capped = 0, 0, 0, cap, True
        # The quick test (``_surely_moving``) of one box found moving at the last full check
        # (-1: none) stands in for the full test while it says that box still moves (never
        # with a settle region, which needs every box's measure).
        witness, quick = -1, False
        dof_start, pose_start = dof_idx[:, 0].tolist(), pose_idx[:, 0].tolist()
        speed_limits = (float(limits[0]), float(limits[1]))
        try:
            while step < cap:
                if region is not None:
                    region.update(history[check % (lag + 1)], speed2[:, 0])
                n = min(every, cap - step)
                for _ in range(n):
                    mujoco.mj_step(model, data)
                step, check = step + n, check + 1
                now, then = check % (lag + 1), (check + 1) % (lag + 1)
                qpos.take(pose_idx, out=history[now])
                history_step[now] = step
                span_s = (step - history_step[then]) * dt
                w, past = witness, step > k  # only past step k is a net motion over k known
                quick = w >= 0 and _surely_moving(
                    qvel[dof_start[w] : dof_start[w] + 6],
                    qpos[pose_start[w] : pose_start[w] + 3],
                    history[then, w, :3] if past else None,
                    span_s,
                    speed_limits,
                )
                if quick:
                    still_checks = 0
                    continue
                speed2 = _squared_speeds(qvel, dof_idx, velocity)
                motion = (history[then], history[now], span_s) if past else None
                moving = _rest_test(speed2, motion, limits, calm, region, n)
                if moving.any():
                    still_checks = 0
                    if region is None:  # the fastest of the moving boxes
                        witness = int(np.argmax(np.where(moving, speed2[:, 0], -1.0)))
                else:
                    still_checks += 1
                    if (still_checks - 1) * every + 1 >= window:
                        steps, capped = step, False
                        break
        finally:
            if region is not None:
                region.thaw_all()
        if quick:  # capped after a quick check: every box's speeds at the last one
            speed2 = _squared_speeds(qvel, dof_idx, velocity)
        if steps > k:  # each box by whichever of velocity and net motion is stiller
            span_s = (steps - history_step[then]) * dt
            net2 = _net_squared_speeds(history[then], history[now], span_s)
            speed2 = _stillest(speed2, net2, limits)
        return self._transition(steps, capped, speed2)

    def _transition(self, steps: int, capped: bool, speed2: np.ndarray) -> Transition:
        """A settle's transition: the heightmap, and the largest residual speeds of any box."""
        residual = np.sqrt(speed2.max(axis=0))
        return Transition(
            self._rasterise(),
            settle_steps=steps,
            capped=capped,
            max_linear_speed=float(residual[0]),
            max_angular_speed=float(residual[1]),
        )

    def _region(
        self, placed: np.ndarray, dropped: int | None, calm: np.ndarray, check_s: float
    ) -> _SettleRegion | None:
        """The settle region of a placement's settle (``PhysicsConfig.freeze``), the dropped box
        moving from the start; None where every box is simulated."""
        if not self.config.freeze or dropped is None or len(placed) < 2:
            return None
        region = _SettleRegion(self, placed, calm, check_s)
        region.moved(placed == dropped, 0)
        return region

    def _freeze(self, indices: np.ndarray) -> None:
        """Freeze boxes ``indices`` where they are: each one's static stand-in (a world geom of
        its collision box, ``f{i}``) takes its pose and collides in its place, while the box
        stops colliding, has its weight carried and its velocity zeroed, so it stays put and
        falls asleep alone. Both the model's and the data's pose of the stand-in are set: with
        sleeping on, MuJoCo does not recompute static geoms' poses at every step."""
        self._whole_scene()
        model, data = self._model, self._data
        geoms, stand_ins = self._geom_ids[indices], self._frozen_geom_ids[indices]
        bodies = self._body_ids[indices]
        joints = model.body_jntadr[bodies]
        pose = data.qpos[model.jnt_qposadr[joints][:, None] + np.arange(7)]
        quat = pose[:, 3:] / np.linalg.norm(pose[:, 3:], axis=1, keepdims=True)
        model.geom_pos[stand_ins] = data.geom_xpos[stand_ins] = pose[:, :3]
        model.geom_quat[stand_ins] = quat
        data.geom_xmat[stand_ins] = _rotation_matrices(quat).reshape(-1, 9)
        model.geom_contype[stand_ins] = model.geom_conaffinity[stand_ins] = 1
        model.geom_contype[geoms] = model.geom_conaffinity[geoms] = 0
        model.body_contype[bodies] = model.body_conaffinity[bodies] = 0
        model.body_gravcomp[bodies] = 1.0
        data.qvel[(model.jnt_dofadr[joints][:, None] + np.arange(6)).ravel()] = 0.0
        self._frozen[indices] = True

    def _thaw(self, indices: np.ndarray) -> None:
        """Undo ``_freeze`` for boxes ``indices``: the box collides again, at the pose it was
        frozen in, at rest, under its weight; its stand-in goes off. A box still asleep stays
        asleep until an awake box touches it, as any sleeping box (see ``_regroup_sleep``)."""
        self._whole_scene()
        model = self._model
        geoms, stand_ins = self._geom_ids[indices], self._frozen_geom_ids[indices]
        bodies = self._body_ids[indices]
        model.geom_contype[stand_ins] = model.geom_conaffinity[stand_ins] = 0
        model.geom_contype[geoms] = model.geom_conaffinity[geoms] = 1
        model.body_contype[bodies] = model.body_conaffinity[bodies] = 1
        model.body_gravcomp[bodies] = 0.0
        self._frozen[indices] = False

    def _regroup_sleep(self) -> None:
        """Put the sleeping boxes in the sleep groups freezing and thawing need.

        MuJoCo keeps each sleeping island in a cycle of its trees (``tree_asleep``) and counts
        on a cycle holding every sleeping box its boxes touch: it wakes a touched cycle in one
        pass, and a woken box touching a box still asleep is an error. A box frozen while
        awake falls asleep alone, and thawed next to other sleeping boxes would break that. So
        after every freeze or thaw each sleeping frozen box sleeps alone (it touches nothing)
        and all the other sleeping placed boxes share one cycle: touching any wakes them all,
        which is more than MuJoCo would wake but never less. Only the links between sleeping
        trees change, so the engine's derived sleep state stays as it is."""
        model, data = self._model, self._data
        trees = model.body_treeid[self._body_ids]
        asleep = data.tree_asleep[trees] >= 0
        alone = trees[asleep & (self._frozen | ~self._placed)]
        data.tree_asleep[alone] = alone
        group = trees[asleep & self._placed & ~self._frozen]
        if group.size:
            data.tree_asleep[group] = np.roll(group, -1)

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        n = len(self._placed)
        positions = np.full((n, 3), np.nan)
        quats = np.full((n, 4), np.nan)
        placed = self._placed
        if placed.any():
            pose = self._data.qpos[self._pose_idx[placed]]
            positions[placed] = pose[:, :3] / _MM
            quats[placed] = pose[:, 3:]
        return positions, quats

    def _rasterise(self) -> np.ndarray:
        """The heightmap of all placed boxes, re-sampling only boxes that moved.

        A box's region is recomputed when it moved more than ``_REUSE_MM`` or turned more than
        ``_REUSE_QUAT`` since it was last sampled; smaller motions cannot change a whole-mm
        heightmap by more than rounding. The regions' maximum is kept: where only boxes not
        sampled before were added, they are maxed into it (the maximum is exact, so the result
        is the one over every region); where a sampled box moved, it is composed again.
        """
        positions, quats = self.poses()
        grid, cell = self._container.cells, self._container.cell_xy_mm
        placed = np.flatnonzero(self._placed)
        pose = np.concatenate([positions[placed], quats[placed]], axis=1)
        was = self._sampled_pose[placed]
        sampled = self._sampled[placed]
        moved = sampled & (
            (np.abs(was[:, :3] - pose[:, :3]).max(axis=1, initial=0.0) > _REUSE_MM)
            | (np.abs(was[:, 3:] - pose[:, 3:]).max(axis=1, initial=0.0) > _REUSE_QUAT)
        )
        stale = moved | ~sampled
        new_regions = []
        for i, row in zip(placed[stale].tolist(), pose[stale]):
            region = box_top_region(grid, cell, self._sizes_mm[i], row[:3], row[3:])
            self._regions[i] = region
            new_regions.append(region)
        self._sampled[placed[stale]] = True
        self._sampled_pose[placed[stale]] = pose[stale]
        if self._composed is None or moved.any():
            self._composed = np.zeros(grid, dtype=np.float64)
            new_regions = list(self._regions.values())
        return round_heightmap(max_regions_into(self._composed, new_regions))


class _SettleRegion:
    """Which boxes one placement's settle simulates (``PhysicsConfig.freeze``); the others are
    frozen (``MujocoBackend._freeze``).

    Simulated: every box that moved in the last ``freeze_still_steps`` steps (faster than
    ``freeze_speed_fraction`` of the rest thresholds, by velocity or net motion); every box whose
    axis-aligned collision bounds lie within ``freeze_margin_mm`` of one of those, plus how far
    that box can travel before the next check (its speed and a free fall over the check
    interval), so a frozen box thaws before anything reaches it; and every box resting on a
    simulated one, up to the top of the pile, so a frozen box never pins down or hangs above
    a box that moves. Frozen: the rest. A box at rest when the settle starts counts as still,
    so a drop onto a settled pile simulates the drop's neighbourhood only.
    """

    def __init__(
        self, backend: MujocoBackend, placed: np.ndarray, still: np.ndarray, span_s: float
    ) -> None:
        cfg = backend.config
        model = backend._model
        self._backend = backend
        self._placed = placed
        self._geoms = backend._geom_ids[placed]
        self._half = model.geom_size[self._geoms]
        quats = backend._data.qpos[
            model.jnt_qposadr[model.body_jntadr[backend._body_ids[placed]]][:, None]
            + np.arange(3, 7)
        ]
        # World half extents, from the quaternions here (the engine has not turned the dropped
        # box's yet), then refreshed from the engine's rotations for the boxes that move.
        self._extent = (np.abs(_rotation_matrices(quats)) @ self._half[:, :, None])[:, :, 0]
        self._window = cfg.freeze_still_steps
        self._margin = cfg.freeze_margin_mm * _MM
        # Until the next update a box falls, slides or is knocked this far beyond its speed now.
        self._span = span_s
        self._reach = 0.5 * abs(cfg.gravity) * span_s**2
        # Steps each box has been still: a box at rest when the settle starts counts as still
        # for the whole window, one moving then (a capped settle before) as just moved.
        self._still_steps = np.where(still, self._window, 0)

    def moved(self, moving: np.ndarray, steps: int) -> None:
        """Count ``steps`` steps after which ``moving`` (per placed box) says which moved."""
        self._still_steps = np.where(moving, 0, self._still_steps + steps)

    def update(self, poses: np.ndarray, speeds: np.ndarray) -> None:
        """Freeze the boxes outside the region, thaw the frozen ones inside it; ``poses``
        (n, 7) are the placed boxes' free-joint poses now and ``speeds`` (n,) their linear
        speeds (m/s)."""
        active = self._still_steps < self._window
        recent = np.flatnonzero(active)
        if recent.size == 0:
            return
        backend = self._backend
        extent, centre = self._extent, poses[:, :3]
        xmat = backend._data.geom_xmat[self._geoms[recent]].reshape(-1, 3, 3)
        extent[recent] = (np.abs(xmat) @ self._half[recent, :, None])[:, :, 0]
        reach = self._margin + self._reach + self._span * speeds[recent]
        gap = np.abs(centre[recent, None] - centre) - extent[recent, None] - extent
        near = (gap.max(axis=2) <= reach[:, None]).any(axis=0)
        # ... and every box resting on one of those, up to the top of the pile: a box frozen
        # on a simulated one would hold it down, or hang in the air once it slid away.
        gaps = np.abs(centre[:, None] - centre) - extent[:, None] - extent  # (n, n, 3)
        rests_on = (gaps[:, :, 0] < 0) & (gaps[:, :, 1] < 0) & (gaps[:, :, 2] <= self._margin)
        rests_on &= centre[:, None, 2] > centre[None, :, 2]  # [i, j]: i is above j
        while True:
            grown = near | rests_on[:, near].any(axis=1)
            if (grown == near).all():
                break
            near = grown
        frozen = backend._frozen[self._placed]
        thaw, freeze = frozen & near, ~(frozen | near | active)
        if thaw.any() or freeze.any():
            backend._thaw(self._placed[thaw])
            backend._freeze(self._placed[freeze])
            backend._regroup_sleep()

    def thaw_all(self) -> None:
        frozen = self._placed[self._backend._frozen[self._placed]]
        if frozen.size:
            self._backend._thaw(frozen)
            self._backend._regroup_sleep()


class _HeldBox:
    """The box in the gripper, as the place skill senses and moves it (``place_skill.HeldBox``):
    relative moves of its free-joint pose and the backend's contact readings. The skill never
    reads the pose itself; the snapshot is an opaque token it hands back.

    While the skill runs nothing moves but the held box (no step: its moves are kinematic), so
    a reading is a function of the held box's pose (and of which trees sleep), and two readings
    at one pose are the same reading. It keeps two memos, neither of which changes a result:

    * the held box's pose at its last collision (``_collided``) and the depth it read there:
      asked again at that pose (the descent's test, then its wrench; a side load, then how far
      to back off), the depth is that one, and ``data.contact`` still lists the box's contacts
      at that pose (those of a collision of the box alone, or of the solve there that followed
      it: the same contacts, bit for bit, ``MujocoBackend._collide_with``);
    * the contacts each solve (``mj_forward``) read, by the state the solve started from: the
      held box's pose and the sleep state (``_solves``). The only state a solve writes is the
      sleep state (it wakes the sleeping boxes the held box touches; ``qacc_warmstart`` is
      written by ``mj_step`` only), so one started from the same state reads the same forces,
      bit for bit, and wakes nothing more: the wrench the descent reads and the side load its
      flush turn reads next at the same pose, a pose a search or a bisection comes back to.

    A side load with nothing across a side, or one the skill does not need (``skip_side_load``),
    reads no solve; the position stage stands in for it (``_unsolved``), so the sleep state
    stays the one the solve would have left.
    """

    def __init__(self, backend: MujocoBackend, index: int) -> None:
        self._backend = backend
        self._data = backend._data
        self._qpos = backend._data.qpos  # a view of the episode's state, updated in place
        self._geom = int(backend._geom_ids[index])
        self._address = backend._qpos_slice(index).start
        self._pose = backend._qpos_slice(index)
        body = backend._body_ids[index]
        self._weight = float(backend._model.body_mass[body]) * abs(backend.config.gravity)
        self._collided: bytes | None = None  # the pose (qpos bytes) of the last collision
        self._depth = 0.0  # the penetration read there
        self._solves: dict[bytes, _SolvedContacts] = {}
        self._positioned: set[bytes] = set()  # states a position stage started from

    @property
    def weight(self) -> float:
        return self._weight

    def snapshot(self) -> np.ndarray:
        return np.array(self._qpos[self._pose])

    def restore(self, token: np.ndarray) -> None:
        self._qpos[self._pose] = token

    def moved_since(self, token: np.ndarray) -> np.ndarray:
        # The free joint's first three entries are the position; its move is the gripper's.
        return np.array(self._qpos[self._address : self._address + 2] - token[:2])

    def translate(self, dx: float, dy: float, dz: float) -> None:
        self._qpos[self._address : self._address + 3] += (dx, dy, dz)

    def turn(self, angle: float, pivot: np.ndarray) -> None:
        qpos = self._qpos
        qpos[self._pose] = _pivoted(qpos[self._pose].copy(), pivot, angle)

    def turned_from(self, token: np.ndarray, angle: float, pivot: np.ndarray, axis: int) -> None:
        out = _pivoted(token, pivot, angle)
        out[1 - axis] = token[1 - axis]
        self._qpos[self._pose] = out

    def penetration(self) -> float:
        pose = self._qpos[self._pose].tobytes()
        if pose != self._collided:
            self._depth = self._backend._penetration(self._geom)
            self._collided = pose
        return self._depth

    def _state(self) -> bytes:
        """The state a solve at the held box's pose starts from: its pose (as last collided)
        and which trees sleep."""
        assert self._collided is not None
        data = self._data
        return self._collided + data.tree_asleep.tobytes() + data.body_awake.tobytes()

    def _contacts(self) -> _SolvedContacts | None:
        """The held box's contacts solved at its pose (None: it touches nothing), from the
        memo where a solve started from this state before."""
        if self.penetration() <= 0.0:
            return None
        state = self._state()
        solved = self._solves.get(state)
        if solved is None:
            solved = self._solves[state] = self._backend._solved_contacts(self._geom)
        return solved

    def _unsolved(self) -> None:
        """A reading that a solve at this pose would have preceded but needs none: where the
        box touches something, the position stage stands in for the solve
        (``MujocoBackend._position_stage``: the sleep state it leaves). Not where a solve or
        a position stage started from this very state before: that one woke nothing (a woken
        tree stays awake while the skill runs, so the state could not recur), and neither
        would this."""
        if self.penetration() <= 0.0:
            return
        state = self._state()
        if state not in self._solves and state not in self._positioned:
            self._backend._position_stage()
            self._positioned.add(state)

    def deepest_across(self, axis: int) -> tuple[float, float]:
        self.penetration()
        return self._backend._deepest_across(self._geom, axis, collided=True)

    def side_load(self) -> tuple[np.ndarray, float, np.ndarray]:
        backend = self._backend
        if self.penetration() > 0.0 and not backend._side_contact(self._geom):
            self._unsolved()  # nothing across a side: the solve's reading would sum nothing
            return backend._side_load(self._geom, self._address, None)
        return backend._side_load(self._geom, self._address, self._contacts())

    def skip_side_load(self) -> None:
        """The skill does not read the side load it would have read here (its answer is
        known): the state is left as that reading leaves it."""
        self._unsolved()

    def wrench(self, axis: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
        return self._backend._wrench(self._geom, self._address, axis, self._contacts())

    def touching(self) -> set[int]:
        self.penetration()  # the contacts at the pose now (no collision if they are listed)
        return self._backend._touching(self._geom)

    def touching_back(self, axis: int) -> float:
        self.penetration()
        return self._backend._touching_back(self._geom, axis, collided=True)
