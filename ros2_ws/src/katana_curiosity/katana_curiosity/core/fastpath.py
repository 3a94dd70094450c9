"""A compiled (numba) run of the abstract world: the same experiment as Explorer, ~10x faster.

Why numba: a step of the NumPy reference is ~30 small array calls (a few microseconds each in
interpreter and dispatch overhead); compiled, the whole step (world, query scan, RLS update,
LSPI) is a few hundred floating-point operations. The reference (Explorer, PredictorBank,
Planner, AbstractBlocksWorld) stays the definition: this module re-implements exactly the same
arithmetic in the same order, and CPython's Mersenne Twister (random.Random's randrange, random,
randint), so that a run gives the same queries, labels and weights (tested against the
reference). It covers the paper's four methods in the abstract world with one-hot features; any
other combination runs on the reference.

Sums whose order is up to a BLAS kernel in the reference (LSPI's expected next values, the
linear solve) can differ in the last bits; planner ties are therefore decided with
planner.TIE_TOLERANCE in both implementations.
"""

from __future__ import annotations

import functools
import math
import random

import numba as nb
import numpy as np

from .abstract_world import AbstractBlocksWorld
from .planner import TIE_TOLERANCE, _height_structure
from .predictors import PredictorBank, one_hot_with_bias

# Method codes of the compiled loop.
Q1, Q10, CONF, RANDOM_METHOD = 0, 1, 2, 3
FAST_METHODS = {"q1": Q1, "q10": Q10, "conf": CONF, "random": RANDOM_METHOD}
Q10_PERIOD = 10  # explorer.Q10.period
LSPI_MAX_ITERATIONS = 50  # planner.lspi's default
# Mode codes: explorer.QUERY, PLAN, RANDOM.
_QUERY, _PLAN, _RANDOM = 0, 1, 2
# Integer state of a run, one int64 array: positions of the scalars.
_STEP, _SOLVED_AT, _CALLS = 0, 1, 2

_N = 624  # Mersenne Twister state words


# -- CPython's random.Random, bit for bit ----------------------------------------------------


@nb.njit(cache=True)
def _genrand(mt: np.ndarray, pos: np.ndarray) -> int:
    """genrand_uint32 of CPython's _randommodule.c; mt holds 624 words, pos[0] the index."""
    if pos[0] >= _N:
        for kk in range(_N):
            y = (mt[kk] & 0x80000000) | (mt[(kk + 1) % _N] & 0x7FFFFFFF)
            v = mt[(kk + 397) % _N] ^ (y >> 1)
            if y & 1:
                v ^= 0x9908B0DF
            mt[kk] = v
        pos[0] = 0
    y = mt[pos[0]]
    pos[0] += 1
    y ^= y >> 11
    y ^= (y << 7) & 0x9D2C5680
    y ^= (y << 15) & 0xEFC60000
    y ^= y >> 18
    return y & 0xFFFFFFFF


@nb.njit(cache=True)
def _randbelow(mt: np.ndarray, pos: np.ndarray, n: int) -> int:
    """Random._randbelow_with_getrandbits(n) for 1 <= n < 2**32."""
    k = 0
    m = n
    while m:
        k += 1
        m >>= 1
    r = _genrand(mt, pos) >> (32 - k)
    while r >= n:
        r = _genrand(mt, pos) >> (32 - k)
    return r


@nb.njit(cache=True)
def _random(mt: np.ndarray, pos: np.ndarray) -> float:
    """Random.random(): 53 bits from two words."""
    a = _genrand(mt, pos) >> 5
    b = _genrand(mt, pos) >> 6
    return (a * 67108864.0 + b) * (1.0 / 9007199254740992.0)


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


# -- the run ---------------------------------------------------------------------------------


