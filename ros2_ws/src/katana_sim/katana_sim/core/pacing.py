"""How far the simulated world runs, and when: the sim's pacing, ROS-free.

Two modes, chosen by `real_time_factor` (rtf):

- rtf > 0 (paced): a stepping thread keeps simulated time at rtf times wall-clock time
  (`WallPacer`); action callbacks only start a motion and wait for it.
- rtf = 0 (fast, lock-step): physics runs only inside the motions it serves. The callback that
  started a motion steps the world itself until the motion has ended and every block is at rest
  (`run_motion`), so how far physics runs between two goals is a function of the goals alone,
  never of thread timing: two runs with the same seed and the same goals give the same world.
  While no motion runs, the clock still advances at wall-clock pace (timers and stamps of nodes
  with use_sim_time go on), but physics is frozen: nothing can move, since every motion ended
  with the world at rest.

`Schedule` says which periodic outputs (clock, joint states, ground truth, images) are due at a
simulated time, so their sequence follows simulated time in both modes.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from contextlib import AbstractContextManager

#: simulated seconds between the checks of a lock-stepped motion (and its feedback)
LOCKSTEP_CHUNK_S = 0.05
#: simulated seconds a motion may take to settle the blocks after its controller is done
SETTLE_MAX_S = 2.0

DONE, CANCELED, TIMEOUT, STOPPED = "done", "canceled", "timeout", "stopped"


class Schedule:
    """Periodic outputs due in simulated time: `due(t)` returns the names due at t."""

    def __init__(self, rates_hz: dict[str, float]) -> None:
        self._period: dict[str, float] = {}
        self._next: dict[str, float] = {}
        for name, hz in rates_hz.items():
            self.set_rate(name, hz)

    def set_rate(self, name: str, hz: float) -> None:
        """Change a rate (0 switches the output off); applies from the next due time."""
        self._period[name] = 1.0 / hz if hz > 0 else 0.0
        self._next.setdefault(name, 0.0)

    def period(self, name: str) -> float:
        return self._period[name]

    def due(self, t: float, only: tuple[str, ...] | None = None) -> list[str]:
        out = []
        for name, period in self._period.items():
            if period <= 0.0 or (only is not None and name not in only):
                continue
            if t + 1e-9 >= self._next[name]:
                out.append(name)
                # next slot after t on the grid of this period (no burst after a long motion)
                self._next[name] = max(self._next[name] + period, t + 0.5 * period)
        return out


class WallPacer:
    """Simulated time owed at a wall-clock instant, at `rate` simulated seconds per wall second.

    Falling behind by more than `max_lag_s` wall seconds drops the debt instead of racing to
    catch up (the machine cannot keep the pace; time stretches)."""

    def __init__(self, rate: float, max_lag_s: float = 0.25) -> None:
        if rate <= 0:
            raise ValueError(f"rate must be positive, got {rate}")
        self.rate = rate
        self.max_lag_s = max_lag_s
        self._wall0: float | None = None
        self._sim0 = 0.0

    def anchor(self, wall: float, sim_time: float) -> None:
        self._wall0, self._sim0 = wall, sim_time

    def owed(self, wall: float, sim_time: float) -> float:
        """Simulated seconds to run now (>= 0)."""
        if self._wall0 is None:
            self.anchor(wall, sim_time)
        behind = self._sim0 + (wall - self._wall0) * self.rate - sim_time
        if behind > self.max_lag_s * self.rate:
            self.anchor(wall, sim_time)
            return 0.0
        return max(0.0, behind)


def run_motion(
    sim,
    handle,
    lock: AbstractContextManager,
    budget_s: float,
    interrupted: Callable[[], str | None] = lambda: None,
    after_chunk: Callable[[], None] = lambda: None,
) -> str:
    """Lock-step: step `sim` until `handle`'s motion is done and the blocks are at rest.

    `budget_s` bounds the simulated time; `interrupted()` returns CANCELED or STOPPED to end
    the motion early (checked between chunks); `after_chunk()` runs under the lock after every
    chunk (publish what is due). Returns DONE, CANCELED, STOPPED or TIMEOUT."""
    chunk = max(1, int(round(LOCKSTEP_CHUNK_S / sim.dt)))
    with lock:
        end = sim.time + budget_s
    while True:
        with lock:  # checked under the lock: a node stopping closes the world under it
            why = interrupted()
            if why:
                return why
            if handle.outcome.done:
                sim.settle_motion(SETTLE_MAX_S)
                after_chunk()
                return DONE
            if sim.time >= end:
                return TIMEOUT
            # whole chunks the arm crosses without physics go in one call (PhysicsSim.free_run)
            sim.step(max(chunk, sim.free_run(chunk)))
            after_chunk()


def wait_motion(
    handle,
    event: threading.Condition,
    wall_budget_s: float,
    interrupted: Callable[[], str | None] = lambda: None,
    on_tick: Callable[[], None] = lambda: None,
    clock: Callable[[], float] | None = None,
) -> str:
    """Paced mode: wait (bounded in wall time) for the stepping thread to finish a motion."""
    now = clock or time.monotonic
    deadline = now() + wall_budget_s
    while not handle.outcome.done:
        why = interrupted()
        if why:
            return why
        if now() > deadline:
            return TIMEOUT
        on_tick()
        with event:
            event.wait(timeout=0.05)
    return DONE
