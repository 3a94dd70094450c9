"""The compiled kernel of the fovea's features (core.fovea.FoveaScene.features_at).

Why compiled: the reference (FoveaSceneReference) rotates every pixel of each nearby stack and
hulls the intersection pixels with OpenCV at each of the ~500 locations an observe visits,
~20 array calls a location. Here one call per location visits only the rows the window can
reach and keeps, per row, only the outermost intersection pixels, which hold every hull vertex.

Same results, not approximately the same:
- window membership is the reference's arithmetic, operation for operation (dx * c + dy * s,
  dx * -s + dy * c, in float64; numba contracts no multiply-add into an FMA unless fastmath),
  so the counts and the pixel sets are those of the reference;
- the hull is exact (integer pixel coordinates, integer cross products); a probe point is
  decided only when it is at least TOLERANCE_PX from every hull edge's line on the decided
  side, far beyond where OpenCV's float32 hull of the same pixels can differ from the exact
  one (~1e-5 px). Otherwise (and for a hull of area exactly 0.5 px^2, which OpenCV's float
  area may put either side of its 0.5 cut) the kernel answers UNSURE and the caller asks the
  reference's hull_bits.

The kernels live in one file: numba's on-disk cache is invalidated only when the file of the
cached function changes.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

UNSURE = -1  # the bits code when the caller must ask the reference's hull_bits
TOLERANCE_PX = 1e-3


@nb.njit(cache=True)
def _cross(ox: int, oy: int, ax: int, ay: int, bx: int, by: int) -> int:
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


@nb.njit(cache=True, inline="always")
def _in_window(dx: float, dy: float, c: float, s: float, ms: float, half: float) -> bool:
    """A pixel at (dx, dy) from the fovea centre lies in its window: the reference's
    to_fovea_frame and in_window, the same float64 operations in the same order."""
    lx = dx * c + dy * s
    if not (lx >= -half and lx < half):
        return False
    ly = dx * ms + dy * c
    return ly >= -half and ly < half


@nb.njit(cache=True)
def features_at(xs, inter, starts, heights, near_lo, near_hi, u, v, c, s, half, probes,
                tol):  # pragma: no cover - compiled; tested against the reference
    """(index of the stack under the fovea or -1, its five bits as a bit mask or UNSURE).

    xs: int64 column of each pixel of all stacks' union masks, row-major per stack; inter:
    whether each is in its stack's intersection mask; starts[k, y]: index of stack k's first
    pixel in image row y (starts[k, rows] ends it); heights, near_lo, near_hi: per stack, the
    bounding box of its union grown by the reference's reach; probes: the five points in the
    fovea frame."""
    n_stacks = heights.shape[0]
    rows = starts.shape[1] - 1
    reach = half * (abs(c) + abs(s)) + 2.0  # the window's bounding box, with a margin
    y0 = max(0, int(math.ceil(v - reach)))
    y1 = min(rows - 1, int(math.floor(v + reach)))
    ms = -s
    best, best_h, best_n = -1, -1, -1
    near = np.zeros(n_stacks, np.bool_)
    for k in range(n_stacks):
        near[k] = near_lo[k, 0] <= u <= near_hi[k, 0] and near_lo[k, 1] <= v <= near_hi[k, 1]
    for k in range(n_stacks):
        if not near[k]:
            continue
        h = heights[k]
        if h < best_h:  # the key is (height, count): a lower stack cannot win
            continue
        # the count matters only against another nearby stack as tall; else any pixel will do
        rival = False
        for j in range(n_stacks):
            if j != k and near[j] and heights[j] == h:
                rival = True
        n = 0
        for y in range(y0, y1 + 1):
            dy = float(y) - v
            for i in range(starts[k, y], starts[k, y + 1]):
                if _in_window(float(xs[i]) - u, dy, c, s, ms, half):
                    n += 1
                    if not rival:
                        break
            if n > 0 and not rival:
                break
        if n > 0 and (h > best_h or n > best_n):  # ties: the first stack in id order
            best, best_h, best_n = k, h, n
    if best < 0:
        return -1, 0
    k = best
    # The outermost intersection pixels of each row inside the window, sorted by (y, x). A
    # row's pixels are sorted by x and each of the four window tests is monotonic in x (so is
    # every rounded step of it): the row's pixels in the window are one run, found from both
    # ends.
    px = np.empty(2 * (y1 - y0 + 1), np.int64)
    py = np.empty(2 * (y1 - y0 + 1), np.int64)
    npts = 0
    for y in range(y0, y1 + 1):
        dy = float(y) - v
        first = -1
        for i in range(starts[k, y], starts[k, y + 1]):
            if inter[i] and _in_window(float(xs[i]) - u, dy, c, s, ms, half):
                first = i
                break
        if first < 0:
            continue
        px[npts], py[npts] = xs[first], y
        npts += 1
        for i in range(starts[k, y + 1] - 1, first, -1):
            if inter[i] and _in_window(float(xs[i]) - u, dy, c, s, ms, half):
                px[npts], py[npts] = xs[i], y
                npts += 1
                break
    if npts < 3:
        # one pixel, two, or one row's run: fewer than 3 pixels or no area; nothing inside
        return k, 0
    # Andrew's monotone chain over (y, x) order, collinear points dropped.
    hx = np.empty(2 * npts + 1, np.int64)
    hy = np.empty(2 * npts + 1, np.int64)
    nh = 0
    for i in range(npts):
        while nh >= 2 and _cross(hx[nh - 2], hy[nh - 2], hx[nh - 1], hy[nh - 1],
                                 px[i], py[i]) <= 0:
            nh -= 1
        hx[nh], hy[nh] = px[i], py[i]
        nh += 1
    lower = nh + 1
    for i in range(npts - 2, -1, -1):
        while nh >= lower and _cross(hx[nh - 2], hy[nh - 2], hx[nh - 1], hy[nh - 1],
                                     px[i], py[i]) <= 0:
            nh -= 1
        hx[nh], hy[nh] = px[i], py[i]
        nh += 1
    nh -= 1  # the last point is the first again
    if nh < 3:
        return k, 0  # collinear: no area, nothing inside (the reference's area < 0.5)
    area2 = 0
    for i in range(nh):
        j = (i + 1) % nh
        area2 += hx[i] * hy[j] - hx[j] * hy[i]
    if area2 == 0:
        return k, 0
    if abs(area2) == 1:
        return k, UNSURE  # area 0.5: OpenCV's float area may fall either side of 0.5
    sign = 1.0 if area2 > 0 else -1.0
    code = 0
    for p in range(probes.shape[0]):
        a, b = probes[p, 0], probes[p, 1]
        qx = u + a * c - b * s
        qy = v + a * s + b * c
        dmin = math.inf
        for i in range(nh):
            j = (i + 1) % nh
            ex, ey = float(hx[j] - hx[i]), float(hy[j] - hy[i])
            d = sign * (ex * (qy - hy[i]) - ey * (qx - hx[i])) / math.sqrt(ex * ex + ey * ey)
            dmin = min(dmin, d)
        if abs(dmin) < tol:
            return k, UNSURE
        if dmin > 0:
            code |= 1 << p
    return k, code
