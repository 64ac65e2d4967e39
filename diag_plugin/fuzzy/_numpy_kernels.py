"""The Wang–Mendel training accumulation and one model's inference in numpy, giving the same
bits as the compiled loops of :mod:`diag_plugin.fuzzy._kernels` (numba).

They let a process that trains one model (``diag train``) run without importing numba and
loading its compiled code, which costs more CPU than the work on months of data: rule-cell
keys by max membership (Kościelny et al., eq. 3) and integer per-cell count, sum and sum of
squares (eq. 5) with ``np.bincount``; inference level by level over the ``2^d`` fired rules,
rows in step (each row's sums are formed in the compiled loop's order, so every figure is
the same float). :func:`diag_plugin.fuzzy.wang_mendel.kernels` says which of the two runs.
"""

from __future__ import annotations

import numpy as np

#: output quantum for exact accumulation: span / QUANT (≈ 1.5e-5 of span)
QUANT = 65536
#: accumulated outputs are clipped to [lo - span, hi + span]
QCLIP = 2 * QUANT
#: float sums of integers below this are exact
EXACT = float(1 << 53)
#: an input beyond its span moves the answer along the model's linear trend for at most this
#: share of the span past its end (then the answer holds): see :func:`._kernels.infer_levels`
REACH = 0.25


def _cells(x: np.ndarray, lo: float, step: float, n: int) -> np.ndarray:
    """Max-membership set of each value (NaN rows give 0; the caller drops them)."""
    t = np.floor((x - lo) / step + 0.5)
    return np.nan_to_num(np.clip(t, 0, n - 1)).astype(np.int64)


def _sums(key: np.ndarray, w: np.ndarray, size: int) -> np.ndarray:
    """Exact int64 per-key sums of the integer weights ``w``."""
    if w.size and float(np.abs(w).max()) * w.size < EXACT:
        return np.rint(np.bincount(key, weights=w.astype(np.float64), minlength=size)).astype(
            np.int64
        )
    out = np.zeros(size, np.int64)
    np.add.at(out, key, w)
    return out


