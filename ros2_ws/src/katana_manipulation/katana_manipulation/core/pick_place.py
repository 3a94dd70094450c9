"""Pick-and-place for the Katana: plan joint-space waypoints for a top-down pick and place, and
run them through an abstract arm port. ROS-free.

The port offers three blocking, bounded calls (`move`, `grip`, `joint_positions`), so the same
sequence runs on the PyBullet world directly (tests), on the ROS arm and gripper actions
(pick_place_executor) and therefore on the real driver.

Phases: approach, descend, grasp, lift, carry, lower, release, retreat, park. Everything is
planned (and every inverse kinematics checked) before the arm moves, so an unreachable goal
moves nothing. The grasp is judged from the finger angle: fingers that close well past the
block's width missed it; fingers that close further while carrying lost it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from katana_description import models as m

from katana_manipulation.core.kinematics import MAX_SPEED, KatanaKinematics, Unreachable, wrap

# Result codes: the constants of katana_interfaces/action/PickAndPlace.
SUCCESS = 0
INVALID_GOAL = 1
UNREACHABLE = 2
GRASP_MISSED = 3
BLOCK_SLIPPED = 4
ARM_DID_NOT_REACH = 5
TIMEOUT = 6
ABORTED = 7

PHASES = ("approach", "descend", "grasp", "lift", "carry", "lower", "release", "retreat", "park")


@dataclass
class PickPlaceRequest:
    pick: Sequence[float]  # block centre x, y, z (m)
    pick_yaw: float  # block yaw about +z (rad)
    block_size: Sequence[float]  # edges along the block's x, y, z (m)
    place: Sequence[float]  # where the block's centre goes
    place_yaw: float


@dataclass
class PickPlaceParams:
    approach_height: float = 0.06  # above the grasp point, before descending
    min_approach_clearance: float = 0.008  # pads above the block top, at the least
    grasp_offset: float = 0.003  # tool point above the block centre when grasping
    release_clearance: float = 0.002  # block bottom above its support when released
    pregrasp_margin: float = 0.024  # open this much wider than the block
    max_grasp_width: float = 0.085
    transit_radius: float = 0.12  # tool distance from the pan axis while panning
    transit_height: float = 0.125  # tool height while panning (a held block clears 3 blocks)
    speed_fraction: float = 0.9  # of each joint's speed limit, at the peak of a move
    min_segment_time: float = 0.1
    descend_points: int = 3  # intermediate points that keep descents nearly vertical
    miss_tolerance: float = 0.08  # rad: fingers closing this far past the block: missed
    slip_tolerance: float = 0.05  # rad: fingers closing this much further: slipped
    grip_effort: float = 0.0  # N m, 0: the gripper's default
    park_pose: Sequence[float] = field(default_factory=lambda: list(m.PARK_POSE))
    park_gripper: float = m.GRIPPER_OPEN


@dataclass
class PickPlaceResult:
    success: bool
    code: int
    message: str
    phase: str = ""


@dataclass
class MoveResult:
    ok: bool
    message: str = ""
    timed_out: bool = False


@dataclass
class GripResult:
    ok: bool
    position: float = math.nan
    stalled: bool = False
    reached_goal: bool = False
    message: str = ""
    timed_out: bool = False


class ArmPort(Protocol):
    """What the sequence needs from an arm. Every call returns within a bounded time."""

    def move(self, points: list[list[float]], times: list[float],
             velocities: list[list[float]] | None = None) -> MoveResult:
        """Follow arm-joint waypoints (ARM_JOINTS order) at times from start (s), passing them
        at the given velocities (None: at rest)."""
        ...

    def grip(self, position: float, effort: float) -> GripResult: ...

    def joint_positions(self) -> dict[str, float] | None: ...


@dataclass
class Segment:
    phase: str
    kind: str  # "arm" or "grip" or "check"
    points: list[list[float]] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    velocities: list[list[float]] = field(default_factory=list)
    position: float = 0.0


class PlanError(Exception):
    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


def _finite(values) -> bool:
    return all(math.isfinite(float(v)) for v in values)


class PickPlacePlanner:
    def __init__(self, kin: KatanaKinematics | None = None,
                 params: PickPlaceParams | None = None) -> None:
        self.kin = kin or KatanaKinematics()
        self.p = params or PickPlaceParams()

    # ------------------------------------------------------------ helpers
    def timed(self, start: Sequence[float], points: list[np.ndarray]) -> tuple[list, list, list]:
        """Times from start and velocities for the waypoints (repeated ones dropped).

        The arm starts and ends at rest; at an interior waypoint a joint that keeps moving the
        same way passes through at the harmonic mean of its neighbouring segments' mean speeds
        (monotone, as in Fritsch-Carlson), so a multi-point move does not stop at each point.
        Segment times then stretch until every cubic Hermite segment peaks within
        speed_fraction of the limits."""
        q = [np.asarray(start, float)]
        for pt in points:
            if not np.allclose(pt, q[-1], atol=1e-6):
                q.append(np.asarray(pt, float))
        if len(q) == 1:
            return [], [], []
        qs = np.array(q)
        dq = np.diff(qs, axis=0)
        vmax = MAX_SPEED * self.p.speed_fraction
        h = np.maximum(self.p.min_segment_time, np.max(np.abs(dq) / vmax, axis=1))
        for _ in range(30):
            slope = dq / h[:, None]
            v = np.zeros_like(qs)
            a, b = slope[:-1], slope[1:]
            same = a * b > 0
            v[1:-1] = np.where(same, 2.0 * a * b / np.where(same, a + b, 1.0), 0.0)
            stretch = np.ones(len(h))
            for i in range(len(h)):
                for j in range(qs.shape[1]):
                    peak = _hermite_peak(qs[i, j], qs[i + 1, j], v[i, j], v[i + 1, j], h[i])
                    stretch[i] = max(stretch[i], peak / vmax[j])
            if np.all(stretch <= 1.0 + 1e-9):
                break
            h = h * np.maximum(stretch, 1.0 + 1e-6)
        times = np.cumsum(h)
        return ([list(map(float, row)) for row in qs[1:]], [float(t) for t in times],
                [list(map(float, row)) for row in v[1:]])

    def _ik(self, xyz, yaw: float, period: float, q5_pref: float, what: str) -> np.ndarray:
        try:
            return self.kin.ik_top_down(xyz[0], xyz[1], xyz[2], yaw, period, q5_pref)
        except Unreachable as exc:
            raise PlanError(UNREACHABLE, f"{what} is unreachable: {exc}") from None

    def _vertical(self, top: np.ndarray, bottom_xyz, yaw: float, q5: float,
                  z_top: float) -> list[np.ndarray]:
        """Intermediate points of a vertical descent from z_top to bottom_xyz (excluded)."""
        n = self.p.descend_points
        out = []
        for k in range(1, n + 1):
            z = z_top + (bottom_xyz[2] - z_top) * k / (n + 1)
            out.append(self._ik((bottom_xyz[0], bottom_xyz[1], z), yaw, math.pi, q5, "descent"))
        return out

    def _above(self, xyz, yaw: float, period: float, q5: float, lowest: float, what: str):
        """Highest reachable top-down pose above xyz, within approach_height and >= lowest."""
        z = xyz[2] + self.p.approach_height
        while z >= lowest - 1e-9:
            try:
                q = self.kin.ik_top_down(xyz[0], xyz[1], z, yaw, period, q5)
                return q, z
            except Unreachable:
                z -= 0.004
        raise PlanError(UNREACHABLE, f"{what}: no room to approach from above (reach limit)")

    def _transit(self, pan: float, yaw_q5: float) -> np.ndarray:
        r, z = self.p.transit_radius, self.p.transit_height
        x, y = r * math.cos(pan), r * math.sin(pan)
        while True:  # the highest top-down pose there, at most transit_height
            try:
                q = self.kin.ik_top_down(x, y, z, 0.0, math.pi, 0.0)
                break
            except Unreachable as exc:
                z -= 0.005
                if z < 0.06:
                    raise PlanError(UNREACHABLE, f"transit pose is unreachable: {exc}") from None
        q[4] = yaw_q5  # the wrist keeps the yaw it will need; only q1 and q5 move in transit
        if self.kin.limit_violation(q) is not None:
            q[4] = 0.0
        return q

    # ------------------------------------------------------------ planning
    def plan(self, req: PickPlaceRequest, current: Sequence[float]) -> list[Segment]:
        p = self.p
        vals = list(req.pick) + [req.pick_yaw] + list(req.block_size) + list(req.place) + [
            req.place_yaw
        ]
        if len(req.pick) != 3 or len(req.place) != 3 or len(req.block_size) != 3:
            raise PlanError(INVALID_GOAL, "pick, place and block_size need three numbers each")
        if not _finite(vals):
            raise PlanError(INVALID_GOAL, f"goal has a non-finite value: {vals}")
        sx, sy, sz = (float(v) for v in req.block_size)
        if min(sx, sy, sz) <= 0.0:
            raise PlanError(INVALID_GOAL, f"block_size must be positive: {[sx, sy, sz]}")
        current = np.asarray(current, float)[:5]
        square = abs(sx - sy) < 1e-3
        # Which block axis the fingers close along, and the equivalent yaws of the block.
        options = []
        if sy <= p.max_grasp_width:
            options.append((0.0, sy))
        if sx <= p.max_grasp_width and not square:
            options.append((math.pi / 2, sx))
        if not options:
            raise PlanError(INVALID_GOAL, f"block {sx:.3f} x {sy:.3f} m is wider than the gripper")
        pick_period = math.pi / 2 if square else math.pi
        place_period = math.pi / 2 if square else math.pi
        pick = np.asarray(req.pick, float)
        place = np.asarray(req.place, float)
        grasp_xyz = pick + [0, 0, p.grasp_offset]
        place_xyz = place + [0, 0, p.grasp_offset + p.release_clearance]
        # Lowest tool heights to start a descent from: the open pads above the block to pick;
        # the held block above where it goes.
        lowest_pick = pick[2] + sz / 2 + m.FINGER_PAD_LENGTH / 2 + p.min_approach_clearance
        lowest_place = place_xyz[2] + p.min_approach_clearance
        last_error: PlanError | None = None
        for axis, width in options:
            try:
                g_yaw = req.pick_yaw + axis
                q_grasp = self._ik(grasp_xyz, g_yaw, pick_period, 0.0, "the block to pick")
                yaw_grip = self.kin.gripper_yaw(q_grasp)
                rel = wrap(req.pick_yaw - yaw_grip)  # block yaw in the gripper
                q_place = self._ik(place_xyz, req.place_yaw - rel, place_period, q_grasp[4],
                                   "the place pose")
                grip_width = width
                break
            except PlanError as exc:
                last_error = exc
        else:
            assert last_error is not None
            raise last_error
        q_above_pick, z_ap = self._above(grasp_xyz, yaw_grip, math.pi, q_grasp[4], lowest_pick,
                                         "pick")
        place_yaw_grip = self.kin.gripper_yaw(q_place)
        q_above_place, z_apl = self._above(place_xyz, place_yaw_grip, math.pi, q_place[4],
                                           lowest_place, "place")
        # Keep q5 continuous along each vertical move.
        q_above_pick[4], q_above_place[4] = q_grasp[4], q_place[4]
        t_pick = self._transit(q_grasp[0], q_grasp[4])
        t_place = self._transit(q_place[0], q_place[4])
        park = np.asarray(p.park_pose, float)
        if len(park) != 5 or self.kin.limit_violation(park) is not None:
            raise PlanError(INVALID_GOAL, f"park pose {list(park)} is outside the joint limits")
        t_park = self._transit(park[0], park[4])
        t_here = self._transit(current[0], current[4])
        pregrasp = m.finger_angle_for_opening(grip_width + p.pregrasp_margin)
        pregrasp = min(m.GRIPPER_OPEN, pregrasp)

        segs: list[Segment] = []

        def arm(phase: str, start: np.ndarray, pts: list[np.ndarray]) -> np.ndarray:
            points, times, vels = self.timed(start, pts)
            if points:
                segs.append(Segment(phase, "arm", points, times, vels))
            return pts[-1]

        q = current
        approach_pts = []
        low = self.kin.tool_position(current)[2] < p.transit_height - 0.02
        if low or not self._near_transit(current):
            approach_pts.append(t_here)
        approach_pts += [t_pick, q_above_pick]
        segs.append(Segment("approach", "grip", position=pregrasp))
        q = arm("approach", q, approach_pts)
        q = arm("descend", q, self._vertical(q, grasp_xyz, yaw_grip, q_grasp[4], z_ap) + [q_grasp])
        segs.append(Segment("grasp", "grip", position=m.GRIPPER_CLOSED))
        segs.append(Segment("grasp", "check",
                            position=m.finger_angle_for_opening(grip_width)))
        q = arm("lift", q, self._vertical(q, (grasp_xyz[0], grasp_xyz[1], z_ap), yaw_grip,
                                          q_grasp[4], grasp_xyz[2]) + [q_above_pick])
        segs.append(Segment("lift", "check"))
        q = arm("carry", q, [t_pick, t_place, q_above_place])
        segs.append(Segment("carry", "check"))
        q = arm("lower", q, self._vertical(q, place_xyz, place_yaw_grip, q_place[4], z_apl)
                + [q_place])
        segs.append(Segment("lower", "check"))
        segs.append(Segment("release", "grip", position=pregrasp))
        q = arm("retreat", q, self._vertical(q, (place_xyz[0], place_xyz[1], z_apl),
                                             place_yaw_grip, q_place[4], place_xyz[2])
                + [q_above_place, t_place])
        q = arm("park", q, [t_park, park])
        segs.append(Segment("park", "grip", position=p.park_gripper))
        return segs

    def placement_reachable(self, place: Sequence[float], place_yaw: float = 0.0,
                            block_size: Sequence[float] = m.BLOCK_SIZE) -> tuple[bool, str]:
        """Whether a block can be put with its centre at `place` (and approached from above),
        without moving anything: (True, "") or (False, reason). For placement searches."""
        p = self.p
        xyz = np.asarray(place, float) + [0, 0, p.grasp_offset + p.release_clearance]
        period = math.pi / 2 if abs(block_size[0] - block_size[1]) < 1e-3 else math.pi
        try:
            q = self._ik(xyz, place_yaw, period, 0.0, "the place pose")
            self._above(xyz, self.kin.gripper_yaw(q), math.pi, q[4],
                        xyz[2] + p.min_approach_clearance, "place")
        except PlanError as exc:
            return False, str(exc)
        return True, ""

    def _near_transit(self, q: np.ndarray) -> bool:
        pos = self.kin.tool_position(q)
        return abs(math.hypot(pos[0], pos[1]) - self.p.transit_radius) < 0.02

    def park_segments(self, current: Sequence[float]) -> list[Segment]:
        """Go up, around and to the park pose, from wherever the arm is (used after a failure)."""
        current = np.asarray(current, float)[:5]
        park = np.asarray(self.p.park_pose, float)
        pts = []
        pos = self.kin.tool_position(current)
        try:
            up = self.kin.ik_top_down(pos[0], pos[1], min(pos[2] + 0.05, 0.12), 0.0, math.pi,
                                      current[4])
            up[4] = current[4]
            pts.append(up)
        except Unreachable:
            pass
        pts += [self._transit(current[0], current[4]), self._transit(park[0], park[4]), park]
        points, times, vels = self.timed(current, pts)
        return [Segment("park", "arm", points, times, vels)] if points else []


def _hermite_peak(p0: float, p1: float, v0: float, v1: float, h: float) -> float:
    """Largest |velocity| of a cubic Hermite segment (its velocity is quadratic in time)."""
    a = 6.0 * (p0 - p1) / h + 3.0 * (v0 + v1)  # v(s) = a s^2 + b s + v0, s = t / h in [0, 1]
    b = 6.0 * (p1 - p0) / h - 4.0 * v0 - 2.0 * v1
    peak = max(abs(v0), abs(v1))
    if abs(a) > 1e-12:
        s = -b / (2.0 * a)
        if 0.0 < s < 1.0:
            peak = max(peak, abs(a * s * s + b * s + v0))
    return peak


ProgressFn = Callable[[str, float], None]


def execute_pick_place(req: PickPlaceRequest, port: ArmPort, planner: PickPlacePlanner,
                       feedback: ProgressFn | None = None,
                       cancelled: Callable[[], bool] | None = None) -> PickPlaceResult:
    """Plan, then run the segments through the port; never raises for arm trouble."""
    feedback = feedback or (lambda phase, progress: None)
    cancelled = cancelled or (lambda: False)
    joints = port.joint_positions()
    if joints is None:
        return PickPlaceResult(False, TIMEOUT, "no joint_states received: is the arm running?")
    current = [joints[n] for n in m.ARM_JOINTS]
    try:
        segments = planner.plan(req, current)
    except PlanError as exc:
        return PickPlaceResult(False, exc.code, str(exc))
    grip_at = math.nan
    holding = False
    for seg in segments:
        if cancelled():
            _recover(port, planner, holding)
            return PickPlaceResult(False, ABORTED, "canceled", seg.phase)
        feedback(seg.phase, PHASES.index(seg.phase) / len(PHASES))
        if seg.kind == "arm":
            res = port.move(seg.points, seg.times, seg.velocities or None)
            if not res.ok:
                code = TIMEOUT if res.timed_out else ARM_DID_NOT_REACH
                _recover(port, planner, holding)
                return PickPlaceResult(False, code, f"{seg.phase}: {res.message}", seg.phase)
        elif seg.kind == "grip":
            g = port.grip(seg.position, planner.p.grip_effort)
            if not g.ok:
                code = TIMEOUT if g.timed_out else ARM_DID_NOT_REACH
                _recover(port, planner, holding)
                return PickPlaceResult(False, code, f"{seg.phase}: gripper: {g.message}", seg.phase)
            if seg.phase == "grasp":
                grip_at = g.position
            if seg.phase == "release":
                holding = False
        else:  # check the grip
            if seg.phase == "grasp":
                expected = seg.position
                if not math.isfinite(grip_at) or grip_at < expected - planner.p.miss_tolerance:
                    _recover(port, planner, holding=True)
                    return PickPlaceResult(
                        False, GRASP_MISSED,
                        f"fingers closed to {grip_at:.3f} rad; a block holds them near "
                        f"{expected:.3f}", seg.phase)
                holding = True
                continue
            joints = port.joint_positions()
            if joints is None:
                _recover(port, planner, holding)
                return PickPlaceResult(False, TIMEOUT, "joint_states stopped", seg.phase)
            fingers = float(np.mean([joints[n] for n in m.FINGER_JOINTS]))
            if fingers < grip_at - planner.p.slip_tolerance:
                _recover(port, planner, holding=True)
                return PickPlaceResult(
                    False, BLOCK_SLIPPED,
                    f"{seg.phase}: fingers closed from {grip_at:.3f} to {fingers:.3f} rad: "
                    "the block slipped out", seg.phase)
    feedback("park", 1.0)
    return PickPlaceResult(True, SUCCESS, "placed", "park")


def _recover(port: ArmPort, planner: PickPlacePlanner, holding: bool) -> None:
    """Best effort after a failure: open the gripper, go up and park (each call is bounded)."""
    try:
        port.grip(planner.p.park_gripper, 0.0)
        joints = port.joint_positions()
        if joints is None:
            return
        for seg in planner.park_segments([joints[n] for n in m.ARM_JOINTS]):
            port.move(seg.points, seg.times, seg.velocities or None)
    except Exception:  # recovery must never mask the original failure
        return