@nb.njit(cache=True)
def _tops_and_available(level, on_top, tops, avail, present):
    """AbstractBlocksWorld._tops and _available: returns (n_tops, n_available)."""
    n_tops = 0
    for j in range(level.shape[0]):
        if on_top[j]:
            tops[n_tops] = j
            n_tops += 1
    avail[0] = 0
    if n_tops < 2:
        return n_tops, 1
    present[:] = False
    for i in range(n_tops):
        present[level[tops[i]]] = True
    n_avail = 1
    for h in range(1, present.shape[0]):
        if present[h]:
            avail[n_avail] = h
            n_avail += 1
    return n_tops, n_avail


@nb.njit(cache=True)
def _put_on_table(level, on_top, below, block):
    below[block] = -1
    level[block] = 1
    on_top[block] = True


@nb.njit(cache=True)
def _execute(level, on_top, below, tops, n_tops, movable, true_margin, state, action, mt, pos):
    """AbstractBlocksWorld.execute for an available (state, action): the label."""
    if state == 0:
        target = -1
        n_movable = n_tops
        for i in range(n_tops):
            movable[i] = tops[i]
    else:
        n_candidates = 0
        for i in range(n_tops):
            if level[tops[i]] == state:
                n_candidates += 1
        pick = _randbelow(mt, pos, n_candidates)
        target = -1
        for i in range(n_tops):
            if level[tops[i]] == state:
                if pick == 0:
                    target = tops[i]
                    break
                pick -= 1
        n_movable = 0
        for i in range(n_tops):
            if tops[i] != target:
                movable[n_movable] = tops[i]
                n_movable += 1
    moved = movable[_randbelow(mt, pos, n_movable)]
    if state == 0:
        label = 1
    else:
        label = 1 if _random(mt, pos) < (1.0 + true_margin[state, action]) / 2.0 else -1
    # _lift
    under = below[moved]
    if under != -1:
        on_top[under] = True
    below[moved] = -1
    if label == 1:  # _put
        below[moved] = target
        level[moved] = 1 if target == -1 else level[target] + 1
        on_top[moved] = True
        if target != -1:
            on_top[target] = False
    else:  # _topple
        keep_level = 1 + _randbelow(mt, pos, state)
        k = target
        while level[k] > keep_level:
            under = below[k]
            _put_on_table(level, on_top, below, k)
            k = under
        on_top[k] = True
        _put_on_table(level, on_top, below, moved)
    return label


@nb.njit(cache=True)
def _update(
    bank_slot,
    a_inv,
    w,
    examples,
    margin,
    quad,
    chi,
    unknown,
    scales,
    theta,
    b,
    state,
    action,
    label,
):
    """PredictorBank.update for one-hot-with-bias features, in the reference's operation order."""
    k = bank_slot[state]
    if k < 0:
        return
    d = w.shape[1]
    bias = d - 1
    n_actions = margin.shape[1]
    for i in range(d):
        b[i] = a_inv[k, i, action] + a_inv[k, i, bias]
    c = b[action] + b[bias]
    m = w[k, action] + w[k, bias]
    if abs(m) > 1.0:
        t = math.copysign((abs(m) - 1.0) / c, m)
        for i in range(d):
            w[k, i] -= t * b[i]
        m = math.copysign(1.0, m)
    scale = 1.0 / (1.0 + c)
    for i in range(d):
        bi = b[i]
        for j in range(d):
            a_inv[k, i, j] -= bi * (b[j] * scale)
    g = (label - m) * scale
    for i in range(d):
        w[k, i] += g * b[i]
    examples[k] += 1
    h_scale = scales[examples[k]]
    for a in range(n_actions):
        fb = b[a] + b[bias]
        fb = fb * fb
        fb = fb * scale
        quad[state, a] -= fb
        ma = w[k, a] + w[k, bias]
        margin[state, a] = ma
        x = np.sqrt(quad[state, a]) * h_scale
        chi[state, a] = x
        unknown[state, a] = (x > abs(ma)) and (x > theta)


