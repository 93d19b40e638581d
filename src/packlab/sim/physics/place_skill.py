"""The robot's place skill: compliant guarded descent, seating, release.

The skill decides only from what the robot knows: the command in its own belief
(``PlaceCommand``: the target centre from the perceived footprint, the chosen rotation, the
target bottom from the perceived heightmap, the perceived box height, the seat sides read from
the observed heightmap) and what its wrist's force-torque sensor reads while it holds the box
(``HeldBox``). It never reads the box's true pose, size or the scene: it moves the gripper by
relative motions (the box moves rigidly with it) and reads contact wrenches. The simulator
maps the command onto the true box (grasp error, arm noise, true height: physics, see
``MujocoBackend.execute``) and implements ``HeldBox``.

Moves are kinematic and quasi-static: every reading is taken with the held box at rest in the
gripper, its weight carried (gravity compensated), as a slow guarded move would read it.

1. **Descent** (``descend``). A command whose release pose touches nothing is released there
   (the usual drop onto a flat stack: the descent met nothing on the way). Otherwise the box
   is lowered from above what the robot sees (``APPROACH_MM`` over the heightmap's top) in
   ``_DESCENT_STEP_MM`` steps, stopping at each contact to read the wrench:

   * a mostly horizontal contact force (a wall, a tilted neighbour's face) lets the compliant
     wrist slide the box along it, and a contact torque about z turns it (yaw compliance):
     pressed into a face with a corner first, it turns flush with that face as in seating
     (``flush_turn``), unless the turn would press it harder into something else; otherwise
     it moves along the generalised force (force, torque / radius) by the contact's depth, at
     most ``_SLIDE_STEP_MM``, at most ``comply_mm`` from the command in all; the descent then
     goes on;
   * a contact that carries the box (mostly vertical force) above its target is a ledge: when
     the support's centre of pressure lies near one edge of the box as the robot believes it
     (within ``comply_mm`` + ``_EDGE_MARGIN_MM`` of its perceived footprint's edge, off its
     middle) the box is landing on a neighbour's edge, and the rounded edges of cartons turn
     part of the reaction outward, so the compliant wrist slides the box off it, away from
     the edge (within the same budget);
   * carried with no edge to read (two edges at once, a corner), the skill searches as a robot
     searches for a slot it cannot see (``_probe``): guarded lateral moves on rings around the
     touching pose, each followed by a guarded try to go lower, then the same with the gripper
     turned by small steps either way (a box a little turned in a slot with no slack fits only
     turned back); the first move from which the descent can go on is taken;
   * otherwise (a support under the box, the budget spent) the descent stops. Stopped more
     than ``retry_margin_mm`` above its release pose (the gripper's height against the
     command, all the robot knows of it), the box is lifted back above everything and the
     descent tried again from the command with a fresh draw of the arm's noise, drawn and
     applied by the simulator (``place``'s ``retry``), at most ``PLACE_RETRIES`` times; then
     it is released where it is (physics decides what happens then), or, where the robot's
   settings say so (``set_aside_stuck``, both presets), taken back out and set aside.

   Nothing squares the yaw or moves the box to the planned pose: no code here knows either.
2. **Seat** (``seat``). Pushes toward the sides the observed heightmap shows flush, guarded
   moves that stop on contact force, turned flush by the contact's torque. The reach is
   measured from the commanded pose plus the skill's own moves (what the robot knows of where
   it holds the box), never from the planned pose the noise moved it off.
3. **Release**: the caller (``MujocoBackend.execute``) lets go and settles.

``SkillReport`` counts what the skill had to do (recoveries) per placement; the episode puts
it in the step record (``skill``) and sums it per episode (``metrics.skill``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Protocol

import numpy as np

_MM = 1e-3  # metres per millimetre
#: A box may touch what is around it this deep (mm) and count as touching nothing: the
#: simulator's contacts and the heightmap's sampling leave that much.
LIFT_TOLERANCE_MM = 0.1
#: The descent starts with the box's bottom this far (mm) above the highest point the robot
#: sees in the container (the heightmap's top cell): over the few mm a cell-centre heightmap
#: can miss of a tilted edge.
APPROACH_MM = 20.0
_DESCENT_STEP_MM = 2.0  # the descent's step; a contact met within one is found to the tolerance
_SLIDE_STEP_MM = 0.5  # a compliant slide's step
#: An edge landing: the centre of pressure of a contact that carries the box lies off its
#: middle and within ``comply_mm`` plus this margin of the edge, as the
#: robot believes it (its command plus its own moves): a strip of overlap with a neighbour's
#: top narrow enough for the wrist to slide off within its budget. A support spread under the
#: box puts it well inside. The margin covers the grasp and arm errors between the believed and
#: the true edge (a few mm).
_EDGE_MARGIN_MM = 5.0
#: How far (deg) the wrist's yaw compliance lets a contact's torque turn the held box, in the
#: descent (in all, beyond arm errors) and in each seating turn (``flush_turn``): one limit of
#: one wrist. With a 5 deg limit in seating, under the stereo preset (3 deg arm yaw error) a
#: box that landed more than 5 deg off square could not be turned flush against a whole face,
#: stayed turned and narrowed its neighbours' slots (traced: a 375 mm box left at -5.8 deg took
#: 19 mm of the next slot, and the two boxes planned there were set aside). 10 deg against 5,
#: on 72 generated layered training cases (3 seeds, plan-fast): stereo +0.012 [+0.001,
#: +0.023]; structured light (1 deg) -0.001 [-0.003, +0.001]; 8 and 15 deg scored about the
#: same as 10 on stereo (0.953 and 0.951 against 0.954, two seeds).
WRIST_YAW_YIELD_DEG = 10.0
_DESCENT_MAX_MOVES = 400  # a bound on the descent's loop
#: The probe's turns (``_probe``): steps, and the lateral reach tried at each. A box that lands
#: on two neighbours' edges at once, turned a degree or more, fits its slot only turned back
#: *and* moved by its xy error (stereo: 5-12 mm); 12 mm, chosen on generated training cases
#: (against 2 mm: stereo +0.014 [+0.005, +0.025], structured light +0.008 [+0.000, +0.018];
#: 6 mm +0.008, the whole slide budget +0.013).
_PROBE_TURN_DEG = 0.25
_PROBE_TURN_REACH_MM = 12.0

_SEAT_STEP_MM = 0.25  # step of the guarded push
#: The guarded push stops when the contacts on the held box push back along the push axis with
#: more than this many times the box's weight (its gravity is carried by the gripper while it
#: pushes, so the reading is the side contacts' alone). The robot knows its payload's weight
#: (its wrist sensor weighs it at the pick), so the threshold scales with it: MuJoCo's soft
#: contacts push back in proportion to the held mass times the depth (about 3.9 weights per mm
#: against a wall or a heavier box, at the backend's solref/solimp), so 0.5 weights stops about
#: 0.13 mm into a contact for any box, from the bench's 0.28 kg boxes to its 97 kg ones. That is
#: just past the 0.1 mm a box may already touch at (``LIFT_TOLERANCE_MM``), so a box resting
#: lightly on one side is not stopped before it moves, and far above the zero a box touching
#: nothing feels. A fixed force would stop the heavy boxes at the first touch and let the light
#: ones press in several times deeper.
_SEAT_FORCE_WEIGHTS = 0.5
#: A held box pushed into a face with a corner first is turned by the contact's torque (a
#: wrist compliant in yaw) until its face is flush (``flush_turn``): by at most
#: ``WRIST_YAW_YIELD_DEG`` per contact (beyond the arm's and the estimate's yaw errors), found
#: to 10 deg / 2**12 (0.002 deg), at most _SEAT_TURNS times per push, turns under
#: _SEAT_MIN_TURN rad (0.003 deg) not taken.
_SEAT_TURN_BISECTIONS = 12
_SEAT_TURNS = 4
_SEAT_MIN_TURN = 5e-5
#: Pushes toward the seat sides go round twice. A first-round push can end short of its face
#: while the box still touches a face across the other axis (traced: a box that had slid off a
#: neighbour's edge across y in its descent was left 2.9 mm off its -x face, and the last box
#: of that row no longer fitted); once the other axis's push has seated it there, the second
#: round's push reaches the face. The second round only translates: its turns would undo the
#: first round's squaring.
_SEAT_PASSES = 2
#: A descent that stopped more than this far above its release pose (a fraction of the box's
#: shown height, at least ``_RETRY_MIN_MM``: over the few mm the observed heightmap and a
#: tilted edge between cell centres can put the true support above the target) stopped on
#: something it was not meant to rest on (mostly a neighbour's edge under a box yawed in a slot
#: with no slack): the robot lifts the box and tries again, up to ``PLACE_RETRIES`` times. Read
#: from the command and the arm's own height only.
_RETRY_ABOVE_FRACTION = 0.2
_RETRY_MIN_MM = 10.0
PLACE_RETRIES = 2


@dataclass(frozen=True, slots=True)
class PlaceCommand:
    """A placement as the robot commands it, in its own belief (mm, container frame).

    Built from what the robot knows only (``packlab.sim.episode``): the perceived size it was
    shown, the policy's choice and the heightmap it observed. The gripper holds the box's top
    face, so it lowers the top to ``bottom_mm + height_mm + release_mm``.
    """

    centre_mm: tuple[float, float]  # the drop corner plus half the perceived footprint
    footprint_mm: tuple[float, float]  # perceived footprint (x, y) under the chosen rotation
    bottom_mm: float  # target bottom: Eq. 2 height on the observed heightmap
    height_mm: float  # perceived box height
    release_mm: float  # the gripper opens this far above the target
    #: The highest point the robot sees in the container (the observed heightmap's top): the
    #: descent starts ``APPROACH_MM`` above it.
    seen_top_mm: float
    comply_mm: float = 0.0  # how far in all the compliant wrist may slide the box
    seat_mm: float = 0.0  # how far past the command a guarded push may go
    seat_sides: tuple[int, int] = (0, 0)  # per axis -1, +1 or 0 (``execution.seat_sides``)
    #: Per axis, whether that seat side is a face along the whole footprint
    #: (``execution.full_faces``): only such a face turns the box flush in seating.
    full_faces: tuple[bool, bool] = (True, True)
    #: After its last try the descent still stopped more than ``retry_margin_mm`` above the
    #: release pose: take the box back out and set it aside (``SkillReport.set_aside``) rather
    #: than let it go on what it stopped on, mostly a neighbour's top, where it would ruin the
    #: layer for every box after it. False: let it go there.
    set_aside_stuck: bool = False


@dataclass(slots=True)
class SkillReport:
    """What the place skill had to do for one placement: 1 (or, for pushes and seat turns,
    how many) when it happened, 0 when not needed."""

    #: The release pose was in contact: the box was lowered from above by a guarded descent.
    descended: int = 0
    #: The wrist slid the box along a mostly horizontal contact force (a wall, a tilted face).
    slid: int = 0
    #: The wrist slid the box off a neighbour's edge it was landing on.
    slid_off_edge: int = 0
    #: A slide also turned the box (contact torque, yaw compliance).
    turned: int = 0
    #: The descent stopped on a contact that carried the box above its target: released there.
    stopped_high: int = 0
    #: Guarded pushes that met a face (seated flush) and that met nothing (back to the start).
    seated: int = 0
    push_missed: int = 0
    #: Turns flush with a face during seating (contact torque).
    seat_turned: int = 0
    #: The slides spent their budget (``comply_mm``) before the box was clear.
    budget_spent: int = 0
    #: Carried above its target with no edge to read, the box was moved aside by a guarded
    #: search (lateral moves, each followed by a guarded try to go lower) and went on down.
    probed: int = 0
    #: Not the skill's doing: the box was let go still pressed into something (its slides
    #: spent) and the simulator raised it clear (``MujocoBackend._lift_clear``: a box never
    #: starts inside another, in exact execution too).
    lifted: int = 0
    #: The descent stopped well above its target (``retry_margin_mm``): the box was lifted
    #: back above everything and placed again from the command, the arm's repeatability error
    #: drawn afresh (``place``); how many times.
    retried: int = 0
    #: Still stopped high after the last try (``PlaceCommand.set_aside_stuck``): the box was
    #: taken back out and set aside, not let go; it counts as unpacked.
    set_aside: int = 0

    def counts(self) -> dict[str, int]:
        """The nonzero counts by name (what records keep)."""
        return {k: v for k, v in asdict(self).items() if v}


class HeldBox(Protocol):
    """The box in the gripper, as the skill may act on it and sense it (``MujocoBackend``).

    Moves are relative (the gripper moves; the box follows rigidly); readings are what a wrist
    force-torque sensor and the arm's own joints give. Positions handed back (a centre of
    pressure) are in the container frame, metres.
    """

    @property
    def weight(self) -> float:
        """The payload's weight (N): the wrist weighs it at the pick."""
        ...

    def snapshot(self) -> np.ndarray:
        """An opaque token of the gripper's pose, for ``restore``."""
        ...

    def restore(self, token: np.ndarray) -> None: ...

    def moved_since(self, token: np.ndarray) -> np.ndarray:
        """How far (m, x and y) the gripper has moved since the pose of ``token``: what the
        arm's joints read of its own moves."""
        ...

    def translate(self, dx: float, dy: float, dz: float) -> None:
        """Move the gripper (and the box) by (dx, dy, dz) metres."""
        ...

    def turn(self, angle: float, pivot: np.ndarray) -> None:
        """Turn the gripper by ``angle`` radians about the vertical line through ``pivot``."""
        ...

    def turned_from(self, token: np.ndarray, angle: float, pivot: np.ndarray, axis: int) -> None:
        """The pose of ``token`` turned about ``pivot``, its centre held across ``axis``."""
        ...

    def penetration(self) -> float:
        """How deep (m) the box is pressed into anything: the contact's depth, read as the
        compliant wrist's deflection under a stiff contact."""
        ...

    def deepest_across(self, axis: int) -> tuple[float, float]:
        """Deepest press (m) into a contact whose normal lies along ``axis``, and the way out
        of it along the axis (+1, -1; 0, 0 if none)."""
        ...

    def side_load(self) -> tuple[np.ndarray, float, np.ndarray]:
        """Force (N, x and y), torque about z (N m) and centre of pressure (m, x and y) of the
        contacts with a mostly horizontal normal (what the box is pushed against)."""
        ...

    def wrench(self, axis: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
        """Force (N, x, y, z) of every contact on the box, their torque (N m) about the
        vertical line through ``axis`` (m, x and y: the wrist's axis), and the centres of
        pressure (m, x and y) of its side contacts and of its support: what the wrist's
        force-torque sensor resolves."""
        ...

    def touching(self) -> set[int]:
        """Which contacts across a side the box touches (a new one shows as a new element), at
        its pose now."""
        ...

    def touching_back(self, axis: int) -> float:
        """How far (m) the box pressed into what it met along ``axis`` backs off to touch."""
        ...

    def skip_side_load(self) -> None:
        """The skill would read the side load here but knows its answer already: the
        simulator leaves its state as that reading would (sensing has no effect on a robot;
        the simulator's solve wakes the sleeping boxes the held box touches)."""
        ...


# -- the descent -------------------------------------------------------------------------------


def descend(held: HeldBox, command: PlaceCommand, report: SkillReport) -> np.ndarray:
    """Lower the held box to its release pose by a compliant guarded descent (module
    docstring); returns the gripper's moves (x, y in mm) from the command, which the robot
    knows from its own joints. The box is left at its release pose or where the descent
    stopped, touching at most ``LIFT_TOLERANCE_MM``."""
    return _descend(held, command, report)[0]


def _descend(held: HeldBox, command: PlaceCommand, report: SkillReport) -> tuple[np.ndarray, float]:
    """``descend``, also returning how far (m) above its release pose the gripper stopped:
    what the arm's joints tell the robot of its own height against the command."""
    if held.penetration() <= LIFT_TOLERANCE_MM * _MM:
        return np.zeros(2), 0.0
    report.descended = 1
    release = command.bottom_mm + command.release_mm
    rise = max(0.0, command.seen_top_mm + APPROACH_MM - release) * _MM
    held.translate(0.0, 0.0, rise)
    return _Descent(held, command, report, below=rise).run()


#: What one contact step of the descent asks next (``_Descent._carried``): go on, or stop.
_AGAIN, _STOP = "again", "stop"


class _Descent:
    """The state of one compliant guarded descent (``_descend``): where the gripper moved from
    the command (mm), how far (m) above its release pose the box still is, how far it turned,
    and how many flush turns the wrist still tries."""

    def __init__(
        self, held: HeldBox, command: PlaceCommand, report: SkillReport, below: float
    ) -> None:
        self.held, self.command, self.report = held, command, report
        self.moved = np.zeros(2)  # mm
        self.below = below
        self.turned = 0.0
        self.half = np.array(command.footprint_mm) / 2
        self.radius = float(np.hypot(*self.half))  # mm: the yaw compliance's radius
        self.flushes_left = _SEAT_TURNS

    def run(self) -> tuple[np.ndarray, float]:
        tol = LIFT_TOLERANCE_MM * _MM
        held, report = self.held, self.report
        for _ in range(_DESCENT_MAX_MOVES):
            depth = held.penetration()
            if depth <= tol:
                if self.below <= 1e-9:
                    return self.moved, self.below
                down = min(_DESCENT_STEP_MM * _MM, self.below)
                held.translate(0.0, 0.0, -down)
                self.below -= down
                continue
            gripper = np.array(self.command.centre_mm) + self.moved
            force, torque, side_pressure, support_pressure = held.wrench(gripper * _MM)
            across = float(math.hypot(force[0], force[1]))
            sideways = across > force[2]  # pushed sideways (a wall, a tilted face), or carried
            # The centre of pressure from the gripper's axis (mm): of the side contacts when the
            # box is pushed sideways, of the support when it is carried.
            lever = (side_pressure if sideways else support_pressure) / _MM - gripper
            push = force[:2] / across if sideways else np.zeros(2)
            if sideways:
                report.slid = 1
                flushed, torque = self._turn_flush(push, torque, depth)
                if flushed:
                    continue
            else:
                outcome = self._carried(depth, lever, gripper)
                if isinstance(outcome, str):
                    if outcome == _STOP:
                        return self.moved, self.below
                    continue  # _AGAIN
                push = outcome
            if float(np.hypot(*self.moved)) + _SLIDE_STEP_MM > self.command.comply_mm + 1e-9:
                report.budget_spent = 1
                if not sideways:
                    report.stopped_high = 1  # left on the edge it could not slide off
                return self.moved, self.below
            self._slide(force, torque, push, lever, gripper, depth, sideways)
        report.stopped_high = 1
        return self.moved, self.below

    def _turn_flush(self, push: np.ndarray, torque: float, depth: float) -> tuple[bool, float]:
        """Pressed into a face with a corner first, the contact's torque turns the box flush
        with it (yaw compliance), as in seating: whether it turned, and the torque (N m) the
        side contacts now read (what the slide then yields to)."""
        if not self.flushes_left:
            return False, torque
        held = self.held
        axis = 0 if abs(push[0]) >= abs(push[1]) else 1
        _, torque, pivot = held.side_load()
        flush = flush_turn(held, axis, torque, pivot)
        self.flushes_left -= 1
        if flush is not None:
            pressed = held.snapshot()
            held.restore(flush)
            if held.penetration() <= depth + LIFT_TOLERANCE_MM * _MM:
                self.report.turned = 1
                return True, torque
            # The turn would press the box harder into something (a second wall, a
            # neighbour): the wrist cannot turn against that contact.
            held.restore(pressed)
        return False, torque

    def _carried(self, depth: float, lever: np.ndarray, gripper: np.ndarray) -> str | np.ndarray:
        """The box is carried by what it met (the contact is under it, its depth along z):
        back up to the touch, then slide off the edge it rests on (the direction to push), or
        probe around for where the descent can go on (``_AGAIN``), or stop (``_STOP``)."""
        held, report = self.held, self.report
        self.below += _back_to_touch(held, depth)
        if self.below <= 1e-9:
            return _STOP  # at the release pose after all
        budget = self.command.comply_mm
        away = _off_edge(lever, self.half, budget + _EDGE_MARGIN_MM)
        if away is not None:
            report.slid_off_edge = 1
            return away
        # No edge to read: probe around for where the descent can go on.
        room = math.radians(WRIST_YAW_YIELD_DEG) - abs(self.turned)
        found = _probe(held, budget - float(np.hypot(*self.moved)), gripper, room)
        if found is None:
            report.stopped_high = 1
            return _STOP
        shift, angle = found
        if angle:
            held.turn(angle, gripper * _MM)
            self.turned += angle
            report.turned = 1
        held.translate(shift[0] * _MM, shift[1] * _MM, 0.0)
        self.moved += shift
        report.probed = 1
        return _AGAIN

    def _slide(
        self,
        force: np.ndarray,
        torque: float,
        push: np.ndarray,
        lever: np.ndarray,
        gripper: np.ndarray,
        depth: float,
        sideways: bool,
    ) -> None:
        """One compliant step. A side contact yields by its depth (the wrist's deflection under
        a stiff contact), so a box in a slot with little slack settles in it instead of
        bouncing between its faces; an edge is slid off in whole steps. The side forces and
        their torque about the wrist turn the box too (a box wedged between two faces feels a
        couple: little net force, a torque that turns it)."""
        length = min(_SLIDE_STEP_MM, max(depth / _MM, LIFT_TOLERANCE_MM))
        if sideways:
            step, angle = _compliant_step(force[:2], torque / _MM, self.radius, length)
        else:
            step, angle = _compliant_step(push, None, self.radius, None, lever)
        if abs(self.turned + angle) > math.radians(WRIST_YAW_YIELD_DEG):
            angle = 0.0
        self.held.translate(step[0] * _MM, step[1] * _MM, 0.0)
        self.moved += step
        if angle:
            self.held.turn(angle, (gripper + step) * _MM)
            self.turned += angle
            self.report.turned = 1


def _back_to_touch(held: HeldBox, depth: float) -> float:
    """Raise the box pressed ``depth`` (m) into what carries it until it touches at most the
    tolerance; returns how far (m) it went up."""
    tol = LIFT_TOLERANCE_MM * _MM
    up = 0.0
    for _ in range(8):
        if depth <= tol:
            break
        lift = max(depth - tol / 2, 0.05 * _MM)
        held.translate(0.0, 0.0, lift)
        up += lift
        depth = held.penetration()
    return up


def _probe(
    held: HeldBox, budget_mm: float, gripper_mm: np.ndarray, turn_left: float
) -> tuple[np.ndarray, float] | None:
    """A guarded search around a box carried above its target (touching what carries it),
    as a robot searches for a slot it cannot see: the nearest lateral move (rings of
    ``_SLIDE_STEP_MM``, 8 directions, within ``budget_mm``) from which a guarded move down by
    ``_DESCENT_STEP_MM`` meets nothing, each move from the touching pose and itself touching
    nothing (a side it would meet blocks that direction); failing that, the same with the
    gripper turned about its axis (``gripper_mm``) by ``_PROBE_TURN_DEG`` steps either way,
    within ``turn_left`` radians and ``_PROBE_TURN_REACH_MM`` of lateral moves: a box a little
    turned in a slot with no slack fits once turned back. Returns the move (mm) and turn
    (rad) with the box back where it was, or None."""
    tol = LIFT_TOLERANCE_MM * _MM
    start = held.snapshot()
    angles = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    pivot = gripper_mm * _MM

    def search(angle: float, reach_mm: float) -> np.ndarray | None:
        blocked = np.zeros(8, dtype=bool)
        radius = 0.0 if angle else _SLIDE_STEP_MM
        # Every try starts from the touching pose turned by ``angle``: turned once, restored.
        held.restore(start)
        if angle:
            held.turn(angle, pivot)
        origin = held.snapshot()
        while radius <= reach_mm + 1e-9 and not blocked.all():
            for k, d in enumerate(directions[: 1 if radius == 0 else 8]):
                if blocked[k]:
                    continue
                held.restore(origin)
                held.translate(d[0] * radius * _MM, d[1] * radius * _MM, 0.0)
                if held.penetration() > tol:
                    blocked[k] = radius > 0  # a side met: no farther this way
                    continue
                held.translate(0.0, 0.0, -_DESCENT_STEP_MM * _MM)
                clear = held.penetration() <= tol
                if clear:
                    held.restore(start)
                    return d * radius
            radius += _SLIDE_STEP_MM
        return None

    found = search(0.0, budget_mm)
    if found is not None:
        held.restore(start)
        return found, 0.0
    step = math.radians(_PROBE_TURN_DEG)
    for k in range(1, int(turn_left / step + 1e-9) + 1):
        for angle in (k * step, -k * step):
            found = search(angle, min(budget_mm, _PROBE_TURN_REACH_MM))
            if found is not None:
                held.restore(start)
                return found, angle
    held.restore(start)
    return None


def _compliant_step(
    force: np.ndarray,
    torque: float | None,
    radius_mm: float,
    length_mm: float | None = None,
    lever_mm: np.ndarray | None = None,
) -> tuple[np.ndarray, float]:
    """One step of the compliant wrist under a contact ``force`` (x, y) and ``torque`` about
    its axis (N mm; None: the force applied at ``lever_mm`` from the axis): the move (x, y mm)
    and turn (rad) along the generalised force (force, torque / radius), ``length_mm``
    (default ``_SLIDE_STEP_MM``) long in that metric. The same stiffness for moves and for
    turns at ``radius_mm`` (the box's half diagonal): a push through the axis slides the box,
    one at a corner also turns it, a couple only turns it."""
    if torque is None:
        assert lever_mm is not None
        torque = float(lever_mm[0] * force[1] - lever_mm[1] * force[0])
    generalised = np.array([force[0], force[1], torque / radius_mm])
    length = _SLIDE_STEP_MM if length_mm is None else length_mm
    step = length * generalised / float(np.linalg.norm(generalised))
    return step[:2], float(step[2] / radius_mm)


def _off_edge(offset_mm: np.ndarray, half_mm: np.ndarray, band_mm: float) -> np.ndarray | None:
    """The unit direction (x, y) away from an edge landing, from the centre of pressure's
    ``offset_mm`` from the gripper's centre and the perceived half footprint: per axis, away
    from a side whose edge the pressure lies within ``band_mm`` of (and off the middle
    quarters: the simulator's contact points of a small corner overlap lie inside it);
    None when the pressure is not at an edge (a support under the box)."""
    direction = np.zeros(2)
    for axis in (0, 1):
        inside = half_mm[axis] - abs(offset_mm[axis])
        if inside <= band_mm and abs(offset_mm[axis]) > half_mm[axis] / 4:
            direction[axis] = -math.copysign(1.0, offset_mm[axis])
    norm = float(np.hypot(*direction))
    return None if norm == 0 else direction / norm


# -- seating ------------------------------------------------------------------------------------


def seat(held: HeldBox, command: PlaceCommand, moved_mm: np.ndarray, report: SkillReport) -> None:
    """Push the held box toward ``command.seat_sides`` by guarded moves.

    A placement is planned flush against walls or boxes on some sides (on the -x and -y sides
    for a minimum-corner rule like DBLF's, anywhere for others); the skill pushes the box
    toward those sides as it lowers it, so execution errors do not add up along a row. Which
    sides is the caller's decision from what the robot observed
    (``packlab.sim.execution.seat_sides``); nothing here looks for what is there. Per axis
    the held box moves in ``_SEAT_STEP_MM`` steps until the contacts push back harder than
    ``_SEAT_FORCE_WEIGHTS`` of its weight (``guarded_push``), at most ``seat_mm`` past the
    commanded pose, measured from where the robot holds it (the command plus the descent's
    moves ``moved_mm``: its own joints, not the noise); a push that meets nothing returns the
    box to where it started. The pushes go round twice (``_SEAT_PASSES``).

    The yaw keeps its error unless a contact's torque turns it, and only a face along the
    whole footprint may turn it (``command.full_faces``, read from the observed heightmap): a
    neighbour under part of a face, off the box's centre, turns the box about the neighbour's
    end and leaves it a few tenths of a degree off square, which narrows the next slot of a
    layout with no slack by a millimetre or two.
    """
    threshold = _SEAT_FORCE_WEIGHTS * held.weight
    start = held.snapshot()
    for seat_pass in range(_SEAT_PASSES):
        # Where the robot holds the box now against the command (its own moves, in mm).
        held_at = np.asarray(moved_mm, float) + held.moved_since(start) / _MM
        for axis, side in enumerate(command.seat_sides):
            if not side:
                continue
            past = side * float(held_at[axis])  # how far it was already taken that way
            reach = max(0.0, -past) + command.seat_mm
            # Turns on the first pass only, and only against a face along the whole footprint.
            turns = _SEAT_TURNS if seat_pass == 0 and command.full_faces[axis] else 0
            met = guarded_push(held, axis, side, reach, threshold, report, turns)
            if met:
                report.seated += 1
            else:
                report.push_missed += 1
    for axis in (0, 1):  # a later push or turn may have pressed a side pushed earlier
        relax(held, axis, command.seat_mm + 2.0)


def guarded_push(
    held: HeldBox,
    axis: int,
    side: int,
    reach_mm: float,
    threshold: float,
    report: SkillReport,
    turns: int = _SEAT_TURNS,
) -> bool:
    """Move the held box toward ``side`` of ``axis`` in ``_SEAT_STEP_MM`` steps, at most
    ``reach_mm``, until the step would make the contacts push back along the axis harder than
    ``threshold`` (N). There it stays at the last step under the threshold, first letting the
    contact's torque turn it flush with the face it met (``flush_turn``, a few times while
    that lets it go on), and returns True; with nothing met it goes back to its start and
    returns False."""
    start = held.snapshot()
    moved, step, turns_left = 0.0, side * _SEAT_STEP_MM * _MM, turns
    shift = np.zeros(3)
    shift[axis] = step
    while True:
        if moved + _SEAT_STEP_MM > reach_mm + 1e-9:
            held.restore(start)
            return False
        held.translate(*shift)
        force, torque, pivot = held.side_load()
        if -side * force[axis] <= threshold:
            moved += _SEAT_STEP_MM
            continue
        rest = side * held.touching_back(axis)  # back off this far from the pressed pose
        turned = flush_turn(held, axis, torque, pivot) if turns_left else None
        held.translate(*(-shift))  # back to the last pose under the threshold
        if turned is None:
            break
        backed = held.snapshot()
        held.restore(turned)
        if not back_off(held, axis, side, threshold):
            held.restore(backed)  # the turn presses the other side (a wall seated on)
            break
        report.seat_turned += 1
        turns_left -= 1
    # From the last pose under the threshold to the touching one: the pressed pose was one
    # step further, and backing off ``touching_back`` from there touches.
    delta = np.zeros(3)
    delta[axis] = step - rest
    held.translate(*delta)
    return True


def back_off(held: HeldBox, axis: int, side: int, threshold: float) -> bool:
    """Back a just-turned box (turned pressed into what it met) off along ``axis`` by
    ``_SEAT_STEP_MM`` steps (at least one, at most three) until the contacts push back
    along it with at most ``threshold``, a turned box bearing at both ends of its face
    bears twice; return whether the other axis is then under the threshold too."""
    shift = np.zeros(3)
    shift[axis] = -side * _SEAT_STEP_MM * _MM
    for _ in range(3):
        held.translate(*shift)
        force = held.side_load()[0]
        if -side * force[axis] <= threshold:
            break
    return abs(force[1 - axis]) <= threshold and -side * force[axis] <= threshold


def flush_turn(held: HeldBox, axis: int, torque: float, pivot: np.ndarray) -> np.ndarray | None:
    """The pose token a wrist compliant in yaw lets the contact's ``torque`` give the held box,
    pressed into what it met: turned in the torque's sense, the arm holding its centre across
    ``axis`` and letting it follow the contact (``pivot``, the centre of pressure) along it, up
    to where the torque reverses (the face is flush, bearing at both ends), found by bisection
    within ``WRIST_YAW_YIELD_DEG``. None when it does not reverse there (a corner against a
    corner: nothing flat to turn flush with), when the turn runs into something other than
    what it met first (a neighbour bearing on part of the face only would turn the box until
    its far end met a wall), or the turn is under ``_SEAT_MIN_TURN``. Leaves the box's pose as
    it was."""
    pressed = held.snapshot()
    sense = math.copysign(1.0, torque)
    met = held.touching()

    def stopped_at(angle: float) -> bool:
        """The turn ran into something else, or the torque reversed (read only when it did
        not run into anything: the contacts alone answer the first)."""
        held.turned_from(pressed, sense * angle, pivot, axis)
        if not held.touching() <= met:
            held.skip_side_load()
            return True
        return held.side_load()[1] * sense < 0.0

    low, high = 0.0, math.radians(WRIST_YAW_YIELD_DEG)
    if torque == 0.0 or not stopped_at(high):
        held.restore(pressed)
        return None
    for _ in range(_SEAT_TURN_BISECTIONS):
        mid = (low + high) / 2
        low, high = (low, mid) if stopped_at(mid) else (mid, high)
    stopped_by_other = not held.touching() <= met  # at ``high``: past the stop
    if low < _SEAT_MIN_TURN or stopped_by_other:
        held.restore(pressed)
        return None  # not turned flush with the face it met (a part face, a corner)
    held.turned_from(pressed, sense * low, pivot, axis)
    turned = held.snapshot()
    held.restore(pressed)
    return turned


def relax(held: HeldBox, axis: int, limit_mm: float) -> None:
    """Back a seated box off along ``axis`` in ``_SEAT_STEP_MM`` steps (at most
    ``limit_mm``, as far as a push may have gone) while it is deeper than
    ``LIFT_TOLERANCE_MM`` in a contact across that axis: the force threshold allows about
    0.13 mm, more where a neighbour lighter than the held box yields, and a box released
    wedged into a side would be lifted on top; released, the compressed contact springs
    back."""
    tol = LIFT_TOLERANCE_MM * _MM
    for _ in range(int(limit_mm / _SEAT_STEP_MM)):
        deepest, normal = held.deepest_across(axis)
        if deepest <= tol:
            return
        shift = np.zeros(3)
        shift[axis] = normal * _SEAT_STEP_MM * _MM
        held.translate(*shift)


def retry_margin_mm(command: PlaceCommand) -> float:
    """How far (mm) above its release pose a descent may stop and the box still be let go
    there (``_RETRY_ABOVE_FRACTION``): from the command alone."""
    return max(_RETRY_MIN_MM, _RETRY_ABOVE_FRACTION * command.height_mm)


def place(
    held: HeldBox, command: PlaceCommand, retry: Callable[[], None] | None = None
) -> SkillReport:
    """Run the skill on the held box (descent, then seating); the caller releases it.

    A descent that stops more than ``retry_margin_mm`` above the release pose (the gripper's
    height against the command: all the robot knows of it) is tried again, at most
    ``PLACE_RETRIES`` times: ``retry`` (the simulator's) lifts the box back above everything
    and brings it over the command again with a fresh draw of the arm's noise (the grasp, and
    its estimate's error, stay). The skill does not know the draw: it starts over from the
    command, its earlier moves forgotten. After the last try the box is released where the
    descent stopped, as without ``retry``, or, with ``command.set_aside_stuck`` and the
    descent still that high, reported ``set_aside`` for the caller to take back out (no
    seating then)."""
    report = SkillReport()
    margin = retry_margin_mm(command) * _MM
    for attempt in range(PLACE_RETRIES + 1):
        moved, above = _descend(held, command, report)
        if retry is None or attempt == PLACE_RETRIES or above <= margin:
            break
        report.retried += 1
        report.stopped_high = 0  # counted for the attempt that is released
        retry()
    if command.set_aside_stuck and above > margin:
        report.stopped_high = 0  # not released: taken back out
        report.set_aside = 1
        return report
    if command.seat_mm > 0 and any(command.seat_sides):
        seat(held, command, moved, report)
    return report


__all__ = [
    "APPROACH_MM",
    "LIFT_TOLERANCE_MM",
    "PLACE_RETRIES",
    "WRIST_YAW_YIELD_DEG",
    "HeldBox",
    "PlaceCommand",
    "SkillReport",
    "descend",
    "place",
    "retry_margin_mm",
    "seat",
]
