"""Whether the robot's exploration still makes progress, online and from the log.

Online, for the robot loop: a planned placement whose outcome is known and after which the arm
is offered exactly the same (height, action) pairs as before changed nothing the learner can
use (on the sim: a loose block moved from the table to the table, next to a stack too tall to
place on). `FutilePlans` remembers such plans by the offer they were made in, so that the loop
changes the setting instead of making them again. `all_known` says when no pair the arm can
ever realise is unknown: the paper's agent "knows when to stop its planning efforts".

From the log, for summary.json: the experiments that were wasted (known before they were made,
and not on a way to an unknown pair), the longest streak of identical planned placements, and
the last query.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field

import numpy as np

from .environment import Setting, ShuffledSetting
from .predictors import PredictorBank, QueryRule
from .run_record import ExperimentRecord

#: (height, action) pairs a setting offers, action 0-based
Offer = frozenset[tuple[int, int]]


def offer_of(setting: Setting | ShuffledSetting) -> Offer:
    """The distinct (height, action) pairs the setting offers."""
    return frozenset(zip(np.asarray(setting.states).tolist(),
                         np.asarray(setting.actions).tolist(), strict=True))


def unknown_offered(bank: PredictorBank, offer: Offer) -> int:
    """How many of the offered pairs the learner would still query (Eq. 2)."""
    return sum(bool(bank.unknown[s, a]) for s, a in offer)


class Realisability:
    """Which (height, action) pairs the arm can realise, as far as its offers show.

    `feasible` says what can ever occur by geometry (core.robot_loop.feasible_actions); on top
    of that, a pair that was never offered in `evidence` settings offering its height is taken
    as one the arm does not realise (on the sim the fovea never offers action 5 on a stack: a
    planner rewarded for it would build stacks for it forever). A pair counts as realisable
    again the first time it is offered. Offers are noted from the experience log, so a resumed
    run knows what an uninterrupted one would.
    """

    def __init__(self, feasible: np.ndarray, evidence: int) -> None:
        self.feasible = np.asarray(feasible, dtype=bool)
        self.evidence = int(evidence)
        self.height_offered = np.zeros(self.feasible.shape[0], dtype=np.int64)
        self.pair_offered = np.zeros(self.feasible.shape, dtype=np.int64)

    def note(self, offer: Offer) -> None:
        for height in {h for h, _ in offer}:
            self.height_offered[height] += 1
        for height, action in offer:
            self.pair_offered[height, action] += 1

    @property
    def table(self) -> np.ndarray:
        """feasible, less the pairs shown unrealisable (0 means: never, with no evidence)."""
        if self.evidence <= 0:
            return self.feasible.copy()
        seen = (self.pair_offered > 0) | (self.height_offered < self.evidence)[:, None]
        return self.feasible & seen


def unknown_realisable(bank: PredictorBank, feasible: np.ndarray, top: int) -> np.ndarray:
    """(heights below `top`) x actions: the pairs that can occur (`feasible`) and are unknown;
    none left means the learner knows everything the arm can realise."""
    return bank.unknown[:top] & feasible[:top]


#: what a setting looks like to the loop: its offer and the heights of its stacks
Scene = Hashable


@dataclass
class FutilePlans:
    """Known planned placements that cannot lead anywhere new, by the scene they were made in.

    A scene is what the loop can tell settings apart by: the offer and the heights of the
    stacks (two settings with the same offer but other stacks are different places to be). The
    scenes since the last experiment on an unknown pair (or the last reset) form a chain. A
    known plan is futile in its scene when it led back to a scene of the chain (it changed
    nothing, or closed a cycle: on the sim, building a two-stack the arm could not use and
    taking it down again), or when it led to a dead end, a scene in which the loop had to change
    the setting instead of going on.

    Call `observed(scene)` for every observed scene, `made(scene, height, action)` after a
    planned placement of a known pair, `restart()` after a reset, `learned()` after an
    experiment on an unknown pair, and `dead_end()` when the loop changes the setting instead
    of a plan. What is futile is forgotten when the learner learns something new: one failed
    attempt in the scene every reset makes (loose blocks) must not bar a plan for good.
    """

    futile: set[tuple[Scene, int, int]] = field(default_factory=set)
    _pending: tuple[Scene, int, int] | None = None  # the known plan the next scene comes from
    _led_here: tuple[Scene, int, int] | None = None  # the known plan the current scene came from
    _chain: list[Scene] = field(default_factory=list)

    def made(self, scene: Scene, height: int, action: int) -> None:
        self._pending = (scene, int(height), int(action))

    def restart(self) -> None:
        self._pending = self._led_here = None
        self._chain = []

    def learned(self) -> None:
        self.restart()
        self.futile.clear()

    def observed(self, scene: Scene) -> bool:
        """Note a scene; True when the known plan that led to it led back into the chain."""
        pending, self._pending = self._pending, None
        self._led_here = pending
        back = pending is not None and scene in self._chain
        if back:
            self.futile.add(pending)
        self._chain.append(scene)
        return back

    def dead_end(self) -> None:
        """The current scene offered nothing worth making: the plan that led here is futile."""
        if self._led_here is not None:
            self.futile.add(self._led_here)
            self._led_here = None

    def is_futile(self, scene: Scene, height: int, action: int) -> bool:
        return (scene, int(height), int(action)) in self.futile


# -- from the log ---------------------------------------------------------------------------


def known_before(record: ExperimentRecord, rule: QueryRule) -> bool:
    """Whether the learner would not have queried the pair when the experiment was made."""
    chi, margin = record.confidence_before, record.margin_before
    return not bool(rule.is_query(np.array(margin), np.array(chi)))


def wasted_experiments(records: Sequence[ExperimentRecord], rule: QueryRule) -> list[int]:
    """Indices of the experiments that were known before they were made and did not lead, with
    no reset in between, to an experiment on an unknown pair. A plan that builds a stack
    towards an unknown pair is not wasted; a run of known placements that ends in a reset, a
    setting change or the end of the run is."""
    wasted: list[int] = []
    chain: list[int] = []
    for record in records:
        if chain and record.resets_before:
            wasted.extend(chain)
            chain = []
        if known_before(record, rule):
            chain.append(record.index)
        else:
            chain = []
    return wasted + chain


def longest_identical_plan_streak(records: Sequence[ExperimentRecord]) -> int:
    """The most planned placements in a row on the same height with the same action in the
    same offer of heights (the livelock: one block moved from the table to the table)."""
    longest = streak = 0
    previous = None
    for record in records:
        key = (record.state, record.action, tuple(record.available))
        if record.mode != "plan":
            streak, previous = 0, None
            continue
        streak = streak + 1 if key == previous else 1
        previous = key
        longest = max(longest, streak)
    return longest


def last_query(records: Sequence[ExperimentRecord]) -> int | None:
    """Index of the last experiment that was a query, or None."""
    return next((r.index for r in reversed(records) if r.mode == "query"), None)