@nb.njit(cache=True)
def _solve(
    bank_slot,
    margin,
    chi,
    unknown,
    up,
    down,
    gamma,
    reward_confidence,
    trans,
    rewards,
    policy,
    q,
    mat,
    vec,
):
    """Planner.solve (tabular LSPI, warm-started from `policy`) on the current bank."""
    ns = trans.shape[0]
    na = trans.shape[1]
    top = ns - 1
    for s in range(ns):
        learned = bank_slot[s] >= 0 and s < top
        for a in range(na):
            if bank_slot[s] < 0:
                stable = 1.0
            else:
                mc = min(max(margin[s, a], -1.0), 1.0)
                stable = (1.0 + mc) / 2.0
            if s == top:
                stable = 0.0
            for s2 in range(ns):
                trans[s, a, s2] = stable * up[s, s2] + (1.0 - stable) * down[s, s2]
            if not learned:
                rewards[s, a] = 0.0
            elif reward_confidence:
                rewards[s, a] = chi[s, a]
            else:
                rewards[s, a] = 1.0 if unknown[s, a] else 0.0
    for _ in range(LSPI_MAX_ITERATIONS):
        # evaluate_tabular: (I - gamma P_pi) v = R_pi, Gaussian elimination, partial pivoting
        for i in range(ns):
            for j in range(ns):
                mat[i, j] = (1.0 if i == j else 0.0) - gamma * trans[i, policy[i], j]
            vec[i] = rewards[i, policy[i]]
        for col in range(ns):
            piv = col
            for r in range(col + 1, ns):
                if abs(mat[r, col]) > abs(mat[piv, col]):
                    piv = r
            if piv != col:
                for j in range(ns):
                    tmp = mat[col, j]
                    mat[col, j] = mat[piv, j]
                    mat[piv, j] = tmp
                tmp = vec[col]
                vec[col] = vec[piv]
                vec[piv] = tmp
            for r in range(col + 1, ns):
                f = mat[r, col] / mat[col, col]
                if f != 0.0:
                    for j in range(col, ns):
                        mat[r, j] -= f * mat[col, j]
                    vec[r] -= f * vec[col]
        for i in range(ns - 1, -1, -1):
            acc = vec[i]
            for j in range(i + 1, ns):
                acc -= mat[i, j] * vec[j]
            vec[i] = acc / mat[i, i]
        for s in range(ns):
            for a in range(na):
                acc = 0.0
                for s2 in range(ns):
                    acc += trans[s, a, s2] * vec[s2]
                q[s, a] = rewards[s, a] + gamma * acc
        changed = False
        for s in range(ns):
            best_value = q[s, 0]
            for a in range(1, na):
                if q[s, a] > best_value:
                    best_value = q[s, a]
            best = 0
            while q[s, best] < best_value - TIE_TOLERANCE:
                best += 1
            if not q[s, policy[s]] >= q[s, best] - TIE_TOLERANCE:
                policy[s] = best
                changed = True
        if not changed:
            return


@nb.njit(cache=True)
def _planned(q, avail, n_avail):
    """Planner.choose over the available heights: (state, action)."""
    best_value = -np.inf
    for i in range(n_avail):
        s = avail[i]
        for a in range(q.shape[1]):
            if q[s, a] > best_value:
                best_value = q[s, a]
    state = avail[0]
    for i in range(n_avail):
        s = avail[i]
        v = q[s, 0]
        for a in range(1, q.shape[1]):
            if q[s, a] > v:
                v = q[s, a]
        if v >= best_value - TIE_TOLERANCE:
            state = s  # the last (highest) of the near-best heights
    v = q[state, 0]
    for a in range(1, q.shape[1]):
        if q[state, a] > v:
            v = q[state, a]
    action = 0
    while q[state, action] < v - TIE_TOLERANCE:
        action += 1
    return state, action


