"""The strategy registry: every exploration strategy by name, and make_strategy.

It sits above the modules whose classes it registers (the paper's methods in explorer.py, the
related-work baselines in strategies_baselines.py), so neither imports the other back (as
gymnasium.envs registers environments defined in modules below it). A new strategy is a
class in its own module and one entry here.
"""

from __future__ import annotations

import numpy as np

from .explorer import Q1, Q10, Conf, PlanningStrategy, RandomChoice, Strategy
from .predictors import GAMMA, PredictorBank
from .strategies_baselines import BASELINES

STRATEGIES: dict[str, type[Strategy]] = {
    cls.name: cls for cls in (Q1, Q10, Conf, RandomChoice, *BASELINES)
}


def make_strategy(name: str, bank: PredictorBank, top: int, gamma: float = GAMMA, seed: int = 0,
                  feasible: np.ndarray | None = None) -> Strategy:
    """A strategy by name; `feasible` (states x actions) tells planners what can ever occur."""
    try:
        cls = STRATEGIES[name]
    except KeyError:
        raise ValueError(
            f"unknown strategy {name!r}: choose from {', '.join(sorted(STRATEGIES))}"
        ) from None
    if issubclass(cls, PlanningStrategy):
        return cls(bank, top, gamma, seed, feasible)
    return cls(bank, top, gamma, seed)
