"""Optional compiled step of the vectorised engine (numba), for the consensus rules.

The numpy step of :mod:`netsim.vectorised` is the reference; this module computes the
same recursion, LCSYS2022 eqs. (4)-(5) (and the delay-tolerant paper's eqs. (6)-(7)),
in one compiled loop per chunk of steps, with the trials innermost so that every
product runs over a contiguous row of trials (SIMD):

    x^i_{k|k-1} = p_ii A x^i_{k-1} + sum_j p_ij A^(k - s_j) x^j_{s_j}      (eq. 4)
    x^i_{k|k}   = x^i_{k|k-1} + L_i (y^i_k - C_i x^i_{k|k-1})              (eq. 5)

(eq. 6: A (p_ii x^i_{k-1} + sum_j p_ij x^j_{s_j})), with agent i's own prediction
standing in for a neighbour from whom nothing has arrived (DESIGN.md). For each
receiver the terms are first summed per lag r = k - s (an n x T accumulator per
lag), then each lag's sum is multiplied by A^r: one n x n product per lag in use
instead of one per term. With one delay d on every link that is two products per
agent (the own prediction and A^(d+1)), the arithmetic floor's count; entries of A^r
and C_i that are exactly zero are skipped (a zero times a finite estimate adds
nothing; an estimate that is no longer finite belongs to a trial that has already
diverged, whose later values are not recorded).

It is used only when asked for (``NETSIM_NUMBA=1`` or ``run_batch(..., kernel=
"numba")``, see :func:`netsim.vectorised.run_batch`; a sweep's tasks carry the
client's ``NETSIM_NUMBA``, :mod:`netsim.taskoptions`): importing numba costs more
CPU than importing numpy and scipy together, which a short command-line run would
pay for nothing. The additions are grouped differently from the numpy step (per lag
before the product, not per term after it), so estimates agree with it to round-off,
not bit for bit; ``tests/test_lockstep_numba.py`` holds them to 1e-10 relative (and
divergence steps, counts and effective delays equal). Only numba's own array
arithmetic is used (no fastmath): the same inputs give the same numbers on every run.
The block rule (LCSYS2022 eqs. 15-16) and the Kalman filter keep the numpy step.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["consensus_chunk"]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def consensus_chunk(k0, k1, ring, ring_flat, powers, own_weight, term_ptr, term_j, term_w,  # type: ignore
                    term_link, chosen, send, uniform_d, compensate, x0_mean, meas,
                    offsets, sizes, C, L, states, sq_out, est_out, record, acc, prior,
                    res, ystep):  # pragma: no cover - compiled
    """Run steps k0 .. k1 - 1 of the consensus recursion for every agent and trial.

    Compiled by numba on the first call (or loaded from numba's on-disk cache).
    Arguments (N agents, T trials, n states, m padded outputs per agent):

    ring, ring_flat : (depth, N, n, T) float and the same memory as one row
        x^i(s) at slot s % depth (depth > the largest k - s of a message used), so
        writing step k's estimates to slot k % depth overwrites nothing step k reads.
    powers : (R + 1, n, n) float
        A^0 .. A^R, R the largest lag k - s (eq. 4's compensation; R = 1 for eq. 6).
    own_weight : (N,) ; term_ptr : (N + 1,) ; term_j, term_w, term_link : (E,)
        p_ii; receiver i's terms ``term_ptr[i]:term_ptr[i+1]`` (sender, p_ij, link index
        into ``chosen``'s axis 1 or -1 when there is no link).
    chosen : (K+1, L, T) int32
        Message index held (-1: none); unused when ``uniform_d >= 0`` (one delay d on
        every link: the message of step k - 1 - d).
    send : (S,) int64
        Send step of each message index.
    compensate : bool
        A^(k - s) per term (eq. 4); False: A once on the sum (eq. 6).
    x0_mean : (n,) ; meas : (K+1, T, M) ; offsets, sizes : (N,) int64
        The prior at k = 0, and agent i's outputs in columns offsets[i]..+sizes[i].
    C : (N, m, n) ; L : (N, n, m)
        Zero-padded output matrices and gains.
    states : ((K+1) n T,)
        The plant's states, (K+1, n, T) flattened: trials innermost.
    sq_out : (k1 - k0, T, N) ; est_out : (k1 - k0, T, N, n) (written when ``record``)
    acc : ((R + 1) n T,) ; prior : (n T,) ; res : ((m + 1) T,) ; ystep : (M T,)
        Scratch.

    The squared errors go to ``sq_out`` (the caller checks them for divergence).
    """
    depth, N, n, T = ring.shape
    R = powers.shape[0] - 1
    m = C.shape[1]
    # flat arrays indexed by unsigned offsets (numba checks a signed index for
    # wraparound on every access, which keeps loops from vectorising); the sums run
    # up to four rows per pass over the trials, so that each pass loads and stores
    # its output row once for four multiply-adds
    rf = ring_flat
    af = acc
    pf = prior
    sf = states
    uT = np.uint64(T)
    unT = np.uint64(n * T)
    used = np.zeros(R + 1, dtype=np.bool_)
    src_at = np.empty(T, dtype=np.uint64)  # a term's source offset per trial
    dst_at = np.empty(T, dtype=np.uint64)  # and the offset of its lag's sum
    # the rows one blocked sum adds: offsets into rf (uniform terms) or af (lags)
    rows = np.empty(max(N, (R + 1) * n), dtype=np.uint64)
    coef = np.empty(max(N, (R + 1) * n))
    rows_r = np.empty(max(N, 1), dtype=np.int64)
    for k in range(k0, k1):
        c = k - k0
        prev = (k - 1) % depth
        cur = k % depth
        # step k's measurements with the trials innermost (read row by row once)
        M = meas.shape[2]
        for t in range(T):
            for col in range(M):
                ystep[np.uint64(col) * uT + np.uint64(t)] = meas[k, t, col]
        for i in range(N):
            own = np.uint64(prev * N + i) * unT  # x^i(k - 1)
            # ---- eq. (4): the terms summed per lag r, then A^r on each sum
            if k == 0:
                for a in range(n):
                    pa = np.uint64(a) * uT
                    for t in range(uT):
                        pf[pa + t] = x0_mean[a]
            else:
                for r in range(R + 1):
                    used[r] = False
                # every term that uses the own prediction x^i(k-1): one weight
                w_own = own_weight[i]
                count = 0
                for e in range(term_ptr[i], term_ptr[i + 1]):
                    link = term_link[e]
                    if link < 0 or (uniform_d >= 0 and k - 1 - uniform_d < 0):
                        w_own += term_w[e]
                    elif uniform_d >= 0:
                        # the same message (sent at s = k - 1 - d) in every trial
                        s = k - 1 - uniform_d
                        rows[count] = np.uint64((s % depth) * N + term_j[e]) * unT
                        coef[count] = term_w[e]
                        rows_r[count] = k - s if compensate else 1
                        count += 1
                for u in range(unT):
                    af[unT + u] = w_own * rf[own + u]
                used[1] = True
                if count:
                    # uniform terms: all of one lag r, summed four rows a pass
                    r = rows_r[0]
                    dst = np.uint64(r) * unT
                    _blocked_sum(af, dst, unT, rf, rows, coef, count, used[r])
                    used[r] = True
                if uniform_d < 0:
                    for e in range(term_ptr[i], term_ptr[i + 1]):
                        link = term_link[e]
                        if link < 0:
                            continue
                        j = term_j[e]
                        w = term_w[e]
                        # a message of its own per trial, of lag r = k - s (none:
                        # the own prediction x^i(k-1) stands in, in the lag-1 sum):
                        # per trial the offsets of its source row and of the sum of
                        # its lag, then ONE pass in which every trial adds its message
                        # to that sum (accumulators are zeroed when first used; each
                        # sum still adds the terms in term order)
                        for t in range(T):
                            q = chosen[k, link, t]
                            if q < 0:
                                src_at[t] = own + np.uint64(t)
                                dst_at[t] = unT + np.uint64(t)
                            else:
                                r = k - send[q]
                                ra = r if compensate else 1
                                if not used[ra]:
                                    used[ra] = True
                                    dst = np.uint64(ra) * unT
                                    for u in range(unT):
                                        af[dst + u] = 0.0
                                src_at[t] = (np.uint64(((k - r) % depth) * N + j) * unT
                                             + np.uint64(t))
                                dst_at[t] = np.uint64(ra) * unT + np.uint64(t)
                        for a in range(n):
                            pa = np.uint64(a) * uT
                            for t in range(T):
                                af[dst_at[t] + pa] += w * rf[src_at[t] + pa]
                # prior row a = sum over the lags r in use and b of A^r[a, b] acc[r, b]
                for a in range(n):
                    count = 0
                    for r in range(1, R + 1):
                        if used[r]:
                            for b in range(n):
                                p = powers[r, a, b]
                                if p != 0.0:  # structural zeros of A^r add nothing
                                    rows[count] = np.uint64(r * n + b) * uT
                                    coef[count] = p
                                    count += 1
                    if count:
                        _blocked_sum(pf, np.uint64(a) * uT, uT, af, rows, coef, count,
                                     False)
                    else:
                        for t in range(uT):
                            pf[np.uint64(a) * uT + t] = 0.0
            # ---- eq. (5): x = prior + L_i (y - C_i prior) into slot k, and the
            # squared error ||x^i_k - x_k||^2 in the same pass
            out = np.uint64(cur * N + i) * unT
            for o in range(sizes[i]):
                col = offsets[i] + o
                ro = np.uint64(o) * uT
                yc = np.uint64(col) * uT
                for t in range(uT):
                    res[ro + t] = ystep[yc + t]
                count = 0
                for b in range(n):
                    if C[i, o, b] != 0.0:
                        rows[count] = np.uint64(b) * uT
                        coef[count] = -C[i, o, b]
                        count += 1
                _blocked_sum(res, ro, uT, pf, rows, coef, count, True)
            sq = np.uint64(m) * uT  # the squared errors' row of res
            for t in range(uT):
                res[sq + t] = 0.0
            for a in range(n):
                oa = out + np.uint64(a) * uT
                pa = np.uint64(a) * uT
                sa = np.uint64(k * n + a) * uT
                if sizes[i] == 1:
                    g = L[i, a, 0]
                    for t in range(uT):
                        v = pf[pa + t] + g * res[t]
                        rf[oa + t] = v
                        diff = v - sf[sa + t]
                        res[sq + t] += diff * diff
                else:
                    for t in range(uT):
                        rf[oa + t] = pf[pa + t]
                    for o in range(sizes[i]):
                        g = L[i, a, o]
                        ro = np.uint64(o) * uT
                        for t in range(uT):
                            rf[oa + t] += g * res[ro + t]
                    for t in range(uT):
                        diff = rf[oa + t] - sf[sa + t]
                        res[sq + t] += diff * diff
            for t in range(T):
                sq_out[c, t, i] = res[sq + np.uint64(t)]
            if record:
                for t in range(T):
                    for a in range(n):
                        est_out[c, t, i, a] = ring[cur, i, a, t]


@numba.njit(inline="always")
def _blocked_sum(out, at, width, src, rows, coef, count, add):  # type: ignore  # pragma: no cover
    """out[at:at+width] (+)= sum_q coef[q] src[rows[q]:rows[q]+width], up to eight rows
    a pass."""
    q = 0
    first = not add
    while q < count:
        left = count - q
        if left >= 8:
            c0, c1, c2, c3 = coef[q], coef[q + 1], coef[q + 2], coef[q + 3]
            c4, c5, c6, c7 = coef[q + 4], coef[q + 5], coef[q + 6], coef[q + 7]
            r0, r1, r2, r3 = rows[q], rows[q + 1], rows[q + 2], rows[q + 3]
            r4, r5, r6, r7 = rows[q + 4], rows[q + 5], rows[q + 6], rows[q + 7]
            if first:
                for t in range(width):
                    out[at + t] = ((c0 * src[r0 + t] + c1 * src[r1 + t])
                                   + (c2 * src[r2 + t] + c3 * src[r3 + t])
                                   + ((c4 * src[r4 + t] + c5 * src[r5 + t])
                                      + (c6 * src[r6 + t] + c7 * src[r7 + t])))
            else:
                for t in range(width):
                    out[at + t] += ((c0 * src[r0 + t] + c1 * src[r1 + t])
                                    + (c2 * src[r2 + t] + c3 * src[r3 + t])
                                    + ((c4 * src[r4 + t] + c5 * src[r5 + t])
                                       + (c6 * src[r6 + t] + c7 * src[r7 + t])))
            q += 8
        elif left >= 4:
            c0, c1, c2, c3 = coef[q], coef[q + 1], coef[q + 2], coef[q + 3]
            r0, r1, r2, r3 = rows[q], rows[q + 1], rows[q + 2], rows[q + 3]
            if first:
                for t in range(width):
                    out[at + t] = (c0 * src[r0 + t] + c1 * src[r1 + t]
                                   + c2 * src[r2 + t] + c3 * src[r3 + t])
            else:
                for t in range(width):
                    out[at + t] += (c0 * src[r0 + t] + c1 * src[r1 + t]
                                    + c2 * src[r2 + t] + c3 * src[r3 + t])
            q += 4
        elif left >= 2:
            c0, c1 = coef[q], coef[q + 1]
            r0, r1 = rows[q], rows[q + 1]
            if first:
                for t in range(width):
                    out[at + t] = c0 * src[r0 + t] + c1 * src[r1 + t]
            else:
                for t in range(width):
                    out[at + t] += c0 * src[r0 + t] + c1 * src[r1 + t]
            q += 2
        else:
            c0 = coef[q]
            r0 = rows[q]
            if first:
                for t in range(width):
                    out[at + t] = c0 * src[r0 + t]
            else:
                for t in range(width):
                    out[at + t] += c0 * src[r0 + t]
            q += 1
        first = False