@nb.njit(cache=True)
def _advance(
    method,
    n_steps,
    t0,
    out_states,
    out_actions,
    out_modes,
    out_labels,
    counters,
    level,
    on_top,
    below,
    true_margin,
    world_mt,
    world_pos,
    agent_mt,
    agent_pos,
    bank_slot,
    a_inv,
    w,
    examples,
    margin,
    quad,
    chi,
    unknown,
    scales,
    theta,
    up,
    down,
    gamma,
    trans,
    rewards,
    policy,
    q,
):
    """Explorer.step n_steps times, writing steps t0.. of the output arrays."""
    n_blocks = level.shape[0]
    n_actions = margin.shape[1]
    tops = np.empty(n_blocks, dtype=np.int64)
    movable = np.empty(n_blocks, dtype=np.int64)
    avail = np.empty(n_blocks + 1, dtype=np.int64)
    present = np.zeros(n_blocks + 1, dtype=np.bool_)
    hits = np.empty((n_blocks + 1) * n_actions, dtype=np.int64)
    b = np.empty(w.shape[1])
    ns = trans.shape[0]
    mat = np.empty((ns, ns))
    vec = np.empty(ns)
    confidence = method == CONF
    for t in range(t0, t0 + n_steps):
        step = counters[_STEP]
        n_tops, n_avail = _tops_and_available(level, on_top, tops, avail, present)
        if method == RANDOM_METHOD:
            idx = _randbelow(agent_mt, agent_pos, n_avail * n_actions)
            state = avail[idx // n_actions]
            action = idx % n_actions
            mode = _RANDOM
        else:
            if method == Q10 and (
                counters[_SOLVED_AT] < 0 or step - counters[_SOLVED_AT] >= Q10_PERIOD
            ):
                _solve(
                    bank_slot,
                    margin,
                    chi,
                    unknown,
                    up,
                    down,
                    gamma,
                    confidence,
                    trans,
                    rewards,
                    policy,
                    q,
                    mat,
                    vec,
                )
                counters[_CALLS] += 1
                counters[_SOLVED_AT] = step
            n_hits = 0
            if method != CONF:  # ShuffledSetting.first_where(bank.unknown)
                for i in range(n_avail):
                    for a in range(n_actions):
                        if unknown[avail[i], a]:
                            hits[n_hits] = i * n_actions + a
                            n_hits += 1
            if n_hits:
                idx = hits[_randbelow(world_mt, world_pos, n_hits)]
                state = avail[idx // n_actions]
                action = idx % n_actions
                mode = _QUERY
            else:
                if method != Q10:
                    _solve(
                        bank_slot,
                        margin,
                        chi,
                        unknown,
                        up,
                        down,
                        gamma,
                        confidence,
                        trans,
                        rewards,
                        policy,
                        q,
                        mat,
                        vec,
                    )
                    counters[_CALLS] += 1
                state, action = _planned(q, avail, n_avail)
                mode = _PLAN
        label = _execute(
            level,
            on_top,
            below,
            tops,
            n_tops,
            movable,
            true_margin,
            state,
            action,
            world_mt,
            world_pos,
        )
        _update(
            bank_slot,
            a_inv,
            w,
            examples,
            margin,
            quad,
            chi,
            unknown,
            scales,
            theta,
            b,
            state,
            action,
            label,
        )
        out_states[t] = state
        out_actions[t] = action
        out_modes[t] = mode
        out_labels[t] = label
        counters[_STEP] = step + 1


class FastRun:
    """One run's state for the compiled loop, taken from the reference objects of a fresh run
    (world, bank, the strategy's generator; a planner's state is not read: it starts empty).
    The bank's arrays are shared and updated in place; sync() writes the world's blocks and
    the generators back, so that the two paths can be compared."""

    def __init__(
        self,
        method: str,
        world: AbstractBlocksWorld,
        bank: PredictorBank,
        agent_rng: random.Random,
        gamma: float,
        steps: int,
    ) -> None:
        if method not in FAST_METHODS:
            raise ValueError(f"no fast path for {method!r}: it has {', '.join(FAST_METHODS)}")
        if not supports(world, bank):
            raise ValueError("the fast path needs the abstract world with one-hot features")
        self.method, self.world, self.bank, self.agent_rng = method, world, bank, agent_rng
        self.code = FAST_METHODS[method]
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
    FastRun("q1", world, bank, random.Random(0), 0.95, 5).advance(5)


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
