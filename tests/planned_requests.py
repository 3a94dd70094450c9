"""Pick-and-place requests inside the arm's reach, for the hypothesis tests of planned motions
(the driver's acceptance, the least motion time): one strategy, so both draw the same goals."""

from __future__ import annotations

import math

from hypothesis import strategies as st
from katana_description import models as m
from katana_manipulation.core import pick_place as pp
from katana_manipulation.core.reach import pick_reach, place_reach


def _at(band, frac: float, angle: float, z: float) -> tuple[float, float, float]:
    r = band.min_m + frac * (band.max_m - band.min_m)
    return (r * math.cos(angle), r * math.sin(angle), z)


_spots = st.tuples(st.floats(0.02, 0.98), st.floats(-1.4, 1.4), st.floats(-1.5, 1.5))


@st.composite
def reachable_requests(draw) -> pp.PickPlaceRequest | None:
    """A block picked from level 1-3 and placed on a stack of 0-3, each at a fraction of its
    reach band, a bearing and a yaw; None where a band is empty."""
    pick_level, place_height = draw(st.integers(1, 3)), draw(st.integers(0, 3))
    pick, place = draw(_spots), draw(_spots)
    h = m.BLOCK_SIZE[2]
    pick_band, place_band = pick_reach(pick_level, h), place_reach(place_height, h)
    if pick_band.empty or place_band.empty:
        return None
    return pp.PickPlaceRequest(_at(pick_band, pick[0], pick[1], (pick_level - 0.5) * h), pick[2],
                               m.BLOCK_SIZE,
                               _at(place_band, place[0], place[1], (place_height + 0.5) * h),
                               place[2])
