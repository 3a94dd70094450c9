"""The pick-and-place planner: joint-space waypoints for a top-down pick and place. ROS-free.

Phases: approach, descend, grasp, lift, carry, lower, release, retreat, park. Everything is
planned (and every inverse kinematics checked) before the arm moves, so an unreachable goal
moves nothing; a goal outside the reach of its height (core.reach, computed with this
planner's own geometry) is refused with the reason before any inverse kinematics.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from katana_description import models as m
from scipy.interpolate import CubicHermiteSpline

from katana_manipulation.core.kinematics import (
    MAX_ACCEL,
    MAX_SPEED,
    KatanaKinematics,
    Unreachable,
    wrap,
)
from katana_manipulation.core.pick_place_types import (
    INVALID_GOAL,
    LEVEL_TOLERANCE_M,
    UNREACHABLE,
    WORKSPACE_XY,
    PickPlaceParams,
    PickPlaceRequest,
    PlanError,
    Segment,
    unreachable_code,
)
from katana_manipulation.core.reach import pick_reach, place_reach
from katana_manipulation.core.time_optimal import time_optimal

TICK_S = m.CONTROL_TICK_S
#: a segment whose cubic breaks a limit stretches by at most this factor (and at least a
#: tick) per step, for at most STRETCH_STEPS steps (then every point becomes a stop)
STRETCH_STEP = 1.05
STRETCH_STEPS = 400


def _finite(values) -> bool:
    return all(math.isfinite(float(v)) for v in values)


def _ticks(seconds: np.ndarray) -> np.ndarray:
    """Durations rounded up to whole controller ticks (the driver runs its splines on them)."""
    return np.ceil(np.asarray(seconds, float) / TICK_S - 1e-9)


def hermite_peaks(q: np.ndarray, v: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Peak |speed| and |acceleration| (segments x joints) of the cubic Hermite spline through
    the points ``q`` with velocities ``v``, segment durations ``h``: its speed is a quadratic in
    time (peak at an end or the vertex), its acceleration linear (peak at an end)."""
    t = np.concatenate([[0.0], np.cumsum(h)])
    c = CubicHermiteSpline(t, q, v, axis=0).c  # c[0] dt^3 + c[1] dt^2 + c[2] dt + c[3]
    hh = h[:, None]
    accel = np.maximum(np.abs(2.0 * c[1]), np.abs(2.0 * c[1] + 6.0 * c[0] * hh))
    with np.errstate(divide="ignore", invalid="ignore"):
        vertex = np.where(c[0] != 0.0, -c[1] / (3.0 * c[0]), 0.0)
    vertex = np.clip(vertex, 0.0, hh)
    speed = np.maximum.reduce([np.abs(v[:-1]), np.abs(v[1:]),
                               np.abs(3.0 * c[0] * vertex**2 + 2.0 * c[1] * vertex + c[2])])
    return speed, accel


@dataclass
class _Ends:
    """The goal's own poses: the grasp and the place, the poses above them, and the grip."""

    grasp_xyz: np.ndarray
    place_xyz: np.ndarray
    q_grasp: np.ndarray
    q_place: np.ndarray
    yaw_grip: float  # the gripper's yaw at the grasp
    place_yaw_grip: float  # ... and at the place
    grip_width: float  # the block's edge between the fingers
    q_above_pick: np.ndarray
    z_above_pick: float
    q_above_place: np.ndarray
    z_above_place: float


@dataclass
class _Columns:
    """The climbs above the pick and the place (empty or holding the block), and the openings."""

    pick_empty: list
    pick_held: list
    place_held: list
    place_empty: list
    pregrasp: float  # finger angle to open to before the grasp
    release: float  # ... and to release with


def _distinct(start: Sequence[float], points: Sequence) -> list[np.ndarray]:
    """The knots of a move (what `timed` times): `start`, then each point that moves some
    joint by 1e-3 rad or more from the knot before it (a point closer is no move worth a
    segment)."""
    q = [np.asarray(start, float)]
    for pt in points:
        pt = np.asarray(pt, float)
        if np.max(np.abs(pt - q[-1])) >= 1e-3:
            q.append(pt)
    return q


