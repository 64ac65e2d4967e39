"""Compiled inner loops of Wang–Mendel training and inference (numba).

Training is one pass over the rows that fuzzifies every input by its
max-membership set (Kościelny et al., eq. 3), forms the rule-cell key in a mixed
radix and accumulates per cell the count, the sum and the sum of squares of the
output. The output is accumulated as an exact integer in units of
``span / QUANT`` so that ``fit``, ``partial_fit`` on any chunking and ``merge``
of partial results give bit-for-bit the same rule base (float sums are not
associative). Rows with a NaN anywhere are skipped and counted.

Inference evaluates, per row, the ``2^d`` rules whose premises fire (with a
Ruspini partition only two neighbouring sets per input have non-zero
membership) and returns the weighted average of their conclusions over the
rules that exist; with triangular sets this is multilinear interpolation over
the rule grid.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

#: output quantum for exact accumulation: span / QUANT (≈ 1.5e-5 of span)
QUANT = 65536
#: accumulated outputs are clipped to [lo - span, hi + span]
QCLIP = 2 * QUANT


@nb.njit(cache=True, nogil=True, inline="always")
def _cell_of(x, lo, step, n):
    t = math.floor((x - lo) / step + 0.5)
    if t < 0:
        return 0
    if t > n - 1:
        return n - 1
    return int(t)


@nb.njit(cache=True, nogil=True, inline="always")
def _row_key(X, r, lo, step, nsets, radix):
    """Rule-cell key of row ``r`` (max-membership set per input, eq. 3); -1 if a NaN."""
    key = 0
    for k in range(X.shape[1]):
        xv = X[r, k]
        if math.isnan(xv):
            return -1
        key += _cell_of(xv, lo[k], step[k], nsets[k]) * radix[k]
    return key


@nb.njit(cache=True, nogil=True, inline="always")
def _quantum(yr, ylo, yq):
    """Output in integer units of ``yq`` above ``ylo``, clipped to one span outside."""
    q = math.floor((yr - ylo) / yq + 0.5)
    if q < -QCLIP // 2:
        q = -QCLIP // 2
    elif q > QCLIP // 2 + QUANT:
        q = QCLIP // 2 + QUANT
    return np.int64(q)


@nb.njit(cache=True, nogil=True)
def accumulate_dense(X, y, lo, step, nsets, radix, ylo, yq, count, ysum, ysq):
    """Averaged Wang–Mendel accumulation into dense per-cell arrays (eq. 5).

    Returns the number of rows skipped because of NaN.
    """
    skipped = 0
    for r in range(X.shape[0]):
        key = -1 if math.isnan(y[r]) else _row_key(X, r, lo, step, nsets, radix)
        if key < 0:
            skipped += 1
            continue
        qi = _quantum(y[r], ylo, yq)
        count[key] += 1
        ysum[key] += qi
        ysq[key] += qi * qi
    return skipped


@nb.njit(cache=True, nogil=True)
def keys_and_quanta(X, y, lo, step, nsets, radix, ylo, yq, keys, qy):
    """Rule-cell key and quantised output per row (sparse path); NaN rows get key -1."""
    for r in range(X.shape[0]):
        key = -1 if math.isnan(y[r]) else _row_key(X, r, lo, step, nsets, radix)
        keys[r] = key
        qy[r] = 0 if key < 0 else _quantum(y[r], ylo, yq)


@nb.njit(cache=True, nogil=True)
def _membership(x, c, h, a, i, n):
    """Trapezoid/triangle membership of x in set i with centre c (shoulders at ends)."""
    if i == 0 and x <= c:
        return 1.0
    if i == n - 1 and x >= c:
        return 1.0
    dd = abs(x - c)
    m = (h - a - dd) / (h - 2 * a)
    if m < 0.0:
        return 0.0
    if m > 1.0:
        return 1.0
    return m


@nb.njit(cache=True, nogil=True)
def classic_weights(X, y, lo, step, core, nsets, radix, ylo, ystep, ycore, yn, keys, w, yset):
    """Classic Wang–Mendel: rule key, weight (eq. 2) and conclusion set per row."""
    n, d = X.shape
    for r in range(n):
        yr = y[r]
        bad = math.isnan(yr)
        key = 0
        wt = 1.0
        for k in range(d):
            if bad:
                break
            xv = X[r, k]
            if math.isnan(xv):
                bad = True
                break
            i = _cell_of(xv, lo[k], step[k], nsets[k])
            key += i * radix[k]
            wt *= _membership(xv, lo[k] + step[k] * i, step[k], core[k], i, nsets[k])
        if bad:
            keys[r] = -1
            continue
        j = _cell_of(yr, ylo, ystep, yn)
        wt *= _membership(yr, ylo + ystep * j, ystep, ycore, j, yn)
        keys[r] = np.int64(key)
        w[r] = wt
        yset[r] = j


@nb.njit(cache=True, nogil=True)
def _lookup_sparse(keys, values, key):
    lo_i = 0
    hi_i = keys.shape[0]
    while lo_i < hi_i:
        mid = (lo_i + hi_i) >> 1
        if keys[mid] < key:
            lo_i = mid + 1
        else:
            hi_i = mid
    if lo_i < keys.shape[0] and keys[lo_i] == key:
        return values[lo_i]
    return np.nan


@nb.njit(cache=True, nogil=True)
def infer(X, lo, step, plateau, nsets, radix, keys, values, dense, out, support, reason):
    """Weighted average of fired rules' conclusions over existing rules.

    ``dense`` is a look-up table indexed by key (NaN = no rule) or an empty
    array, in which case ``keys``/``values`` (sorted) are searched. ``reason``
    gets 0 (ok), 1 (NaN input), 2 (no trained rule fires), 3 (input clipped
    to its span).
    """
    n, d = X.shape
    use_dense = dense.shape[0] > 0
    js = np.empty(d, dtype=np.int64)
    ws = np.empty(d, dtype=np.float64)
    hi = np.empty(d, dtype=np.float64)
    inv_step = np.empty(d, dtype=np.float64)
    for k in range(d):
        hi[k] = lo[k] + step[k] * (nsets[k] - 1)
        inv_step[k] = 1.0 / step[k]
    ncorner = 1 << d
    for r in range(n):
        code = 0
        for k in range(d):
            xv = X[r, k]
            if math.isnan(xv):
                code = 1
                break
            if xv < lo[k]:
                xv = lo[k]
                code = 3
            elif xv > hi[k]:
                xv = hi[k]
                code = 3
            t = (xv - lo[k]) * inv_step[k]
            j = int(t)
            if j > nsets[k] - 2:
                j = nsets[k] - 2
            f = t - j
            p = plateau[k]
            wv = (f - 0.5 * p) / (1.0 - p)
            if wv < 0.0:
                wv = 0.0
            elif wv > 1.0:
                wv = 1.0
            js[k] = j
            ws[k] = wv
        if code == 1:
            out[r] = np.nan
            support[r] = 0.0
            reason[r] = 1
            continue
        base = 0
        for k in range(d):
            base += js[k] * radix[k]
        num = 0.0
        den = 0.0
        for c in range(ncorner):
            wt = 1.0
            key = base
            for k in range(d):
                if (c >> k) & 1:
                    wt *= ws[k]
                    key += radix[k]
                else:
                    wt *= 1.0 - ws[k]
            if wt == 0.0:
                continue
            if use_dense:
                v = dense[key]
            else:
                v = _lookup_sparse(keys, values, key)
            if not math.isnan(v):
                num += wt * v
                den += wt
        support[r] = den
        if den > 0.0:
            out[r] = num / den
            reason[r] = code
        else:
            out[r] = np.nan
            reason[r] = 2
