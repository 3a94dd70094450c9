"""The least time a joint-space path can be followed in under per-joint speed and acceleration
limits (time-optimal path parameterisation). ROS-free.

The path through the waypoints is the monotone cubic (scipy's PCHIP, Fritsch-Carlson) over the
waypoints' cumulative joint-space distance: straight where the waypoints are collinear, and a
joint stops at a waypoint where it turns back, as the planner's own timing makes it. Along the
path q(s) the speed s' and acceleration s'' obey, per joint j, |q_j' s'| <= v_j and
|q_j' s'' + q_j'' s'^2| <= a_j. On a fine grid of s, x = s'^2 is pushed as high as those allow
by a backward pass (the largest x from which the arm can still stop in time) and a forward pass
(the largest x reachable from rest), constant s'' on each grid interval and the limits held at
both its ends (the interpolation discretisation of TOPP-RA, Pham and Pham 2018, with its
one-dimensional sets written in closed form).

toppra (PyPI) computes the same but needs matplotlib at run time; for box limits the
reachability passes are a few lines here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from katana_manipulation.core.time_optimal_kernels import reachable_speeds

#: grid intervals per path segment (between waypoints); the time converges as 1/n
GRID_PER_SEGMENT = 60
_TINY = 1e-9


@dataclass(frozen=True)
class Profile:
    """A time-optimal motion along a path: grid parameters ``s``, path speeds ``sdot`` there,
    the times ``t`` they are reached at, and the waypoints' parameters ``s_knots``."""

    s: np.ndarray
    sdot: np.ndarray
    t: np.ndarray
    s_knots: np.ndarray
    path: PchipInterpolator | None

    @property
    def duration(self) -> float:
        return float(self.t[-1]) if len(self.t) else 0.0

    def knot_times(self) -> np.ndarray:
        """When the waypoints are passed."""
        return np.interp(self.s_knots, self.s, self.t)


def waypoint_path(
        points: Sequence[Sequence[float]]) -> tuple[PchipInterpolator | None, np.ndarray]:
    """The monotone cubic through the points (repeated ones dropped) over their cumulative
    Euclidean joint-space distance, and the points' parameters."""
    q = np.atleast_2d(np.asarray(points, float))
    keep = np.concatenate([[True], np.linalg.norm(np.diff(q, axis=0), axis=1) > _TINY])
    q = q[keep].copy()
    for k in range(1, len(q)):  # a joint that barely moves does not (its secant would be
        # subnormal, and the monotone cubic's harmonic mean of secants overflow)
        q[k] = np.where(np.abs(q[k] - q[k - 1]) < _TINY, q[k - 1], q[k])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])
    if len(q) < 2:
        return None, s
    return PchipInterpolator(s, q, axis=0), s


