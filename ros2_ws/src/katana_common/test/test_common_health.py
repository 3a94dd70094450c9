"""katana_common.health: the rate meter against a count made by hand, and a stream's levels."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_common.health import OK, WARN, ClockRatio, RateMeter, pace_health, stream_health


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


@settings(max_examples=200, deadline=None)
@given(gaps=st.lists(st.floats(0.0, 5.0), max_size=40), window=st.floats(0.5, 20.0),
       wait=st.floats(0.0, 30.0))
def test_the_rate_is_the_events_in_the_window_over_the_window(gaps, window, wait) -> None:
    clock = FakeClock()
    meter = RateMeter(window, now=clock)
    times = []
    for gap in gaps:
        clock.t += gap
        meter.tick()
        times.append(clock.t)
    clock.t += wait
    now = clock.t
    in_window = sum(now - window <= t <= now for t in times)
    span = min(window, now - 100.0)
    expected = in_window / span if span > 0 else 0.0
    assert meter.per_second() == pytest.approx(expected)
    assert meter.count == len(times)
    assert meter.age_s() == (pytest.approx(now - times[-1]) if times else None)


def test_a_stream_warns_before_its_first_message_and_when_it_stops() -> None:
    clock = FakeClock()
    meter = RateMeter(10.0, now=clock)
    assert stream_health("images", meter).level == WARN
    for _ in range(20):
        clock.t += 0.1
        meter.tick()
    health = stream_health("images", meter)
    assert health.level == OK and health.values["images_per_s"] == pytest.approx(10.0)
    clock.t += 2.5
    stale = stream_health("images", meter, stale_after_s=2.0)
    assert stale.level == WARN and "no images for 2.5 s" in stale.message


def test_a_window_must_be_positive() -> None:
    with pytest.raises(ValueError, match="window_s"):
        RateMeter(0.0)


def test_the_clock_ratio_is_clock_over_wall_time_in_the_window() -> None:
    wall, sim = FakeClock(), FakeClock()
    meter = ClockRatio(sim, window_s=5.0, now=wall)
    assert meter.ratio() is None  # one sample
    for _ in range(20):  # the sim at 2x wall time, then at 0.5x
        wall.t += 1.0
        sim.t += 2.0
    assert meter.ratio() == pytest.approx(2.0)
    for _ in range(10):
        wall.t += 1.0
        sim.t += 0.5
        ratio = meter.ratio()
    assert ratio == pytest.approx(0.5)  # the window holds only the slow part now


@pytest.mark.parametrize(("ratio", "target", "level"), [
    (None, 1.0, OK), (5.0, 0.0, OK), (0.95, 1.0, OK), (0.85, 1.0, WARN), (0.3, 0.0, OK)])
def test_a_sim_behind_its_pace_warns(ratio, target, level) -> None:
    assert pace_health(ratio, target, 12.0).level == level
