"""A compiled (numba) run of the abstract world: the same experiment as Explorer, ~10x faster.

Why numba: a step of the NumPy reference is ~30 small array calls (a few microseconds each in
interpreter and dispatch overhead); compiled, the whole step (world, query scan, RLS update,
LSPI) is a few hundred floating-point operations. The reference (Explorer, PredictorBank,
Planner, AbstractBlocksWorld) stays the definition: this module re-implements exactly the same
arithmetic in the same order, and CPython's Mersenne Twister (random.Random's randrange, random,
randint), so that a run gives the same queries, labels and weights (tested against the
reference). It covers the paper's four strategies in the abstract world with one-hot features;
any other combination runs on the reference. The compiled kernels are in fastpath_kernels.py; this
module moves a run's state between the reference objects and them.

Sums whose order is up to a BLAS kernel in the reference (LSPI's expected next values, the
linear solve) can differ in the last bits; planner ties are therefore decided with
planner.TIE_TOLERANCE in both implementations.
"""

from __future__ import annotations

import functools
import math
import random

import numpy as np

from .abstract_world import AbstractBlocksWorld
from .fastpath_kernels import _CALLS, _N, _STEP, FAST_STRATEGIES, _advance
from .planner import _height_structure
from .predictors import GAMMA, PredictorBank, one_hot_with_bias


def _mt_from(rng: random.Random) -> tuple[np.ndarray, np.ndarray]:
    version, internal, _gauss = rng.getstate()
    if version != 3:
        raise RuntimeError(f"unexpected random.Random state version {version}")
    return np.array(internal[:_N], dtype=np.int64), np.array([internal[_N]], dtype=np.int64)


def _mt_to(rng: random.Random, mt: np.ndarray, pos: np.ndarray) -> None:
    _version, _internal, gauss = rng.getstate()
    rng.setstate((3, (*(int(v) for v in mt), int(pos[0])), gauss))


@functools.lru_cache(maxsize=8)
def _chi_scales(alpha: float, n: int) -> np.ndarray:
    """chi's scale alpha sqrt(log(2 + examples)) for examples 0..n-1, computed with the math
    module as PredictorBank._flags does (NumPy's vectorised log may differ in the last bit)."""
    table = np.array([alpha * math.sqrt(math.log(2.0 + float(i))) for i in range(n)])
    table.flags.writeable = False
    return table


class FastRun:
    """One run's state for the compiled loop, taken from the reference objects of a fresh run
    (world, bank, the strategy's generator; a planner's state is not read: it starts empty).
    The bank's arrays are shared and updated in place; sync() writes the world's blocks and
    the generators back, so that the two paths can be compared."""

    def __init__(
        self,
        strategy: str,
        world: AbstractBlocksWorld,
        bank: PredictorBank,
        agent_rng: random.Random,
        gamma: float,
        steps: int,
    ) -> None:
        if strategy not in FAST_STRATEGIES:
            raise ValueError(
                f"no fast path for {strategy!r}: it has {', '.join(FAST_STRATEGIES)}")
        if not supports(world, bank):
            raise ValueError("the fast path needs the abstract world with one-hot features")
        self.strategy, self.world, self.bank, self.agent_rng = strategy, world, bank, agent_rng
        self.code = FAST_STRATEGIES[strategy]
        self.gamma = float(gamma)
        self.level = np.array(world.level, dtype=np.int64)
        self.on_top = np.array(world.on_top, dtype=np.bool_)
        self.below = np.array(world.below, dtype=np.int64)
        self.true_margin = np.ascontiguousarray(world.true_margin, dtype=float)
        self.world_mt, self.world_pos = _mt_from(world._rng)
        self.agent_mt, self.agent_pos = _mt_from(agent_rng)
        most = int(bank.examples.max()) + steps + 2
        self.scales = _chi_scales(float(bank.rule.alpha), 1 << max(most - 1, 1).bit_length())
        up, down = _height_structure(world.top)
        self.up, self.down = np.array(up), np.array(down)
        ns = world.top + 1
        self.trans = np.zeros((ns, bank.n_actions, ns))
        self.rewards = np.zeros((ns, bank.n_actions))
        self.policy = np.zeros(ns, dtype=np.int64)
        self.q = np.zeros((ns, bank.n_actions))
        self.counters = np.array([0, -1, 0], dtype=np.int64)
        self._synced = 0  # steps already counted in world.settings
        self.states = np.empty(steps, dtype=np.int16)
        self.actions = np.empty(steps, dtype=np.int16)
        self.modes = np.empty(steps, dtype=np.int8)
        self.labels = np.empty(steps, dtype=np.int8)

    @property
    def done(self) -> int:
        return int(self.counters[_STEP])

    @property
    def plan_calls(self) -> int:
        return int(self.counters[_CALLS])

    def advance(self, n: int) -> None:
        """The next n steps (the bank's arrays are updated in place)."""
        if self.done + n > len(self.states):
            raise ValueError("advance past the steps this run was sized for")
        bank = self.bank
        _advance(
            self.code, n, self.done, self.states, self.actions, self.modes, self.labels,
            self.counters, self.level, self.on_top, self.below, self.true_margin,
            self.world_mt, self.world_pos, self.agent_mt, self.agent_pos,
            bank.slot, bank.a_inv, bank.w, bank.examples, bank.margin, bank.quad, bank.chi,
            bank.unknown, self.scales, float(bank.rule.theta),
            self.up, self.down, self.gamma, self.trans, self.rewards, self.policy, self.q,
        )  # fmt: skip

    def sync(self) -> None:
        """Write the world's blocks and both generators back into the reference objects."""
        world = self.world
        world.level = [int(v) for v in self.level]
        world.on_top = [bool(v) for v in self.on_top]
        world.below = [int(v) for v in self.below]
        world.settings += self.done - self._synced
        self._synced = self.done
        world._last = None
        _mt_to(world._rng, self.world_mt, self.world_pos)
        _mt_to(self.agent_rng, self.agent_mt, self.agent_pos)
        self.bank.version[self.bank.heights] += 1


def warm_up() -> None:
    """Load the compiled loop from numba's cache (compiling it the first time): a few steps."""
    world = AbstractBlocksWorld(seed=0)
    bank = PredictorBank(world.learned_heights, world.features, n_states=world.top + 1)
    FastRun("q1", world, bank, random.Random(0), GAMMA, 5).advance(5)


def supports(world: object, bank: PredictorBank) -> bool:
    """True when the compiled loop reproduces the reference for this world and bank."""
    return (
        isinstance(world, AbstractBlocksWorld)
        and world.shuffle_scan
        and bank.features.shape == (world.n_actions, world.n_actions + 1)
        and np.array_equal(bank.features, one_hot_with_bias(world.n_actions))
        and bank.n_states == world.top + 1
        and not bank.listeners  # the compiled update does not call them
    )