def accumulate_dense(X, y, lo, step, nsets, radix, ylo, yq, count, ysum, ysq) -> int:
    """:func:`._kernels.accumulate_dense`: add each row's count, output quantum and its square
    to its rule cell; returns the rows skipped for a NaN."""
    ok = ~np.isnan(y)
    key = np.zeros(X.shape[0], np.int64)
    for k in range(X.shape[1]):
        xv = X[:, k]
        ok &= ~np.isnan(xv)
        key += _cells(xv, lo[k], step[k], int(nsets[k])) * radix[k]
    key = key[ok]
    q = np.floor((y[ok] - ylo) / yq + 0.5)
    q = np.clip(q, -QCLIP // 2, QCLIP // 2 + QUANT).astype(np.int64)
    count += np.bincount(key, minlength=count.size)
    ysum += _sums(key, q, count.size)
    ysq += _sums(key, q * q, count.size)
    return int(X.shape[0] - key.size)


def _find(keys, dense, sa: int, sb: int, da: int, key: np.ndarray) -> np.ndarray:
    """Index of each rule ``key`` of one level (its dense table, or a search of the sorted
    ``keys[sa:sb]``); -1 where there is none."""
    if da >= 0:
        return dense[da + key]
    seg = keys[sa:sb]
    pos = np.searchsorted(seg, key)
    hit = pos < seg.size
    hit[hit] = seg[pos[hit]] == key[hit]
    return np.where(hit, sa + pos, -1)


def infer_levels(
    which, X, n_inputs, lo, step, plateau, nsets, inner, trend, blocks, radix, n_levels, seg,
    dense_at, keys, values, spreads, data, dense, enough, out, support, reason, level, spread,
):  # fmt: skip
    """:func:`._kernels.infer_levels` for one model (``which`` empty): the same outputs, the
    same bits."""
    if which.shape[0]:
        raise ValueError("the numpy inference evaluates one model (which must be empty)")
    n = X.shape[0]
    d = int(n_inputs[0])
    out[:] = np.nan
    support[:] = 0.0
    level[:] = -1
    spread[:] = np.nan
    nan = np.zeros(n, bool)
    clipped = np.zeros(n, bool)
    inside = np.ones(n, bool)
    xs = np.empty((n, d))
    own = np.empty((n, d), np.int64)
    past = np.zeros(n)  # the trend's move past the span (:data:`REACH`)
    for k in range(d):
        xv = X[:, k]
        nan |= np.isnan(xv)
        lo_k = lo[0, k]
        hi_k = lo_k + step[0, k] * (nsets[0, k] - 1)
        clipped |= (xv < lo_k) | (xv > hi_k)
        xs[:, k] = np.clip(xv, lo_k, hi_k)
        reach = REACH * (hi_k - lo_k)
        far = np.clip(xv, lo_k - reach, hi_k + reach)
        out_k = (xv < lo_k) | (xv > hi_k)
        past[out_k] += trend[0, k + 1] * (far[out_k] - xs[out_k, k])
        i = np.minimum(
            np.nan_to_num(np.floor((xs[:, k] - lo_k) / step[0, k] + 0.5)), nsets[0, k] - 1
        )
        own[:, k] = i
        inside &= (i >= inner[0, k, 0]) & (i <= inner[0, k, 1])
    active = ~nan  # rows no level has answered with ``enough`` support yet
    for lv in range(int(n_levels[0])):
        if lv == 1:
            active &= inside  # coarse levels only inside the data's range
        rows = np.flatnonzero(active)
        if not rows.size:
            break
        sa, sb = int(seg[0, lv, 0]), int(seg[0, lv, 1])
        da = int(dense_at[0, lv])
        ws = np.empty((rows.size, d))
        base = np.zeros(rows.size, np.int64)
        own_key = np.zeros(rows.size, np.int64)
        rad = radix[0, lv]
        for k in range(d):
            b = blocks[0, lv, k]
            nl = (nsets[0, k] + b - 1) // b
            t = (xs[rows, k] - (lo[0, k] + 0.5 * step[0, k] * (b - 1))) / (step[0, k] * b)
            t = np.minimum(np.maximum(t, 0.0), nl - 1.0)
            j = np.minimum(t.astype(np.int64), nl - 2)
            f = t - j
            p = plateau[0, k]
            ws[:, k] = np.minimum(np.maximum((f - 0.5 * p) / (1.0 - p), 0.0), 1.0)
            base += j * rad[k]
            own_key += (own[rows, k] // b) * rad[k]
        if lv > 0:  # a coarse cell answers only where the data reached it
            io = _find(keys, dense, sa, sb, da, own_key)
            here = io >= 0
            here[here] = data[io[here]]
            rows, ws, base = rows[here], ws[here], base[here]
        vl = np.zeros(rows.size)
        sl = np.zeros(rows.size)
        ql = np.zeros(rows.size)
        wl = np.zeros(rows.size)
        for c in range(1 << d):
            wt = np.ones(rows.size)
            key = base.copy()
            for k in range(d):
                if (c >> k) & 1:
                    wt *= ws[:, k]
                    key += rad[k]
                else:
                    wt *= 1.0 - ws[:, k]
            fire = np.flatnonzero(wt != 0.0)
            ix = _find(keys, dense, sa, sb, da, key[fire])
            hit = ix >= 0
            fire, ix = fire[hit], ix[hit]
            w = wt[fire]
            vl[fire] += w * values[ix]
            sl[fire] += w
            known = ~np.isnan(spreads[ix])
            ql[fire[known]] += w[known] * spreads[ix[known]]
            wl[fire[known]] += w[known]
        take = (sl > 0.0) & ((level[rows] < 0) | (sl >= enough))
        r = rows[take]
        out[r] = vl[take] / sl[take]
        support[r] = sl[take]
        level[r] = lv
        wq = wl[take]
        spread[r] = np.where(wq > 0.0, ql[take] / np.where(wq > 0.0, wq, 1.0), np.nan)
        active[rows[sl >= enough]] = False
    moved = clipped & (level >= 0) & ~nan
    out[moved] = out[moved] + past[moved]
    reason[:] = np.where(nan, 1, np.where(level >= 0, np.where(clipped, 3, 0), 2))
