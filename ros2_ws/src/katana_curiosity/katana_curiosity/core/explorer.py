"""The exploration loop of Algorithm 1 and the strategies compared in section 3.2.

A strategy looks at the setting and returns a choice: an instance to query directly, or a
planned (state, action) pair. The explorer executes it in the world, learns from the label
(planned outcomes are learned from too: the paper's agent "keeps on refining the learned model"
while it exploits it) and reports what happened. A new strategy is one small class, registered
by name in core.strategies.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .environment import Environment, Outcome, PlacementUnavailable, Setting, ShuffledSetting
from .planner import Planner, RewardTable
from .predictors import GAMMA, PredictorBank

QUERY, PLAN, RANDOM = 0, 1, 2
MODE_NAMES = {QUERY: "query", PLAN: "plan", RANDOM: "random"}


@dataclass(frozen=True)
class Choice:
    state: int
    action: int
    mode: int
    index: int | None = None  # position in the setting for a direct choice


@dataclass(frozen=True)
class Step:
    """One experiment: what was chosen, how, and the label it got."""

    state: int
    action: int
    mode: int
    label: int
    margin_before: float
    chi_before: float
    weights_before: np.ndarray | None = None  # only when the explorer records weights
    record: object = None  # the environment's record of the execution (Outcome.record)


class NoRouteToUnknown(PlacementUnavailable):
    """A planned choice not worth making: its outcome is known and it leads to no unknown pair,
    so the setting should change instead (the robot loop resets it). `reason` says why:
    no_route_to_unknown (the model sees no unknown pair beyond it), plan_leads_nowhere (made
    before in the same scene, it led only to scenes offering no pair unknown now),
    detour_too_long (as many known plans as the deepest plan were made in a row) or
    table_to_table (a placement on the table would move a block that lies on the table)."""

    def __init__(self, message: str, reason: str = "no_route_to_unknown") -> None:
        super().__init__(message)
        self.reason = reason


def first_unknown(bank: PredictorBank, setting: Setting | ShuffledSetting) -> Choice | None:
    """Algorithm 1, lines 2-9: the first instance in scan order whose query condition holds."""
    found = setting.first_where(bank.unknown)
    if found is None:
        return None
    index, state, action = found
    return Choice(state, action, QUERY, index)


class Strategy:
    """Base class: a strategy decides what to try in a setting."""

    name: ClassVar[str] = ""

    def __init__(self, bank: PredictorBank, top: int, gamma: float = GAMMA, seed: int = 0) -> None:
        self.bank = bank
        self.top = top
        self.gamma = gamma
        self.rng = random.Random(seed)

    def choose(self, setting: Setting | ShuffledSetting, step: int) -> Choice:
        raise NotImplementedError

    def alternatives(self, setting: Setting | ShuffledSetting, failed: Choice) -> list[Choice]:
        """Other choices to try when the world cannot realise `failed` (ranked)."""
        return []


class PlanningStrategy(Strategy):
    """Shared by the strategies that plan on the phantom-reward MDP. A subclass keeps its own
    state in `setup` and may plan on its own reward (`phantom_reward`), with no constructor."""

    reward: ClassVar[str] = "query"

    def __init__(self, bank: PredictorBank, top: int, gamma: float = GAMMA, seed: int = 0,
                 feasible: np.ndarray | None = None) -> None:
        super().__init__(bank, top, gamma, seed)
        self.setup()
        self.planner = Planner(bank, top, gamma, reward=self.phantom_reward(), feasible=feasible)

    def setup(self) -> None:
        """The strategy's own state, made before its planner (bank, top, gamma are set)."""

    def phantom_reward(self) -> str | RewardTable:
        """What the planner rewards: a kind of planner.REWARD_KINDS or a RewardTable."""
        return self.reward

    def planned(self, setting: Setting | ShuffledSetting, q: np.ndarray | None = None) -> Choice:
        """(s*, a*) constrained by availability (section 2.2): the available state of highest
        value, then the best action the setting offers there."""
        q = self.planner.q if q is None else q
        s, a = self.planner.choose(setting.available, q)
        offered = setting.actions_at(s)
        if len(offered) and a not in offered:
            a = int(offered[int(np.argmax(q[s, offered]))])
        return Choice(s, a, PLAN, setting.index_of(s, a))

    def alternatives(self, setting: Setting | ShuffledSetting, failed: Choice) -> list[Choice]:
        q = self.planner.q
        pairs = [
            (q[s, a], int(s), int(a))
            for s in setting.available
            for a in setting.actions_at(int(s))
        ]
        pairs.sort(key=lambda t: (-t[0], -t[1], t[2]))
        return [
            Choice(s, a, failed.mode, setting.index_of(s, a))
            for _, s, a in pairs
            if (s, a) != (failed.state, failed.action)
        ]


class Q1(PlanningStrategy):
    """The paper's method: query the first unknown instance; plan only when none is unknown."""

    name = "q1"

    def choose(self, setting: Setting | ShuffledSetting, step: int) -> Choice:
        direct = first_unknown(self.bank, setting)
        if direct is not None:
            return direct
        self.planner.solve()
        return self.planned(setting)