class PickPlacePlanner:
    """Plans with its `PickPlaceParams`; the reach it checks goals against (core.reach) is
    computed with the same settings (`params.geometry`), not with the defaults."""

    def __init__(self, kin: KatanaKinematics | None = None,
                 params: PickPlaceParams | None = None) -> None:
        self.kin = kin or KatanaKinematics()
        self.p = params or PickPlaceParams()

    # ------------------------------------------------------------ helpers
    def timed(self, start: Sequence[float], points: list[np.ndarray]) -> tuple[list, list, list]:
        """Times from start and velocities for the waypoints (repeated ones dropped), near the
        least time the limits allow on their path.

        The time-optimal motion (core.time_optimal) through the waypoints, within
        speed_fraction of the speed limits and accel_fraction of the controller's acceleration
        limits (kinematics.MAX_ACCEL, the arm contract's), no stretch between waypoints quicker
        than min_segment_time, gives each waypoint a time and a velocity. A stretch that lasts
        longer than `cruise_piece_s` gets points of that motion in between, at equal times, so
        the cubic Hermite segments the driver and the simulation follow (acceleration linear in
        time) trace its accelerate-cruise-brake profile closely. Times are rounded up to whole
        10 ms controller ticks; a segment whose cubic still peaks above a limit is lengthened a
        little at a time, its end velocities slowed in proportion. Should that not settle,
        every point becomes a stop, each segment timed on its own: a cubic from rest to rest
        over h peaks at 1.5 d / h and 6 d / h^2."""
        vmax = MAX_SPEED * self.p.speed_fraction
        amax = MAX_ACCEL * self.p.accel_fraction
        q = _distinct(start, points)
        if len(q) == 1:
            return [], [], []
        qs, v_opt, ticks = self._optimal_knots(np.array(q), vmax, amax)
        dq = np.diff(qs, axis=0)
        ticks0 = ticks.copy()
        for _ in range(STRETCH_STEPS):
            slow = ticks0 / ticks  # a segment made longer passes its ends slower
            v = v_opt * np.minimum(np.concatenate([[1.0], slow]), np.concatenate([slow, [1.0]]))[
                :, None]
            speed, accel = hermite_peaks(qs, v, ticks * TICK_S)
            stretch = np.max(np.maximum(speed / vmax, np.sqrt(accel / amax)), axis=1)
            if np.all(stretch <= 1.0):
                break
            grow = np.minimum(stretch, STRETCH_STEP)
            ticks = np.where(stretch > 1.0,
                             np.maximum(_ticks(ticks * TICK_S * grow), ticks + 1), ticks)
        else:  # stop at every point: each segment on its own, from rest to rest
            v = np.zeros_like(qs)
            d = np.abs(dq)
            ticks = _ticks(np.maximum(self.p.min_segment_time, np.max(
                np.maximum(1.5 * d / vmax, np.sqrt(6.0 * d / amax)), axis=1)))
        times = np.cumsum(ticks) * TICK_S
        return ([list(map(float, row)) for row in qs[1:]], [float(t) for t in times],
                [list(map(float, row)) for row in v[1:]])

    def _optimal_knots(self, qs: np.ndarray, vmax: np.ndarray,
                       amax: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The knots (the waypoints and points of the time-optimal motion between them), their
        velocities on it, and the segments' durations in whole ticks."""
        prof = time_optimal(qs, vmax, amax, min_segment_time=self.p.min_segment_time)
        t_way = prof.knot_times()
        piece = max(self.p.cruise_piece_s, self.p.min_segment_time)
        times, way_at = [0.0], [0]
        for a, b in zip(t_way[:-1], t_way[1:], strict=True):
            n = max(int(round((b - a) / piece)), 1)
            times += [a + (b - a) * k / n for k in range(1, n)] + [b]
            way_at.append(len(times) - 1)
        times = np.array(times)
        s = np.interp(times, prof.t, prof.s)
        s[way_at] = prof.s_knots  # the waypoints exactly
        sdot = np.interp(s, prof.s, prof.sdot)
        knots = prof.path(s)
        vel = prof.path(s, 1) * sdot[:, None]
        way = np.zeros(len(s), bool)
        way[way_at] = True
        knots[way] = qs
        # points in between are targets too, so inside the limit margin: one outside it (the
        # first stretch may start there, where the arm is) is left out
        keep = way | np.all((knots >= self.kin.lower) & (knots <= self.kin.upper), axis=1)
        knots, vel, times = knots[keep], vel[keep], times[keep]
        vel[0] = vel[-1] = 0.0
        ticks = np.maximum(_ticks(np.diff(times)), round(self.p.min_segment_time / TICK_S))
        return knots, vel, ticks

    def _ik(self, xyz, yaw: float, period: float, q5_pref: float, what: str) -> np.ndarray:
        try:
            return self.kin.ik_top_down(xyz[0], xyz[1], xyz[2], yaw, period, q5_pref)
        except Unreachable as exc:
            raise PlanError(unreachable_code(what), f"{what} is unreachable: {exc}") from None

    def check_target(self, xyz, size: Sequence[float], what: str) -> None:
        """Refuse a pick or place centre below the table top, outside the workspace, or outside
        the reach of its height (katana_manipulation.core.reach), with the reason."""
        x, y, z = (float(v) for v in xyz)
        sz = float(size[2])
        code = unreachable_code(what)
        if z < sz / 2 - LEVEL_TOLERANCE_M:
            raise PlanError(INVALID_GOAL, f"{what}: centre z = {z:.3f} m puts the block below "
                            f"the table top (lowest centre {sz / 2:.3f} m)")
        x0, x1, y0, y1 = WORKSPACE_XY
        if not (x0 <= x <= x1 and y0 <= y <= y1):
            raise PlanError(code, f"{what} is unreachable: ({x:.3f}, {y:.3f}) is outside the "
                            f"workspace x [{x0:.2f}, {x1:.2f}], y [{y0:.2f}, {y1:.2f}] m")
        height = int(round((z - sz / 2) / sz))  # blocks below it
        geometry, model = self.p.geometry, self.kin.model.name
        band = (pick_reach(height + 1, sz, model, geometry) if "pick" in what
                else place_reach(height, sz, model, geometry))
        r = math.hypot(x, y)
        if band.empty:
            raise PlanError(code, f"{what} is unreachable: nothing at height {height} "
                            f"(z = {z:.3f} m) is in reach")
        if not band.contains(x, y, tolerance_m=0.002):
            raise PlanError(code, f"{what} is unreachable: {r:.3f} m from the pan axis, outside "
                            f"the reach [{band.min_m:.3f}, {band.max_m:.3f}] m at height {height}")

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
                z -= self.p.approach_step
        raise PlanError(unreachable_code(what),
                        f"{what}: no room to approach from above (reach limit)")

    def _line(self, q_from: np.ndarray, q_to: np.ndarray, step_m: float = 0.02) -> list:
        """Top-down poses on the straight line between two top-down poses (both excluded).

        Between a transit pose and a pose above a stack, joint-space interpolation tilts the
        gripper and sags below the line, so an open pad or a held block's corner can clip the
        stack's top block; on the line the tool stays pointing down and its height changes
        monotonically. [] when the line is one step or the solutions jump (a wrist flip, the
        pan over the top): then the move stays in joint space."""
        a, b = self.kin.tool_position(q_from), self.kin.tool_position(q_to)
        n = int(math.ceil(float(np.linalg.norm(b - a)) / step_m))
        if n < 2:
            return []
        yaw, q5 = self.kin.gripper_yaw(q_to), float(q_to[4])
        out, prev = [], np.asarray(q_from, float)
        for k in range(1, n):
            x, y, z = a + (b - a) * k / n
            try:
                q = self.kin.ik_top_down(x, y, z, yaw, math.pi, q5)
            except Unreachable:
                return []
            if np.max(np.abs(q - prev)) > 0.5 or abs(q[4] - q5) > 1e-6:
                return []
            out.append(q)
            prev = q
        return out

    def _transit(self, pan: float, yaw_q5: float) -> np.ndarray:
        r, z = self.p.transit_radius, self.p.transit_height
        pan = float(np.clip(pan, self.kin.lower[0], self.kin.upper[0]))  # a target: in the margin
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
        # A top-down tool reaches 0.13 m at most, where the open pads hang to 0.117 m: below
        # the top of a stack of four (0.12 m). Raising the shoulder tilts the gripper a little
        # and lifts the pads clear of it while panning.
        lifted = q.copy()
        lifted[1] = min(q[1] + self.p.transit_lift_rad, self.kin.upper[1])
        return lifted if self.kin.limit_violation(lifted) is None else q

    def _rise(self, q_start: np.ndarray, z_goal: float, step_m: float = 0.01) -> list:
        """Top-down poses going up from q_start to tool height z_goal (or as high as the arm
        reaches), each at the largest radius, not beyond the last one, that the arm reaches.

        Near the edge of the reach a vertical move soon runs out of room; the arm must then come
        in a little as it rises. Leaving a block or a stack, the tool first climbs this column
        until the pads (or the held block) clear every stack, and only then heads for the
        transit pose: a straight line there would sweep low over whatever is on the way."""
        pos = self.kin.tool_position(q_start)
        ang, r = math.atan2(pos[1], pos[0]), math.hypot(pos[0], pos[1])
        yaw, q5 = self.kin.gripper_yaw(q_start), float(q_start[4])
        out, prev, z = [], np.asarray(q_start, float), float(pos[2])
        while z < z_goal - 1e-9:
            z = min(z + step_m, z_goal)
            for rr in np.arange(r, max(r - 0.06, 0.0), -0.002):
                try:
                    q = self.kin.ik_top_down(rr * math.cos(ang), rr * math.sin(ang), z, yaw,
                                             math.pi, q5)
                except Unreachable:
                    continue
                if np.max(np.abs(q - prev)) <= 0.5 and abs(q[4] - q5) <= 1e-6:
                    break
            else:
                return out
            out.append(q)
            prev, r = q, float(rr)
        return out

    # ------------------------------------------------------------ planning
    def plan(self, req: PickPlaceRequest, current: Sequence[float]) -> list[Segment]:
        sz = self._checked(req)
        current = np.asarray(current, float)[:5]
        ends = self._ends(req)
        t_pick = self._transit(ends.q_grasp[0], ends.q_grasp[4])
        t_place = self._transit(ends.q_place[0], ends.q_place[4])
        park = np.asarray(self.p.park_pose, float)
        if len(park) != 5 or self.kin.limit_violation(park) is not None:
            raise PlanError(INVALID_GOAL, f"park pose {list(park)} is outside the joint limits")
        t_park = self._transit(park[0], park[4])
        t_here = self._transit(current[0], current[4])
        columns = self._columns(ends, float(req.place[2]), sz)
        return self._merged(self._sequence(current, ends, columns,
                                           (t_here, t_pick, t_place, t_park), park))

    def pregrasp(self, req: PickPlaceRequest) -> float:
        """The finger angle `plan` opens to first (its first segment), from the goal alone:
        the gripper can move there while the rest is planned. Raises PlanError as `plan`
        does for a malformed goal or a pick or place out of reach."""
        self._checked(req)
        return self._pregrasp(self._ends(req).grip_width)

    def _pregrasp(self, grip_width: float) -> float:
        return min(m.GRIPPER_OPEN,
                   m.finger_angle_for_opening(grip_width + self.p.pregrasp_margin))

    def _checked(self, req: PickPlaceRequest) -> float:
        """Refuse a malformed goal or one outside the reach; the block's height."""
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
        self.check_target(req.pick, (sx, sy, sz), "the block to pick")
        self.check_target(req.place, (sx, sy, sz), "the place pose")
        return sz

    def _grip_options(self, sx: float, sy: float) -> list[tuple[float, float]]:
        """Which block axis the fingers close along: (yaw added to the block's, width)."""
        options = []
        if sy <= self.p.max_grasp_width:
            options.append((0.0, sy))
        if sx <= self.p.max_grasp_width and abs(sx - sy) >= 1e-3:
            options.append((math.pi / 2, sx))
        if not options:
            raise PlanError(INVALID_GOAL, f"block {sx:.3f} x {sy:.3f} m is wider than the gripper")
        return options

    def _ends(self, req: PickPlaceRequest) -> _Ends:
        """The grasp and place poses (the first grip that reaches both) and those above them."""
        p = self.p
        sx, sy, sz = (float(v) for v in req.block_size)
        options = self._grip_options(sx, sy)
        # the equivalent yaws of the block: a square one every quarter turn
        period = math.pi / 2 if abs(sx - sy) < 1e-3 else math.pi
        pick = np.asarray(req.pick, float)
        place = np.asarray(req.place, float)
        grasp_xyz = pick + [0, 0, p.grasp_offset]
        place_xyz = place + [0, 0, p.grasp_offset + p.release_clearance]
        last_error: PlanError | None = None
        for axis, width in options:
            try:
                q_grasp = self._ik(grasp_xyz, req.pick_yaw + axis, period, 0.0,
                                   "the block to pick")
                yaw_grip = self.kin.gripper_yaw(q_grasp)
                rel = wrap(req.pick_yaw - yaw_grip)  # block yaw in the gripper
                q_place = self._ik(place_xyz, req.place_yaw - rel, period, q_grasp[4],
                                   "the place pose")
                grip_width = width
                break
            except PlanError as exc:
                last_error = exc
        else:
            assert last_error is not None
            raise last_error
        # Lowest tool heights to start a descent from: the open pads above the block to pick;
        # the held block above where it goes.
        lowest_pick = pick[2] + sz / 2 + m.FINGER_PAD_LENGTH / 2 + p.min_approach_clearance
        lowest_place = place_xyz[2] + p.min_approach_clearance
        q_above_pick, z_ap = self._above(grasp_xyz, yaw_grip, math.pi, q_grasp[4], lowest_pick,
                                         "pick")
        place_yaw_grip = self.kin.gripper_yaw(q_place)
        q_above_place, z_apl = self._above(place_xyz, place_yaw_grip, math.pi, q_place[4],
                                           lowest_place, "place")
        # Keep q5 continuous along each vertical move.
        q_above_pick[4], q_above_place[4] = q_grasp[4], q_place[4]
        return _Ends(grasp_xyz, place_xyz, q_grasp, q_place, yaw_grip, place_yaw_grip,
                     grip_width, q_above_pick, z_ap, q_above_place, z_apl)

    def _columns(self, ends: _Ends, place_z: float, sz: float) -> _Columns:
        """Columns above the pick and the place: climbed before heading for the transit pose,
        to where the pads (empty) or the held block clear a stack of clear_stack_blocks."""
        p = self.p
        pregrasp = self._pregrasp(ends.grip_width)
        stacks_top = p.clear_stack_blocks * sz + p.clearance
        pad_below_tool = m.FINGER_PAD_LENGTH / 2
        held_below_tool = p.grasp_offset + sz / 2
        pick_empty = self._rise(ends.q_above_pick, stacks_top + pad_below_tool)
        pick_held = self._rise(ends.q_above_pick, stacks_top + held_below_tool)
        place_held = self._rise(ends.q_above_place, stacks_top + held_below_tool)
        placed_top = place_z + sz / 2 + p.clearance
        place_empty = self._rise(ends.q_above_place, max(placed_top, stacks_top)
                                 + pad_below_tool)
        # Coming in while it rises, an open pad must not push the placed block: release wide
        # when the column leans in by more than half the pregrasp margin.
        release = pregrasp
        if place_empty:
            lean = abs(math.hypot(*self.kin.tool_position(place_empty[-1])[:2])
                       - math.hypot(*self.kin.tool_position(ends.q_above_place)[:2]))
            if lean > p.pregrasp_margin / 3:
                release = m.GRIPPER_OPEN
        return _Columns(pick_empty, pick_held, place_held, place_empty, pregrasp, release)

    def _via(self, q_from: np.ndarray, column: list, q_to: np.ndarray) -> list:
        """Up the column from q_from (or down it, reversed), then straight to q_to."""
        top = column[-1] if column else q_from
        return [*column, *self._line(top, q_to), q_to]

    def _sequence(self, current: np.ndarray, e: _Ends, c: _Columns, transits: tuple,
                  park: np.ndarray) -> list[Segment]:
        """Every phase's segments, in order, from `current` to `park` (unmerged)."""
        t_here, t_pick, t_place, t_park = transits
        segs: list[Segment] = []

        def arm(phase: str, start: np.ndarray, pts: list[np.ndarray],
                holding: bool = False) -> np.ndarray:
            if len(_distinct(start, pts)) > 1:  # a move (`timed` gives it points): timed
                segs.append(Segment(phase, "arm", start=list(start), waypoints=list(pts),
                                    holding=holding))
            return pts[-1]  # once, in _merged, with the moves it runs into

        q, approach_pts = current, []
        low = self.kin.tool_position(current)[2] < self.p.transit_height - 0.02
        if low or not self._near_transit(current):
            approach_pts.append(t_here)
        down = self._via(e.q_above_pick, c.pick_empty, t_pick)[::-1][1:] + [e.q_above_pick]
        approach_pts += [t_pick, *down]
        segs.append(Segment("approach", "grip", position=c.pregrasp))
        q = arm("approach", q, approach_pts)
        q = arm("descend", q, self._vertical(q, e.grasp_xyz, e.yaw_grip, e.q_grasp[4],
                                             e.z_above_pick) + [e.q_grasp])
        segs.append(Segment("grasp", "grip", position=m.GRIPPER_CLOSED))
        segs.append(Segment("grasp", "check",
                            position=m.finger_angle_for_opening(e.grip_width)))
        # lift, carry and lower run as one move, the fingers watched for a slip all along it
        # and judged where it ends, where the block is about to be let go (execute_pick_place)
        q = arm("lift", q, self._vertical(q, (e.grasp_xyz[0], e.grasp_xyz[1], e.z_above_pick),
                                          e.yaw_grip, e.q_grasp[4], e.grasp_xyz[2])
                + [e.q_above_pick], holding=True)
        down = self._via(e.q_above_place, c.place_held, t_place)[::-1][1:] + [e.q_above_place]
        q = arm("carry", q, [*self._via(e.q_above_pick, c.pick_held, t_pick), t_place, *down],
                holding=True)
        q = arm("lower", q, self._vertical(q, e.place_xyz, e.place_yaw_grip, e.q_place[4],
                                           e.z_above_place) + [e.q_place], holding=True)
        segs.append(Segment("release", "grip", position=c.release))
        # the fingers must have let go: open at least half the pregrasp margin past the block
        let_go = m.finger_angle_for_opening(e.grip_width + self.p.pregrasp_margin / 2)
        segs.append(Segment("release", "check", position=min(c.release, let_go)))
        q = arm("retreat", q, self._vertical(q, (e.place_xyz[0], e.place_xyz[1], e.z_above_place),
                                             e.place_yaw_grip, e.q_place[4], e.place_xyz[2])
                + [e.q_above_place, *self._via(e.q_above_place, c.place_empty, t_place)])
        q = arm("park", q, [t_park, park])
        if self.p.park_gripper is not None:
            segs.append(Segment("park", "grip", position=self.p.park_gripper))
        return segs

    def _merged(self, segs: list[Segment]) -> list[Segment]:
        """Run consecutive arm moves as one trajectory: one goal instead of several, and no stop
        between them (approach into descend; lift, carry and lower; retreat into park), on the
        same waypoints. Each trajectory is timed here, once: timing the moves before merging
        them was most of the planning time of a pick-and-place, spent on timings nobody ran."""
        out: list[Segment] = []
        for seg in segs:
            prev = out[-1] if out else None
            if (seg.kind == "arm" and prev is not None and prev.kind == "arm"
                    and seg.holding == prev.holding):
                out[-1] = Segment(prev.phase, "arm", start=prev.start,
                                  waypoints=prev.waypoints + seg.waypoints,
                                  also=(*prev.also, seg.phase), holding=seg.holding)
            else:
                out.append(seg)
        for seg in out:
            if seg.kind == "arm":
                seg.points, seg.times, seg.velocities = self.timed(seg.start, seg.waypoints)
        return out

    def placement_reachable(self, place: Sequence[float], place_yaw: float = 0.0,
                            block_size: Sequence[float] = m.BLOCK_SIZE) -> tuple[bool, str]:
        """Whether a block can be put with its centre at `place` (and approached from above),
        without moving anything: (True, "") or (False, reason). For placement searches."""
        p = self.p
        xyz = np.asarray(place, float) + [0, 0, p.grasp_offset + p.release_clearance]
        period = math.pi / 2 if abs(block_size[0] - block_size[1]) < 1e-3 else math.pi
        try:
            self.check_target(place, block_size, "the place pose")
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
            up[4] = np.clip(current[4], self.kin.lower[4], self.kin.upper[4])  # a target
            pts.append(up)
        except Unreachable:
            pass
        pts += [self._transit(current[0], current[4]), self._transit(park[0], park[4]), park]
        points, times, vels = self.timed(current, pts)
        return [Segment("park", "arm", points, times, vels)] if points else []

