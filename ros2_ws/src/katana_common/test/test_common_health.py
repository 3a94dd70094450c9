"""katana_common.health: the rate meter against a count made by hand, and a stream's levels."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from katana_common.health import OK, WARN, RateMeter, stream_health


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
