"""The small environment protocol the explorer is written against.

The same explorer drives the abstract blocks world in-process and the simulated or real arm
through ROS: an environment lists the instances of its current setting in scan order, executes
one (or finds a place that realises a planned state-action pair), and reports the label, with
what it did on the way (an `Outcome`) when it has more to say than the label.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np


class PlacementUnavailable(RuntimeError):
    """The world cannot realise a requested (state, action) in its current setting."""


@dataclass(frozen=True)
class Setting:
    """The instances of one setting, in scan order, and the states available in it."""

    states: np.ndarray  # (n,) int: height under each instance
    actions: np.ndarray  # (n,) int: 0-based action index of each instance
    available: np.ndarray  # sorted distinct states of the setting

    def __len__(self) -> int:
        return len(self.states)

    @classmethod
    def from_pairs(cls, states: np.ndarray, actions: np.ndarray) -> Setting:
        states = np.asarray(states, dtype=int)
        return cls(states, np.asarray(actions, dtype=int), np.unique(states))

    def first_where(self, table: np.ndarray) -> tuple[int | None, int, int] | None:
        """The first instance in scan order whose (state, action) entry of `table` is true."""
        flags = table[self.states, self.actions]
        index = int(flags.argmax())
        if not flags[index]:
            return None
        return index, int(self.states[index]), int(self.actions[index])

    def random_instance(self, rng: random.Random) -> tuple[int | None, int, int]:
        index = rng.randrange(len(self.states))
        return index, int(self.states[index]), int(self.actions[index])

    def actions_at(self, state: int) -> np.ndarray:
        """The distinct actions this setting offers at `state`, ascending."""
        return np.unique(self.actions[self.states == state])

    def indices_of(self, state: int, action: int) -> np.ndarray:
        """Positions of every instance realising (state, action), in scan order."""
        return np.flatnonzero((self.states == state) & (self.actions == action))

    def index_of(self, state: int, action: int) -> int | None:
        """Position of the first instance realising (state, action), or None."""
        hits = self.indices_of(state, action)
        return int(hits[0]) if len(hits) else None


@dataclass(frozen=True)
class ShuffledSetting:
    """Every available state with every action, scanned in a uniformly random order.

    The order is never materialised: the first instance satisfying a condition in a uniformly
    random permutation is uniformly distributed over the instances that satisfy it, so
    `first_where` samples among those directly (same distribution, no permutation to build).
    Indices are therefore None: the world realises the returned (state, action) itself.
    """

    available: np.ndarray  # sorted distinct states
    n_actions: int
    rng: random.Random

    def __len__(self) -> int:
        return len(self.available) * self.n_actions

    @property
    def states(self) -> np.ndarray:
        return np.repeat(self.available, self.n_actions)

    @property
    def actions(self) -> np.ndarray:
        return np.tile(np.arange(self.n_actions), len(self.available))

    def first_where(self, table: np.ndarray) -> tuple[int | None, int, int] | None:
        hits = np.flatnonzero(table[self.available])
        if len(hits) == 0:
            return None
        row, action = divmod(int(hits[self.rng.randrange(len(hits))]), self.n_actions)
        return None, int(self.available[row]), action

    def random_instance(self, rng: random.Random) -> tuple[int | None, int, int]:
        row, action = divmod(rng.randrange(len(self)), self.n_actions)
        return None, int(self.available[row]), action

    def actions_at(self, state: int) -> np.ndarray:
        return np.arange(self.n_actions) if state in self.available else np.arange(0)

    def index_of(self, state: int, action: int) -> int | None:
        return None  # the world realises any available pair itself


@dataclass(frozen=True)
class Outcome:
    """The label of one executed placement and the environment's record of how it was done.

    The robot environment returns one (its `record` is what the experience log keeps); the
    abstract world returns the bare label, which the explorer reads as `Outcome(label)`.
    """

    label: int
    record: Any = None


class Environment(Protocol):
    """What the explorer needs from an environment."""

    def observe(self) -> Setting | ShuffledSetting:
        """The instances of the current setting, in the order the fovea scans them."""
        ...

    def execute(self, state: int, action: int, index: int | None = None) -> int | Outcome:
        """Place a block; returns the label +1 (stable) or -1 (fell), or an Outcome with it.

        index: position of the chosen instance in the last observed setting, or None for a
        planned pair, which the environment must realise itself (fovea search) or raise
        PlacementUnavailable.
        """
        ...