class Q10(Q1):
    """Like Q1, but the exploration policy is re-planned only every `period` observations."""

    name = "q10"
    period: ClassVar[int] = 10

    def setup(self) -> None:
        self.solved_at: int | None = None

    def choose(self, setting: Setting | ShuffledSetting, step: int) -> Choice:
        if self.solved_at is None or step - self.solved_at >= self.period:
            self.planner.solve()
            self.solved_at = step
        direct = first_unknown(self.bank, setting)
        if direct is not None:
            return direct
        return self.planned(setting)


class Conf(PlanningStrategy):
    """Ngo et al. 2012: plan every step with the confidence chi itself as the phantom reward."""

    name = "conf"
    reward = "confidence"

    def choose(self, setting: Setting | ShuffledSetting, step: int) -> Choice:
        self.planner.solve()
        return self.planned(setting)


class RandomChoice(Strategy):
    """Uniform random instance of the setting: undirected babbling."""

    name = "random"

    def choose(self, setting: Setting | ShuffledSetting, step: int) -> Choice:
        index, state, action = setting.random_instance(self.rng)
        return Choice(state, action, RANDOM, index)


class Explorer:
    """Algorithm 1 in a loop: observe, query or plan, execute, learn."""

    def __init__(
        self,
        world: Environment,
        bank: PredictorBank,
        strategy: Strategy,
        max_alternatives: int = 20,
        record_weights: bool = False,
        worth_making: Callable[[Strategy, Choice], str | None] | None = None,
        on_setting: Callable[[Setting | ShuffledSetting], None] | None = None,
        place_planned: Callable[[Setting | ShuffledSetting, Choice], Choice] | None = None,
    ) -> None:
        """The robot's hooks (None: the abstract world's behaviour):
        worth_making(strategy, choice): asked before a planned choice is executed; a reason
        code raises NoRouteToUnknown with it instead ("no experiment wasted"), None makes it.
        on_setting(setting): told of every observed setting before a choice is made.
        place_planned(setting, choice): which instance of a planned pair to make."""
        self.world, self.bank, self.strategy = world, bank, strategy
        self.max_alternatives = max_alternatives
        self.record_weights = record_weights
        self.worth_making = worth_making
        self.on_setting = on_setting
        self.place_planned = place_planned
        self.steps = 0

    def step(self) -> Step:
        setting = self.world.observe()
        if len(setting) == 0:
            raise PlacementUnavailable("the setting offers no instance")
        if self.on_setting is not None:
            self.on_setting(setting)
        choice = self._plan_to_make(setting, self.strategy.choose(setting, self.steps))
        (label, record), choice = self._execute(setting, choice)
        s, a = choice.state, choice.action
        margin, chi = float(self.bank.margin[s, a]), float(self.bank.chi[s, a])
        weights = self.bank.weights(s) if self.record_weights and self.bank.slot[s] >= 0 else None
        self.bank.update(s, a, label)
        self.steps += 1
        return Step(s, a, choice.mode, label, margin, chi, weights, record)

    def _plan_to_make(self, setting: Setting | ShuffledSetting, choice: Choice) -> Choice:
        """The plan to make: the strategy's choice, or when the robot's hooks refuse it the
        best alternative they accept; NoRouteToUnknown when they accept none."""
        if choice.mode != PLAN:
            return choice
        candidates = [choice]
        if self.worth_making is not None:
            candidates += self.strategy.alternatives(setting, choice)[: self.max_alternatives]
        refusal = None
        for candidate in candidates:
            if self.place_planned is not None:
                candidate = self.place_planned(setting, candidate)
            reason = (self.worth_making(self.strategy, candidate)
                      if self.worth_making is not None else None)
            if not reason:
                return candidate
            refusal = refusal or reason
        raise NoRouteToUnknown(f"the planned placement on height {choice.state}, action "
                               f"{choice.action + 1} is not worth making ({refusal}), nor any "
                               "other the setting offers", refusal)

    def _run(self, choice: Choice) -> tuple[int, object]:
        """(label, record) of executing `choice`; a bare label has no record."""
        result = self.world.execute(choice.state, choice.action, choice.index)
        if isinstance(result, Outcome):
            return result.label, result.record
        return result, None

    def _execute(
        self, setting: Setting | ShuffledSetting, choice: Choice
    ) -> tuple[tuple[int, object], Choice]:
        try:
            return self._run(choice), choice
        except PlacementUnavailable:
            if choice.mode != PLAN:
                raise
        # A planned pair the world cannot realise: try the next best ones.
        for alternative in self.strategy.alternatives(setting, choice)[: self.max_alternatives]:
            try:
                return self._run(alternative), alternative
            except PlacementUnavailable:
                continue
        raise PlacementUnavailable(
            f"no placement realises ({choice.state}, {choice.action}) or any alternative"
        )
