"""The simulated blocks world of the paper's section 3.1.

Eight blocks in the signed q-vector representation (|q_j| is block j's height; negative when
something rests on it). The available states are height 0 (the table) and the heights of the
stacks' top blocks. Every available state offers all 21 one-hot features (plus a bias). Each
height s >= 1 has a random true model u^s whose 21 margins are drawn in [-1, 1] and re-ordered
ascending, so that a low feature index means a likely fall. The label of a placement is
sign(u.x) flipped with probability (1 - |u.x|) / 2, i.e. P(stable) = (1 + u.x) / 2. A placement on
the table always succeeds. A fall topples the placed block and, from a randomly chosen level of
the target stack upwards, the rest of that stack onto the table.
"""

from __future__ import annotations

import random

import numpy as np

from .environment import PlacementUnavailable, Setting, ShuffledSetting
from .predictors import one_hot_with_bias


class AbstractBlocksWorld:
    """The paper's simulated world; deterministic for a given seed."""

    def __init__(
        self,
        n_blocks: int = 8,
        n_features: int = 21,
        seed: int = 0,
        shuffle_scan: bool = True,
    ) -> None:
        if not 2 <= n_blocks <= 64:
            raise ValueError(f"n_blocks must be in [2, 64], got {n_blocks}")
        if not 1 <= n_features <= 1000:
            raise ValueError(f"n_features must be in [1, 1000], got {n_features}")
        models_seed, events_seed = np.random.SeedSequence(seed).spawn(2)
        model_rng = np.random.default_rng(models_seed)
        self.n_blocks, self.n_actions = n_blocks, n_features
        self.features = one_hot_with_bias(n_features)
        # u^s for s = 1..n_blocks-1: 21 margins sorted ascending, bias component 0 (|u.x| <= 1).
        margins = np.sort(model_rng.uniform(-1.0, 1.0, (n_blocks, n_features)), axis=1)
        margins[0] = 1.0  # the table: always stable, never learned
        self.true_margin = margins
        self.true_weights = np.hstack([margins, np.zeros((n_blocks, 1))])
        self.learned_heights = list(range(1, n_blocks))
        self.top = n_blocks  # absorbing state of the planning MDP: no block left to place
        self._rng = random.Random(int(np.random.default_rng(events_seed).integers(2**63)))
        self.shuffle_scan = shuffle_scan
        self.level = [1] * n_blocks
        self.on_top = [True] * n_blocks
        self.below = [-1] * n_blocks
        self.settings = 0
        self._last: Setting | ShuffledSetting | None = None
        self._last_tops: list[int] = []
        self._last_available: list[int] = [0]

    # -- representation --------------------------------------------------------------------

    @property
    def q(self) -> np.ndarray:
        """The signed q-vector of the paper."""
        return np.array(
            [lv if top else -lv for lv, top in zip(self.level, self.on_top, strict=True)]
        )

    def stacks(self) -> list[list[int]]:
        """Block ids of every stack, bottom first."""
        result = []
        for j in range(self.n_blocks):
            if self.on_top[j]:
                stack, k = [], j
                while k != -1:
                    stack.append(k)
                    k = self.below[k]
                result.append(stack[::-1])
        return result

    def available_states(self) -> list[int]:
        """Table plus each top height that some other stack can supply a block for."""
        return self._available(self._tops())

    def _tops(self) -> list[int]:
        return [j for j, top in enumerate(self.on_top) if top]

    def _available(self, tops: list[int]) -> list[int]:
        if len(tops) < 2:
            return [0]
        return [0, *sorted({self.level[j] for j in tops})]

    def arrange(self, stacks: list[list[int]]) -> None:
        """Put the blocks in the given stacks (ids bottom first); every block exactly once."""
        flat = sorted(j for stack in stacks for j in stack)
        if flat != list(range(self.n_blocks)) or any(not stack for stack in stacks):
            raise ValueError(f"stacks must use each of the {self.n_blocks} blocks exactly once")
        for stack in stacks:
            for level, j in enumerate(stack, start=1):
                self.level[j] = level
                self.below[j] = stack[level - 2] if level > 1 else -1
                self.on_top[j] = level == len(stack)
        self._last = None

    # -- protocol --------------------------------------------------------------------------

    def observe(self) -> Setting | ShuffledSetting:
        self._last_tops = self._tops()
        self._last_available = self._available(self._last_tops)
        available = np.array(self._last_available)
        if self.shuffle_scan:
            self._last = ShuffledSetting(available, self.n_actions, self._rng)
        else:
            n = len(available) * self.n_actions
            states, actions = np.divmod(np.arange(n), self.n_actions)
            self._last = Setting(available[states], actions, available)
        return self._last

    def execute(self, state: int, action: int, index: int | None = None) -> int:
        if index is not None:
            if self._last is None:
                raise PlacementUnavailable("an instance index needs a current observed setting")
            state, action = int(self._last.states[index]), int(self._last.actions[index])
        if self._last is not None:
            tops, available = self._last_tops, self._last_available
        else:
            tops = self._tops()
            available = self._available(tops)
        if state not in available:
            raise PlacementUnavailable(f"height {state} is not available in this setting")
        if not 0 <= action < self.n_actions:
            raise PlacementUnavailable(f"action {action} is not in [0, {self.n_actions})")
        rng = self._rng
        if state == 0:
            target = -1
            movable = tops
        else:
            candidates = [j for j in tops if self.level[j] == state]
            target = candidates[rng.randrange(len(candidates))]
            movable = [j for j in tops if j != target]
        moved = movable[rng.randrange(len(movable))]
        if state == 0:
            label = 1
        else:
            label = 1 if rng.random() < (1.0 + self.true_margin[state, action]) / 2.0 else -1
        self._lift(moved)
        if label == 1:
            self._put(moved, target)
        else:
            self._topple(moved, target, rng.randint(1, state))
        self.settings += 1
        self._last = None  # the setting has changed
        return label

    # -- mechanics -------------------------------------------------------------------------

    def _lift(self, block: int) -> None:
        under = self.below[block]
        if under != -1:
            self.on_top[under] = True
        self.below[block] = -1

    def _put(self, block: int, target: int) -> None:
        self.below[block] = target
        self.level[block] = 1 if target == -1 else self.level[target] + 1
        self.on_top[block] = True
        if target != -1:
            self.on_top[target] = False

    def _topple(self, block: int, target: int, keep_level: int) -> None:
        """The block at keep_level becomes the stack's top; everything above it falls flat."""
        k = target
        while self.level[k] > keep_level:
            under = self.below[k]
            self._put_on_table(k)
            k = under
        self.on_top[k] = True
        self._put_on_table(block)

    def _put_on_table(self, block: int) -> None:
        self.below[block] = -1
        self.level[block] = 1
        self.on_top[block] = True
