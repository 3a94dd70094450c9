"""The compiled kernels of the fast path (core.fastpath): CPython's Mersenne Twister, the
abstract world, the RLS update, LSPI, the planned choice, and the loop over all of them.

They are in one file because numba's on-disk cache (cache=True) is invalidated only when the
file of the cached function changes, not when a function it calls changes in another file:
split over files, an edited kernel could run beside a stale compiled caller.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .planner import TIE_TOLERANCE

# Strategy codes of the compiled loop.
Q1, Q10, CONF, RANDOM_METHOD = 0, 1, 2, 3
FAST_STRATEGIES = {"q1": Q1, "q10": Q10, "conf": CONF, "random": RANDOM_METHOD}
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
def _update(bank_slot, a_inv, w, examples, margin, quad, chi, unknown, scales, theta, b, state,
        action, label):
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
def _solve(bank_slot, margin, chi, unknown, up, down, gamma, reward_confidence, trans, rewards,
        policy, q, mat, vec):
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
def _advance(method, n_steps, t0, out_states, out_actions, out_modes, out_labels, counters,
        level, on_top, below, true_margin, world_mt, world_pos, agent_mt, agent_pos,
        bank_slot, a_inv, w, examples, margin, quad, chi, unknown, scales, theta,
        up, down, gamma, trans, rewards, policy, q):
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
            # Q10 re-plans every Q10_PERIOD steps, the others when no pair is unknown; the
            # scan reads no planner state, so scanning first changes nothing for Q10.
            n_hits = 0
            if method != CONF:  # ShuffledSetting.first_where(bank.unknown)
                for i in range(n_avail):
                    for a in range(n_actions):
                        if unknown[avail[i], a]:
                            hits[n_hits] = i * n_actions + a
                            n_hits += 1
            if method == Q10:
                replan = counters[_SOLVED_AT] < 0 or step - counters[_SOLVED_AT] >= Q10_PERIOD
            else:
                replan = n_hits == 0
            if replan:
                _solve(bank_slot, margin, chi, unknown, up, down, gamma, confidence, trans,
                       rewards, policy, q, mat, vec)
                counters[_CALLS] += 1
                counters[_SOLVED_AT] = step
            if n_hits:
                idx = hits[_randbelow(world_mt, world_pos, n_hits)]
                state = avail[idx // n_actions]
                action = idx % n_actions
                mode = _QUERY
            else:
                state, action = _planned(q, avail, n_avail)
                mode = _PLAN
        label = _execute(level, on_top, below, tops, n_tops, movable, true_margin, state, action,
                         world_mt, world_pos)
        _update(bank_slot, a_inv, w, examples, margin, quad, chi, unknown, scales, theta, b,
                state, action, label)
        out_states[t] = state
        out_actions[t] = action
        out_modes[t] = mode
        out_labels[t] = label
        counters[_STEP] = step + 1
