"""Whether the robot's exploration still makes progress, online and from the log.

Online, for the robot loop: `PlanOutcomes` remembers where every placement led, scene to scene,
so that a known plan that cannot lead to an unknown pair any more (it changed nothing, closed a
cycle, or ends in scenes offering only known pairs) is not made again; the loop changes the
setting instead. `unknown_realisable` says when no pair the arm can
ever realise is unknown: the paper's agent "knows when to stop its planning efforts".

From the log, for summary.json: the experiments that were wasted (known before they were made,
predicted right, and not on a way to an experiment that taught the learner), the longest streak
of identical planned placements, and the last query.
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
class PlanOutcomes:
    """Where each placement led, scene to scene, so that a known plan is made only while it can
    still lead to a pair the learner does not know.

    A scene is what the loop tells settings apart by (on the robot: the heights offered and the
    heights of the stacks), with every pair it was seen to offer. Every placement adds an edge from
    the scene it was made in to the scene observed after it. The scenes since the last
    experiment that taught the learner (on an unknown pair, or known and mispredicted: `made`
    with known=False) or the last reset form the chain. A plan tried before leads
    nowhere when no scene reachable over the recorded edges in at most `depth` placements,
    without entering a scene of the chain, offers a pair that is unknown now: it changed
    nothing, closed a cycle (on the sim, building a two-stack the arm cannot use and taking it
    down again), or ends in scenes that offer only known pairs (a two-stack whose top offers
    nothing new). The depth is that of the deepest plan (one placement per height): a way to an
    unknown pair longer than that is not one the planner takes. The test is made against the
    learner's unknown pairs at the time of asking, so a plan comes back as soon as learning
    makes a pair beyond it unknown again; a plan never tried in a scene gets one try.

    However the scenes are told apart, a chain of as many known placements as the deepest plan
    that reached no unknown pair is not extended (`detour_too_long`).

    Call `observed(scene, offer)` for every observed scene, `made(scene, height, action, known)`
    after every placement and `restart()` after a reset.
    """

    depth: int = 4
    _offers: dict[Scene, Offer] = field(default_factory=dict)
    _led_to: dict[tuple[Scene, int, int], set[Scene]] = field(default_factory=dict)
    _tried: dict[Scene, set[tuple[int, int]]] = field(default_factory=dict)
    _pending: tuple[Scene, int, int] | None = None  # the placement the next scene comes from
    _chain: list[Scene] = field(default_factory=list)
    _chain_ends: bool = False  # the last placement was on an unknown pair
    _known_made: int = 0  # known placements made in the chain

    def made(self, scene: Scene, height: int, action: int, known: bool = True,
             leads: bool = True) -> None:
        """A placement was made in `scene`; `known`: its pair was known and it came out as
        predicted; `leads` False: where it led says nothing of the plan (its scene is noted in
        the chain, but no edge is recorded)."""
        self._pending = (scene, int(height), int(action)) if leads else None
        self._chain_ends = not known
        self._known_made += bool(known)

    def restart(self) -> None:
        self._pending = None
        self._chain = []
        self._known_made = 0

    @property
    def detour_too_long(self) -> bool:
        """Whether the chain holds as many known placements as the deepest plan: a way to an
        unknown pair is never longer, so the chain is going round (on the sim, scenes told
        apart by a perceived detail, such as a block on its side seen or not, hide a cycle)."""
        return self._known_made >= self.depth

    @property
    def chain(self) -> tuple[Scene, ...]:
        return tuple(self._chain)

    def observed(self, scene: Scene, offer: Offer) -> bool:
        """Note a scene; True when the placement that led to it left the scene as it was."""
        self._offers[scene] = self._offers.get(scene, frozenset()) | offer
        pending, self._pending = self._pending, None
        if self._chain_ends:
            self._chain, self._chain_ends, self._known_made = [], False, 0
        self._chain.append(scene)
        if pending is None:
            return False
        self._led_to.setdefault(pending, set()).add(scene)
        self._tried.setdefault(pending[0], set()).add(pending[1:])
        return scene == pending[0]

    def tried(self, scene: Scene, height: int, action: int) -> bool:
        return (scene, int(height), int(action)) in self._led_to

    def leads_nowhere(self, scene: Scene, height: int, action: int,
                      unknown: np.ndarray) -> bool:
        """Whether the plan was tried in `scene` and nothing it led to, nor anything reachable
        from there by placements made before (breadth first, `depth` placements in all, never
        into the chain or `scene`), offers a pair that is `unknown` (heights x actions) now."""
        outcomes = self._led_to.get((scene, int(height), int(action)))
        if not outcomes:
            return False
        seen = {scene, *self._chain}
        layer = {s for s in outcomes if s not in seen}
        for step in range(self.depth):
            if any(bool(unknown[h, a]) for here in layer for h, a in self._offers.get(here, ())
                   if h < unknown.shape[0]):
                return False
            seen |= layer
            if step + 1 == self.depth:
                break
            layer = {there for here in layer for h, a in self._tried.get(here, ())
                     for there in self._led_to[(here, h, a)]} - seen
        return True


def blocks_short(height: int, target: int, movable: int) -> bool:
    """Whether a known placement on `height` that builds towards an unknown pair at `target`
    leaves too few blocks to get there, `movable` being the blocks the arm could move now
    (the one this placement moves among them). On a stack (height >= 1) its old top is covered
    and the moved block is the new top, so `movable - 2` blocks remain for the `target - height`
    placements still needed (the known ones and the query), one block each. On the table the
    moved block is the new base and the stack it leaves may uncover one more block, so at most
    `movable` remain for `target` placements. On the sim a fall often leaves a block on its side
    (never moved again): the loop took a two-stack's top down and built it again with nothing
    left to put on it."""
    if target <= height:
        return False
    return movable - (2 if height else 0) < target - height


# -- from the log ---------------------------------------------------------------------------


def known_before(record: ExperimentRecord, rule: QueryRule) -> bool:
    """Whether the learner would not have queried the pair when the experiment was made."""
    chi, margin = record.confidence_before, record.margin_before
    return not bool(rule.is_query(np.array(margin), np.array(chi)))


def mispredicted(record: ExperimentRecord) -> bool:
    """Whether the outcome contradicted the learner's prediction (the sign of its margin)."""
    return record.label * record.margin_before <= 0