def _max_x(b: np.ndarray, c: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Per interval, the largest x = s'^2 with some u within every row |b u + c x| <= a:
    u in [-beta x - r, -beta x + r] for a row with b != 0 (beta = c / b, r = a / |b|), and
    |c x| <= a for one with b = 0; the intervals overlap iff x (beta_k - beta_j) <= r_j + r_k
    for every pair."""
    moving = np.abs(b) > _TINY
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        x = np.min(np.where(~moving & (np.abs(c) > _TINY), a / np.abs(c), np.inf), axis=1)
        beta = np.where(moving, c / np.where(moving, b, 1.0), 0.0)
        r = np.where(moving, a / np.where(moving, np.abs(b), 1.0), np.inf)
        gap = beta[:, None, :] - beta[:, :, None]
        both = moving[:, :, None] & moving[:, None, :] & (gap > _TINY)
        bound = np.where(both, (r[:, :, None] + r[:, None, :]) / np.where(both, gap, 1.0),
                         np.inf)
    return np.minimum(x, bound.reshape(len(x), -1).min(axis=1))


def time_optimal(points: Sequence[Sequence[float]], vmax: Sequence[float],
                 amax: Sequence[float], grid_per_segment: int = GRID_PER_SEGMENT,
                 min_segment_time: float = 0.0) -> Profile:
    """The fastest motion from rest to rest through ``points`` (rows: joint positions, rad)
    on their monotone-cubic path, each joint within ``vmax`` (rad/s) and ``amax`` (rad/s^2).

    ``min_segment_time`` > 0 also caps the path speed on each stretch between waypoints at its
    length over that time, so none is passed quicker (the driver's shortest spline segment)."""
    vmax, amax = np.asarray(vmax, float), np.asarray(amax, float)
    if np.any(vmax <= 0.0) or np.any(amax <= 0.0):
        raise ValueError(f"limits must be positive: vmax {vmax}, amax {amax}")
    path, knots = waypoint_path(points)
    if path is None:
        z = np.zeros(1)
        return Profile(z, z, z, knots, None)
    s = np.concatenate([np.linspace(a, b, grid_per_segment, endpoint=False)
                        for a, b in zip(knots[:-1], knots[1:], strict=True)] + [knots[-1:]])
    ds = np.diff(s)
    qd = path(s, 1)
    end = s[1:] - 1e-9 * ds  # the interval's end, on its own piece of the cubic
    qd_end, qdd_end = path(end, 1), path(end, 2)
    b = np.hstack([qd[:-1], qd_end + 2.0 * ds[:, None] * qdd_end])
    c = np.hstack([path(s[:-1], 2), qdd_end])
    a = np.concatenate([amax, amax])
    with np.errstate(divide="ignore", over="ignore"):
        xmax = np.min(np.where(np.abs(qd) > _TINY, (vmax / np.abs(qd)) ** 2, np.inf), axis=1)
    xmax[:-1] = np.minimum(xmax[:-1], _max_x(b, c, a))
    if min_segment_time > 0.0:
        seg = np.minimum(np.searchsorted(knots, s, side="right") - 1, len(knots) - 2)
        cap = (np.diff(knots)[seg] / min_segment_time) ** 2
        xmax = np.minimum(xmax, np.minimum(cap, np.concatenate([cap[1:], cap[-1:]])))
    xmax[0] = xmax[-1] = 0.0
    moving = np.abs(b) > _TINY
    with np.errstate(divide="ignore", invalid="ignore"):
        beta = np.where(moving, c / np.where(moving, b, 1.0), 0.0)
        step = 2.0 * ds[:, None] * np.where(moving, a / np.where(moving, np.abs(b), 1.0), 0.0)
    g = 1.0 - 2.0 * ds[:, None] * beta
    x = reachable_speeds(g, step, moving, xmax, _TINY)
    sdot = np.sqrt(x)
    with np.errstate(divide="ignore"):
        dt = np.where(sdot[:-1] + sdot[1:] > 0.0, 2.0 * ds / (sdot[:-1] + sdot[1:]), np.inf)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    return Profile(s, sdot, t, knots, path)


def reachable_speeds_reference(g: np.ndarray, step: np.ndarray, moving: np.ndarray,
                               xmax: np.ndarray, tiny: float = _TINY) -> np.ndarray:
    """The reachability passes in plain Python: the reference twin of the compiled
    `time_optimal_kernels.reachable_speeds`, which must give bit-equal results.

    x_{i+1} = x_i + 2 ds u_i with u_i in [max_j(-beta_j x_i - r_j), min_j(-beta_j x_i + r_j)]
    over the moving rows j: x_{i+1} in [max_j(g_j x_i - step_j), min_j(g_j x_i + step_j)]."""
    rows = [[(gj, sj) for gj, sj, mj in zip(gi, si, mi, strict=True) if mj]
            for gi, si, mi in zip(g.tolist(), step.tolist(), moving.tolist(), strict=True)]
    # backward: the largest x at s_i from which x_{i+1} <= k[i+1] is still reachable
    k = xmax.tolist()
    for i in range(len(k) - 2, -1, -1):
        for gj, sj in rows[i]:
            if gj > tiny:
                k[i] = min(k[i], (k[i + 1] + sj) / gj)
        k[i] = max(k[i], 0.0)
    # forward: as fast as the limits and the controllable set allow
    x = [0.0] * len(k)
    for i in range(len(k) - 1):
        nxt = k[i + 1]
        for gj, sj in rows[i]:
            nxt = min(nxt, gj * x[i] + sj)
        x[i + 1] = max(0.0, nxt)
    return np.array(x)


def minimum_time(points: Sequence[Sequence[float]], vmax: Sequence[float],
                 amax: Sequence[float], grid_per_segment: int = GRID_PER_SEGMENT) -> float:
    """Least duration (s) of a rest-to-rest motion through ``points``; see `time_optimal`."""
    return time_optimal(points, vmax, amax, grid_per_segment).duration
