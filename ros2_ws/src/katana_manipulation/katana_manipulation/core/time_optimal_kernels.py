"""The compiled reachability passes of `time_optimal` (numba).

Why compiled: the two passes are a recurrence along the path grid (each x depends on the one
before), so NumPy cannot vectorise them, and in plain Python they cost most of a pick-and-place
plan (one took 29 ms with them, 12 ms compiled: docs/DESIGN.md). The reference twin is
`time_optimal.reachable_speeds_reference`; the tests hold the two to bit-equal results.

Same results, not approximately the same: each value is made by the reference's float64
operations in the same order ((k + step) / g and g * x + step; numba contracts no multiply-add
into an FMA unless fastmath), and every min and max is written as the comparison Python's
built-in makes (it keeps the first argument unless the other is strictly smaller or larger).

The kernel lives in a file of its own: numba's on-disk cache is invalidated only when the file
of the cached function changes.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def reachable_speeds(g, step, moving, xmax,
                     tiny):  # pragma: no cover - compiled; tested against the reference
    """Squared path speeds x on the grid: the backward pass (the largest x from which every
    later bound is still reachable) then the forward pass (as fast as those allow from rest).

    g, step: per interval and limit row, x_{i+1} in [g x_i - step, g x_i + step] for the rows
    that move; moving: which rows do; xmax: the speed bound at each grid point."""
    n, rows = g.shape[0] + 1, g.shape[1]
    k = xmax.copy()
    for i in range(n - 2, -1, -1):
        ki = k[i]
        for j in range(rows):
            if moving[i, j] and g[i, j] > tiny:
                v = (k[i + 1] + step[i, j]) / g[i, j]
                if v < ki:
                    ki = v
        if 0.0 > ki:
            ki = 0.0
        k[i] = ki
    x = np.zeros(n)
    for i in range(n - 1):
        nxt = k[i + 1]
        for j in range(rows):
            if moving[i, j]:
                v = g[i, j] * x[i] + step[i, j]
                if v < nxt:
                    nxt = v
        x[i + 1] = nxt if nxt > 0.0 else 0.0
    return x
