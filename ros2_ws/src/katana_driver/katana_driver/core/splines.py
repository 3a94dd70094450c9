"""Joint trajectories -> Katana spline segments, checked against joint, speed and acceleration
limits.

The controller runs one cubic per motor and segment, pos(t) = p0 + p1/64 t + p2/1024 t^2 +
p3/32768 t^3 with t in 10 ms ticks and 16-bit coefficients. Rounding p2 and p3 costs
0.5/1024 t^2 and 0.5/32768 t^3 encoders, so segments are kept short (0.5 s at most: under
4 encoders of error); segments shorter than 0.2 s would overflow p3 at full speed, so knots
closer than that are merged. Knot velocities come from the goal or, when it has none, are
zero (the arm stops at every point, as the simulation's controller does, so one goal moves
both backends alike and never overshoots between points); the arm starts and ends at rest.

Every knot and every point between knots stays ``limit_margin`` encoders inside the motor's
encoder range (a real controller is reported to refuse targets within about 200 encoders of
its limits); only a segment that starts inside the margin, where the arm already is, may move
there, and only towards the inside. A segment's acceleration (the cubic's second derivative,
encoders per tick squared) must not exceed the motor's limit: KNI's own moves use 2 (the ROS 1
node's KNI_MAX_ACCELERATION), where an unchecked 20-tick segment at full speed asked for 36.
Goals that break a limit are refused with the reason, never re-timed: the arm contract judges
the goal on its own timing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from .encoders import ARM_JOINTS, DEFAULT_LIMIT_MARGIN_ENC, EncoderModel
from .protocol import (
    INT16_MAX,
    INT16_MIN,
    KNI_MAX_ACCELERATION,
    SPLINE_SCALE,
    TICK_S,
    SplineSegment,
)

MIN_SEGMENT_TICKS = 20
MAX_SEGMENT_TICKS = 50
START_TOLERANCE_RAD = 0.05  # a point at t=0 must be this close to where the arm is


class TrajectoryError(ValueError):
    """The goal cannot be executed as given (limits, speeds, timing); the text says why."""


def cubic_speed_max(c1: float, c2: float, c3: float, duration: float) -> float:
    """Largest |c1 + 2 c2 t + 3 c3 t^2| over t in [0, duration]."""
    candidates = [0.0, float(duration)]
    if c3 != 0.0:
        t_star = -c2 / (3.0 * c3)
        if 0.0 < t_star < duration:
            candidates.append(t_star)
    return max(abs(c1 + 2.0 * c2 * t + 3.0 * c3 * t * t) for t in candidates)


def cubic_accel_max(c2: float, c3: float, duration: float) -> float:
    """Largest |2 c2 + 6 c3 t| over t in [0, duration] (linear in t: at an end)."""
    return max(abs(2.0 * c2), abs(2.0 * c2 + 6.0 * c3 * float(duration)))


def cubic_extremes(c: Sequence[float], duration: float) -> tuple[float, float]:
    """(min, max) of c0 + c1 t + c2 t^2 + c3 t^3 over t in [0, duration]."""
    c0, c1, c2, c3 = c
    ts = [0.0, float(duration)]
    # Stationary points: roots of 3 c3 t^2 + 2 c2 t + c1. A leading coefficient negligible over
    # this duration is dropped (np.roots overflows on subnormal ones).
    a, b = 3.0 * c3, 2.0 * c2
    size = abs(b) * duration + abs(c1)
    if abs(a) * duration * duration <= 1e-12 * size:
        a = 0.0
    if a != 0.0:
        roots = np.roots([a, b, c1])
    elif b != 0.0:
        roots = np.array([-c1 / b])
    else:
        roots = np.array([])
    ts += [float(r.real) for r in roots if abs(r.imag) < 1e-12 and 0.0 < r.real < duration]
    values = [c0 + c1 * t + c2 * t * t + c3 * t**3 for t in ts]
    return min(values), max(values)


def hermite_coefficients(
    e0: float, e1: float, v0: float, v1: float, ticks: int
) -> tuple[float, float, float, float]:
    """Cubic through (0, e0) and (ticks, e1) with slopes v0, v1 (encoders, encoders per tick)."""
    t = float(ticks)
    delta = e1 - e0
    return (e0, v0, (3.0 * delta / t - 2.0 * v0 - v1) / t, (-2.0 * delta / t + v0 + v1) / (t * t))


def quantize(c: Sequence[float], target: float, ticks: int) -> SplineSegment:
    """Firmware segment (16-bit scaled coefficients) of the cubic ``c``."""
    p = [int(round(ci * s)) for ci, s in zip(c, SPLINE_SCALE, strict=True)]
    for value in p:
        if not INT16_MIN <= value <= INT16_MAX:
            raise TrajectoryError(
                "a spline coefficient overflows 16 bits: the motion is too fast for its "
                "duration; give the trajectory more time"
            )
    return SplineSegment(int(ticks), int(round(target)), *p)


def hermite_segment(e0: float, e1: float, v0: float, v1: float, ticks: int) -> SplineSegment:
    """Firmware segment from end values and slopes (encoders, encoders per tick)."""
    return quantize(hermite_coefficients(e0, e1, v0, v1, ticks), e1, ticks)


def hold_segment(enc: int, ticks: int) -> SplineSegment:
    """A segment that keeps a motor where it is (the gripper during arm trajectories)."""
    return SplineSegment(ticks, int(enc), int(enc), 0, 0, 0)


def evaluate(segment: SplineSegment, tick: float) -> float:
    """Position of a firmware segment at ``tick`` (clamped to the segment; target at the end)."""
    if tick >= segment.duration:
        return float(segment.target)
    c0, c1, c2, c3 = segment.coefficients()
    t = max(0.0, tick)
    return c0 + c1 * t + c2 * t * t + c3 * t**3


@dataclass
class SplinePlan:
    """The segments to send (per segment: motors 1..5) and the timing they imply."""

    segments: list[list[SplineSegment]]
    start_ticks: list[int]  # tick at which each segment starts, from the trajectory start
    model: EncoderModel

    @property
    def total_ticks(self) -> int:
        return self.start_ticks[-1] + self.segments[-1][0].duration if self.segments else 0

    @property
    def duration_s(self) -> float:
        return self.total_ticks * TICK_S

    def encoders_at(self, t_s: float) -> list[float]:
        """Commanded encoder positions of motors 1..5 at ``t_s`` seconds from the start."""
        tick = t_s / TICK_S
        idx = int(np.searchsorted(self.start_ticks, tick, side="right")) - 1
        idx = min(max(idx, 0), len(self.segments) - 1)
        return [evaluate(s, tick - self.start_ticks[idx]) for s in self.segments[idx]]

    def desired_at(self, t_s: float) -> list[float]:
        """Commanded joint angles (rad, URDF convention) at ``t_s`` seconds from the start."""
        enc = self.encoders_at(t_s)
        return [self.model.encoder_to_angle(i + 1, e) for i, e in enumerate(enc)]

    def final_angles(self) -> list[float]:
        return [
            self.model.encoder_to_angle(i + 1, s.target) for i, s in enumerate(self.segments[-1])
        ]


def _select_knots(ticks: np.ndarray, min_ticks: int) -> list[int]:
    """Indices of knots to keep so that kept knots are at least ``min_ticks`` apart."""
    keep = [0]
    for i in range(1, len(ticks)):
        if ticks[i] - ticks[keep[-1]] >= min_ticks:
            keep.append(i)
    last = len(ticks) - 1
    if keep[-1] != last:  # the goal must be reached exactly: keep the last knot
        if len(keep) > 1:
            keep[-1] = last
        else:
            keep.append(last)
    return keep


def plan_trajectory(
    model: EncoderModel,
    start_encoders: Sequence[int],
    times_s: Sequence[float],
    positions: Sequence[Sequence[float]],
    velocities: Sequence[Sequence[float]] | None = None,
    speed_scale: float = 1.0,
    min_segment_ticks: int = MIN_SEGMENT_TICKS,
    max_segment_ticks: int = MAX_SEGMENT_TICKS,
    limit_margin: int = DEFAULT_LIMIT_MARGIN_ENC,
    accel_limits: Sequence[float] | None = None,
    firmware_speed_limits: Sequence[float] | None = None,
) -> SplinePlan:
    """Plan spline segments for motors 1..5 from the arm's encoders and a joint trajectory.

    ``positions`` rows are joint angles in ARM_JOINTS order, at ``times_s`` from the start.
    ``limit_margin``: encoders every point keeps inside the encoder ranges; ``accel_limits``:
    per motor 1..5, encoders per tick squared (default KNI's 2); ``firmware_speed_limits``:
    the speed limits set on the controller, encoders per tick (the joint speed limits apply
    anyway). Raises TrajectoryError naming the joint and the limit when the goal cannot run.
    """
    times, q, v = _checked_goal(times_s, positions, velocities)
    at_start = bool(np.round(times[0] / TICK_S) <= 0.0)  # a point at t=0: where the arm is
    start = np.asarray(start_encoders[:5], dtype=float)
    enc, enc_per_tick = _encoder_knots(model, q, v, limit_margin, at_start, start)
    ticks, enc, enc_per_tick = _from_start(model, start, times, enc, enc_per_tick,
                                           min_segment_ticks)
    curve, knot_ticks = _knot_curve(ticks, enc, enc_per_tick, min_segment_ticks)
    bounds: list[int] = [knot_ticks[0]]
    for a, b in zip(knot_ticks[:-1], knot_ticks[1:], strict=True):
        n = math.ceil((b - a) / max_segment_ticks)
        bounds += [a + round((b - a) * (i + 1) / n) for i in range(n)]
    limits = _Limits(
        speed=[model.speed_limit_enc(j + 1) * speed_scale for j in range(5)],
        accel=[float(a) for a in (accel_limits or [KNI_MAX_ACCELERATION] * 5)[:5]],
        margin=int(limit_margin),
    )
    if firmware_speed_limits is not None:
        limits.speed = [min(a, float(b))
                        for a, b in zip(limits.speed, firmware_speed_limits[:5], strict=True)]
    deriv = curve.derivative()
    segments: list[list[SplineSegment]] = []
    prev = [int(round(e)) for e in start]
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        row = _segment_row(model, prev, curve(b), deriv(a), deriv(b), b - a, limits)
        prev = [seg.target for seg in row]
        segments.append(row)
    return SplinePlan(
        segments=segments, start_ticks=[b - bounds[0] for b in bounds[:-1]], model=model
    )


def _checked_goal(
    times_s: Sequence[float],
    positions: Sequence[Sequence[float]],
    velocities: Sequence[Sequence[float]] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """times, positions (points x 5) and velocities (or None) as arrays, checked."""
    times = np.asarray(times_s, dtype=float)
    q = np.asarray(positions, dtype=float)
    if times.ndim != 1 or len(times) == 0:
        raise TrajectoryError("the trajectory has no points")
    if q.shape != (len(times), 5):
        raise TrajectoryError(f"expected {len(times)} x 5 positions, got shape {q.shape}")
    if not (np.all(np.isfinite(times)) and np.all(np.isfinite(q))):
        raise TrajectoryError("the trajectory contains NaN or infinite values")
    if times[0] < 0.0 or np.any(np.diff(times) <= 0.0):
        raise TrajectoryError("time_from_start must be non-negative and strictly increasing")
    v = None
    if velocities is not None and len(velocities) > 0:
        v = np.asarray(velocities, dtype=float)
        if v.shape != q.shape or not np.all(np.isfinite(v)):
            raise TrajectoryError("velocities must be finite and match the positions")
    return times, q, v


@dataclass
class _Limits:
    speed: list[float]  # encoders per tick, motors 1..5
    accel: list[float]  # encoders per tick squared, motors 1..5
    margin: int  # encoders kept inside every encoder range


#: encoders a knot may lie beyond the range and still be "on the limit" (the URDF's limits are
#: rounded to 6 decimals: under 0.01 encoders)
_ON_LIMIT_ENC = 1.0


def _encoder_knots(
    model: EncoderModel, q: np.ndarray, v: np.ndarray | None, margin: int, at_start: bool,
    start: np.ndarray,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The knots in encoder space and their slopes per tick. Every knot must lie ``margin``
    encoders inside the encoder range, but for a first knot at t=0 (it stands for where the
    arm is, which _from_start checks) and a motor held where it is at every knot (no new
    target: the joints a partial goal leaves out): those must only be inside the limits."""
    enc = np.empty_like(q)
    for j in range(5):
        lo, hi = model.encoder_range(j + 1)
        lo_rad, hi_rad = model.joint_limits(j + 1)
        per_rad = abs(model.params(j + 1).enc_per_rad)
        held = all(abs(model.angle_to_encoder(j + 1, a) - start[j]) <= _ON_LIMIT_ENC
                   for a in q[:, j])
        for k in range(len(q)):
            e = model.angle_to_encoder(j + 1, q[k, j])
            if not lo - _ON_LIMIT_ENC <= e <= hi + _ON_LIMIT_ENC:
                raise TrajectoryError(
                    f"point {k}: {ARM_JOINTS[j]} = {q[k, j]:.4f} rad is outside its limits "
                    f"[{lo_rad:.4f}, {hi_rad:.4f}]"
                )
            if not ((k == 0 and at_start) or held) and not lo + margin <= e <= hi - margin:
                raise TrajectoryError(
                    f"point {k}: {ARM_JOINTS[j]} = {q[k, j]:.4f} rad is "
                    f"{min(abs(e - lo), abs(hi - e)):.0f} encoders from the end of its range; "
                    f"targets stay {margin} encoders inside it (limit_margin_encoders), in "
                    f"[{lo_rad + margin / per_rad:.4f}, {hi_rad - margin / per_rad:.4f}] rad"
                )
            enc[k, j] = e
    enc_per_tick = None
    if v is not None:
        enc_per_tick = np.array(
            [[model.speed_to_encoder(j + 1, v[k, j]) for j in range(5)] for k in range(len(q))]
        )
    return enc, enc_per_tick


def _from_start(
    model: EncoderModel,
    start: np.ndarray,
    times: np.ndarray,
    enc: np.ndarray,
    enc_per_tick: np.ndarray | None,
    min_segment_ticks: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Knot ticks, encoders and slopes starting where the arm is, at rest at both ends."""
    ticks = np.round(times / TICK_S)
    if ticks[0] <= 0.0:  # a point at t=0 stands for the current position
        gap = [
            abs(model.encoder_to_angle(j + 1, enc[0, j]) - model.encoder_to_angle(j + 1, start[j]))
            for j in range(5)
        ]
        gap = [min(g, 2 * math.pi - g) for g in gap]
        if max(gap) > START_TOLERANCE_RAD:
            j = int(np.argmax(gap))
            raise TrajectoryError(
                f"the point at t=0 puts {ARM_JOINTS[j]} {gap[j]:.3f} rad from where the arm is"
            )
        enc[0] = start
        if enc_per_tick is not None:
            enc_per_tick[0] = 0.0
    else:
        enc = np.vstack([start, enc])
        ticks = np.concatenate([[0.0], ticks])
        if enc_per_tick is not None:
            enc_per_tick = np.vstack([np.zeros(5), enc_per_tick])
    if len(ticks) == 1:  # only "be where you are": hold for one short segment
        ticks = np.array([0.0, float(min_segment_ticks)])
        enc = np.vstack([start, start])
        enc_per_tick = None
    if np.any(np.diff(ticks) <= 0.0):
        raise TrajectoryError("trajectory points closer than 10 ms apart")
    if enc_per_tick is None:
        enc_per_tick = np.zeros_like(enc)
    enc_per_tick[0] = 0.0
    enc_per_tick[-1] = 0.0
    return ticks, enc, enc_per_tick


def _knot_curve(
    ticks: np.ndarray, enc: np.ndarray, enc_per_tick: np.ndarray, min_segment_ticks: int
) -> tuple[CubicHermiteSpline, list[int]]:
    """The Hermite curve through the knots and the knots kept (at least min_segment_ticks
    apart; a goal shorter than that is slowed down to it)."""
    curve = CubicHermiteSpline(ticks, enc, enc_per_tick, axis=0)
    keep = _select_knots(ticks, min_segment_ticks)
    knot_ticks = [int(ticks[i]) for i in keep]
    if knot_ticks[-1] - knot_ticks[0] < min_segment_ticks:  # a very short goal: slow it down
        stretch = min_segment_ticks / max(knot_ticks[-1] - knot_ticks[0], 1)
        scaled = CubicHermiteSpline(ticks * stretch, enc, enc_per_tick / stretch, axis=0)
        curve, knot_ticks = scaled, [0, min_segment_ticks]
    return curve, knot_ticks


def _segment_row(
    model: EncoderModel,
    prev: Sequence[int],
    e1: np.ndarray,
    v0: np.ndarray,
    v1: np.ndarray,
    ticks: int,
    limits: _Limits,
) -> list[SplineSegment]:
    """One segment per motor from ``prev`` to ``e1``, checked against speed, acceleration and
    range (a segment may start inside the margin, where the arm is, but not go further out)."""
    row = []
    for j in range(5):
        c = hermite_coefficients(prev[j], float(e1[j]), float(v0[j]), float(v1[j]), ticks)
        per_rad = abs(model.speed_to_encoder(j + 1, 1.0))  # encoders per tick at 1 rad/s
        speed = cubic_speed_max(c[1], c[2], c[3], ticks)
        if speed > limits.speed[j] * (1.0 + 1e-6) + 1e-9:
            raise TrajectoryError(
                f"{ARM_JOINTS[j]} would move at {speed / per_rad:.3f} rad/s, above its "
                f"limit of {limits.speed[j] / per_rad:.3f} rad/s; give the trajectory more time"
            )
        accel = cubic_accel_max(c[2], c[3], ticks)
        if accel > limits.accel[j] * (1.0 + 1e-6) + 1e-9:
            to_rad_s2 = 1.0 / (per_rad * TICK_S)  # encoders per tick^2 -> rad/s^2
            raise TrajectoryError(
                f"{ARM_JOINTS[j]} would accelerate at {accel * to_rad_s2:.3f} rad/s^2, above "
                f"its limit of {limits.accel[j] * to_rad_s2:.3f} rad/s^2 ({limits.accel[j]:g} "
                "encoders per 10 ms squared, acceleration_limits); give the trajectory more time"
            )
        lo, hi = model.encoder_range(j + 1)
        low, high = cubic_extremes(c, ticks)
        if low < min(lo + limits.margin, prev[j]) or high > max(hi - limits.margin, prev[j]):
            raise TrajectoryError(
                f"{ARM_JOINTS[j]} would overshoot its limits between trajectory points (the "
                f"driver keeps {limits.margin} encoders inside them, limit_margin_encoders)"
            )
        row.append(quantize(c, float(e1[j]), ticks))
    return row