def taught(record: ExperimentRecord, rule: QueryRule) -> bool:
    """Whether the experiment taught the learner something: its pair was unknown, or the
    learner thought it known and the outcome proved it wrong (the mistake moves the weights
    and can make the pair unknown again, so it is no repetition of what was known)."""
    return not known_before(record, rule) or mispredicted(record)


def wasted_experiments(records: Sequence[ExperimentRecord], rule: QueryRule) -> list[int]:
    """Indices of the experiments that were known before they were made, came out as predicted
    and did not lead, with no reset in between, to an experiment that taught the learner
    (`taught`). A plan that builds a stack towards an unknown pair is not wasted; a run of
    known placements that ends in a reset, a setting change or the end of the run is."""
    return [records[i].index for i in wasted_positions(
        [taught(r, rule) for r in records], [r.resets_before for r in records])]


def wasted_positions(taught_flags: Sequence[bool], resets_before: Sequence[int]) -> list[int]:
    """`wasted_experiments` on plain sequences (positions, in order): an experiment that did not
    teach is wasted unless a later one teaches before any reset. Shared by the loop's summary
    and the study's replay (katana_paper.robot_paper), so both count the same experiments."""
    wasted: list[int] = []
    chain: list[int] = []
    for i, (taught_it, resets) in enumerate(zip(taught_flags, resets_before, strict=True)):
        if chain and resets:
            wasted.extend(chain)
            chain = []
        if taught_it:
            chain = []
        else:
            chain.append(i)
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
