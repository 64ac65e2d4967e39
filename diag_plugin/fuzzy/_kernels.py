"""Compiled inner loops of Wang–Mendel training and inference (numba; the same loops in
numpy, for a process that need not load numba: :mod:`._numpy_kernels`).

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
the rule grid. The firing weight of rules never trained passes to coarser
levels of the same grid (:func:`infer_levels`).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from diag_plugin.fuzzy._numpy_kernels import QCLIP, QUANT, REACH  # noqa: F401 - one definition


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


@nb.njit(cache=True, nogil=True, inline="always")
def _find(keys, dense, seg_a, seg_b, dense_a, key):
    """Index of rule ``key`` of one level in ``keys`` (its dense table when ``dense_a`` >= 0,
    else a binary search in the sorted ``keys[seg_a:seg_b]``); -1 when there is none."""
    if dense_a >= 0:
        return dense[dense_a + key]
    lo_i = seg_a
    hi_i = seg_b
    while lo_i < hi_i:
        mid = (lo_i + hi_i) >> 1
        if keys[mid] < key:
            lo_i = mid + 1
        else:
            hi_i = mid
    if lo_i < seg_b and keys[lo_i] == key:
        return lo_i
    return -1


@nb.njit(cache=True, nogil=True, inline="always")
def _clipped(xv, lo_k, hi_k, code):
    """An input held to its span ``[lo_k, hi_k]``, and the reason code 3 (clipped) if it
    was outside (else ``code`` as it was)."""
    if xv < lo_k:
        return lo_k, 3
    if xv > hi_k:
        return hi_k, 3
    return xv, code


@nb.njit(cache=True, nogil=True, inline="always")
def _lower_weight_at(t, nl, half, den, inv):
    """:func:`_lower_weight` with its plateau ``p`` given as ``half`` = ``0.5·p`` and ``den``
    = ``1 − p``, and ``inv`` = ``1 / den`` where ``den`` is a power of two (else 0): dividing
    by a power of two and multiplying by its reciprocal (exact) round the same real number,
    so the same bits, without a division (a trapezoid's plateau of 0.5 gives ``den`` 0.5)."""
    # the clamps as min/max, not branches: a plateau puts half the samples on one (0 or 1
    # at random), a branch mispredicted that often costs more than the rest of the row
    t = min(max(t, 0.0), nl - 1.0)
    j = int(t)
    if j > nl - 2:
        j = nl - 2
    f = t - j
    wv = (f - half) * inv if inv > 0.0 else (f - half) / den
    return j, min(max(wv, 0.0), 1.0)


@nb.njit(cache=True, nogil=True, inline="always")
def _lower_weight(t, nl, p):
    """Lower set ``j`` of a sample at ``t`` (in set spacings from the first centre) among
    ``nl`` sets of plateau ``p``, and the upper set's membership: the sample lies between
    centres ``j`` and ``j + 1``."""
    return _lower_weight_at(t, nl, 0.5 * p, 1.0 - p, 0.0)


@nb.njit(cache=True, nogil=True, inline="always")
def _corners(ws, d, base, radix, cw, ck):
    """The ``2^d`` corners of cell ``base`` (upper memberships ``ws``) into the scratch
    ``cw`` (weights) and ``ck`` (keys), both ``2^d`` long; returns ``2^d``.

    Corner ``c`` (bit ``k`` set: the upper set of input ``k``) weighs
    ``((1·f_0)·f_1)·…·f_{d-1}``, ``f_k`` = ``ws[k]`` or ``1 − ws[k]``: the products are
    built input by input, each corner's factors multiplied in the same order as one product
    per corner, so the same bits with ``2^(d+1)`` multiplications instead of ``d·2^d``."""
    cw[0] = 1.0
    ck[0] = base
    m = 1
    for k in range(d):
        w = ws[k]
        rk = radix[k]
        for c in range(m):
            cw[c + m] = cw[c] * w
            ck[c + m] = ck[c] + rk
            cw[c] = cw[c] * (1.0 - w)
        m <<= 1
    return m


@nb.njit(cache=True, nogil=True, inline="always")
def _fire(ws, d, base, radix, keys, dense, sa, sb, da, values, spreads, cw, ck):
    """The ``2^d`` rules around cell ``base`` (upper memberships ``ws``): the weighted sums
    of the existing rules' conclusions and spreads and their weights ``(vl, sl, ql, wl)``.

    The corners' weights and keys: :func:`_corners`."""
    m = _corners(ws, d, base, radix, cw, ck)
    vl = 0.0
    sl = 0.0
    ql = 0.0
    wl = 0.0
    for c in range(m):
        wt = cw[c]
        if wt == 0.0:
            continue
        ix = _find(keys, dense, sa, sb, da, ck[c])
        if ix >= 0:
            vl += wt * values[ix]
            sl += wt
            if not math.isnan(spreads[ix]):
                ql += wt * spreads[ix]
                wl += wt
    return vl, sl, ql, wl


@nb.njit(cache=True, nogil=True, inline="always")
def _fire_table(ws, d, base, radix, table, rules, cw, ck):
    """:func:`_fire` through a dense table of rule rows without a branch per corner:
    ``table`` maps every cell key to a row of ``rules`` (``[conclusion, 1, spread, 1]``, the
    spread and its weight 0 where it is NaN; the last row all 0: no rule), and every corner
    adds ``weight · row``. A corner of weight 0, or without a rule, adds ``±0`` to a sum that
    is never ``-0`` (it starts at ``+0``), so the same bits as :func:`_fire`'s skipping it
    while every conclusion and spread is finite (what :meth:`WangMendelRegressor._fine_table`
    requires) — without the branch on the weight, which a plateau makes 0 at random."""
    vl = sl = ql = wl = 0.0
    for c in range(_corners(ws, d, base, radix, cw, ck)):
        wt = cw[c]
        q = table[ck[c]]
        vl += wt * rules[q, 0]
        sl += wt * rules[q, 1]
        ql += wt * rules[q, 2]
        wl += wt * rules[q, 3]
    return vl, sl, ql, wl


@nb.njit(cache=True, nogil=True, inline="always")
def _past(xv, lo_k, hi_k, slope):
    """The linear trend's move (``slope``) for an input ``xv`` beyond its span ``[lo_k,
    hi_k]``, at most :data:`REACH` of the span past its end (0 inside the span)."""
    reach = REACH * (hi_k - lo_k)
    if xv < lo_k:
        far = xv if xv > lo_k - reach else lo_k - reach
        return slope * (far - lo_k)
    if xv > hi_k:
        far = xv if xv < hi_k + reach else hi_k + reach
        return slope * (far - hi_k)
    return 0.0


@nb.njit(cache=True, nogil=True)
def infer_levels(
    which, X, n_inputs, lo, step, plateau, nsets, inner, trend, blocks, radix, n_levels, seg,
    dense_at, keys, values, spreads, data, dense, enough, out, support, reason, level, spread,
    first=0,
):  # fmt: skip
    """Inference over the fine rule grid and the coarser levels behind it, for many models.

    Row ``r`` is evaluated by model ``which[r]`` (model 0 when ``which`` is empty). Per model
    ``m`` and level ``l``: ``blocks[m, l, k]`` fine sets of input ``k`` form one coarse set
    (level 0: 1), ``radix[m, l]`` the mixed radix of that level's keys, ``seg[m, l]`` the slice
    of ``keys``/``values``/``data`` holding its rules (sorted keys), ``dense_at[m, l]`` the
    offset of its dense table of rule indices in ``dense`` or -1; ``inner[m, k]`` the first
    and last fine set of input ``k`` holding training data; ``data`` says per coarse node
    whether its own cell holds training data.

    A coarse set groups ``b`` neighbouring fine sets: its centre is their mean, its spacing
    ``b·h``, the same shape (a uniform partition, so a sample's max-membership coarse set is
    its fine set ``// b``, eq. 3). Each level gives the weighted average of its fired rules'
    conclusions (eq. 5 conclusions, multilinear interpolation) over the rules that exist, with
    ``S``, the firing weight they carry. The finest level with ``S >= enough`` answers; where
    none does, the finest level with ``S > 0`` (so wherever the fine grid answered with all
    its weight, the answer is the fine grid's, exactly). A coarse level is asked only where
    the sample's own cell at that level holds training data and the sample lies inside the
    range of the training data (every input's fine set between the first and last set holding
    data); beyond it the fine grid alone answers, as without levels.

    ``support`` gets the answering level's ``S``, ``level`` that level (-1: no answer),
    ``spread`` the same weighted average of the fired rules' ``spreads`` (their outputs'
    spread; NaN where none is known), ``reason`` 0 (ok), 1 (NaN input), 2 (no trained rule
    fires at any level), 3 (input clipped to its span).

    **Past the span, along the trend.** ``trend[m]`` is the model's linear trend ``[b0, b1 …
    bd]`` (:attr:`~diag_plugin.fuzzy.wang_mendel.WangMendelRegressor.trend_`). An input past
    its span is clipped to it (reason 3) as before, and the answer then moves by the trend's
    slope times the distance past the span's end, at most :data:`REACH` of the span
    (:func:`_past`); inside the spans the answer is unchanged.

    ``first`` > 0: the levels from ``first`` on only, for rows whose ``out``, ``support``,
    ``level`` and ``spread`` already hold the answer of the levels before it (none of which
    reached ``enough``: the rows :meth:`WangMendelRegressor.predict_detail` asks again).
    The levels are a fold from the finest on, so the answers are the same bits as from
    level 0, without evaluating the finer levels a second time (the trend's move past the
    span added only to an answer of these levels: the earlier answer holds it already).
    """
    n = X.shape[0]
    d_max = X.shape[1]
    ws = np.empty(d_max, dtype=np.float64)
    cw = np.empty(1 << d_max, dtype=np.float64)
    ck = np.empty(1 << d_max, dtype=np.int64)
    xs = np.empty(d_max, dtype=np.float64)
    own = np.empty(d_max, dtype=np.int64)
    per_row = which.shape[0] > 0
    for r in range(n):
        m = which[r] if per_row else 0
        d = n_inputs[m]
        code = 0
        inside = True
        past = 0.0
        for k in range(d):
            xv = X[r, k]
            if math.isnan(xv):
                code = 1
                break
            lo_k = lo[m, k]
            hi_k = lo_k + step[m, k] * (nsets[m, k] - 1)
            if code == 3 or xv < lo_k or xv > hi_k:
                past += _past(xv, lo_k, hi_k, trend[m, k + 1])
            xv, code = _clipped(xv, lo_k, hi_k, code)
            xs[k] = xv
            i = math.floor((xv - lo_k) / step[m, k] + 0.5)
            if i > nsets[m, k] - 1:
                i = nsets[m, k] - 1
            own[k] = i
            if i < inner[m, k, 0] or i > inner[m, k, 1]:
                inside = False
        if first == 0:
            out[r] = np.nan
            support[r] = 0.0
            level[r] = -1
            spread[r] = np.nan
        if code == 1:
            reason[r] = 1
            continue
        answered = False  # by a level of this call
        for lv in range(first, n_levels[m] if inside else 1):
            sa = seg[m, lv, 0]
            sb = seg[m, lv, 1]
            da = dense_at[m, lv]
            base = 0
            own_key = 0
            for k in range(d):
                b = blocks[m, lv, k]
                nl = (nsets[m, k] + b - 1) // b
                t = (xs[k] - (lo[m, k] + 0.5 * step[m, k] * (b - 1))) / (step[m, k] * b)
                j, ws[k] = _lower_weight(t, nl, plateau[m, k])
                base += j * radix[m, lv, k]
                own_key += (own[k] // b) * radix[m, lv, k]
            if lv > 0:
                io = _find(keys, dense, sa, sb, da, own_key)
                if io < 0 or not data[io]:
                    continue  # a coarse cell answers only where the data reached it
            vl, sl, ql, wl = _fire(
                ws, d, base, radix[m, lv], keys, dense, sa, sb, da, values, spreads, cw, ck
            )
            if sl > 0.0 and (level[r] < 0 or sl >= enough):
                out[r] = vl / sl
                support[r] = sl
                level[r] = lv
                spread[r] = ql / wl if wl > 0.0 else np.nan
                answered = True
            if sl >= enough:
                break
        if code == 3 and answered:  # past the span: along the trend (REACH at most)
            out[r] = out[r] + past
        reason[r] = code if level[r] >= 0 else 2


@nb.njit(cache=True, nogil=True)
def infer_fine(
    X, lo, step, plateau, nsets, inner, trend, radix, table, rules, enough, coarse,
    out, support, reason, level, spread, again,
):  # fmt: skip
    """:func:`infer_levels` of one model at its fine level only, through the level's dense
    table of rule rows (``table``: cell key → row of ``rules``, :func:`_fire_table`): the
    same arithmetic in the same order, so the same bits, without the per-model and per-level
    indexing and without a branch per corner. ``again[r]`` is set where :func:`infer_levels`
    would go on to a coarser level (``coarse``: the model has one): the fine rules carry less
    than ``enough`` of the weight, no input is NaN and the sample lies inside the training
    data's range.
    Elsewhere the answer is :func:`infer_levels`' answer.

    Divisions only where they round: the plateau's (:func:`_lower_weight_at`); the weighted
    averages are divided always (by a total weight of exactly 1 the sums themselves, ``x / 1``
    is ``x``: a division is cheaper than a branch on it mispredicted)."""
    n = X.shape[0]
    d = X.shape[1]
    ws = np.empty(d, dtype=np.float64)
    cw = np.empty(1 << d, dtype=np.float64)
    ck = np.empty(1 << d, dtype=np.int64)
    half = np.empty(d, dtype=np.float64)
    den = np.empty(d, dtype=np.float64)
    inv = np.zeros(d, dtype=np.float64)
    for k in range(d):
        half[k] = 0.5 * plateau[k]
        den[k] = 1.0 - plateau[k]
        if den[k] > 0.0 and math.frexp(den[k])[0] == 0.5:  # a power of two
            inv[k] = 1.0 / den[k]
    for r in range(n):
        code = 0
        inside = True
        base = 0
        past = 0.0
        for k in range(d):
            xv = X[r, k]
            if math.isnan(xv):
                code = 1
                break
            lo_k = lo[k]
            st = step[k]
            nk = nsets[k]
            hi_k = lo_k + st * (nk - 1)
            if code == 3 or xv < lo_k or xv > hi_k:
                past += _past(xv, lo_k, hi_k, trend[k + 1])
            xv, code = _clipped(xv, lo_k, hi_k, code)
            t = (xv - lo_k) / st  # the fine level: b = 1, its centre offset 0
            i = int(t + 0.5)  # t >= 0 here (xv clipped), so the floor
            if i > nk - 1:
                i = nk - 1
            if i < inner[k, 0] or i > inner[k, 1]:
                inside = False
            j, ws[k] = _lower_weight_at(t, nk, half[k], den[k], inv[k])
            base += j * radix[k]
        out[r] = np.nan
        support[r] = 0.0
        level[r] = -1
        spread[r] = np.nan
        again[r] = False
        if code == 1:
            reason[r] = 1
            continue
        vl, sl, ql, wl = _fire_table(ws, d, base, radix, table, rules, cw, ck)
        if sl > 0.0:
            out[r] = vl / sl
            support[r] = sl
            level[r] = 0
            if wl > 0.0:
                spread[r] = ql / wl
        if sl < enough and coarse and inside:
            again[r] = True
        if code == 3 and level[r] >= 0:
            out[r] = out[r] + past
        reason[r] = code if level[r] >= 0 else 2


@nb.njit(cache=True, nogil=True)
def coarse_corners(fine, blocks, nsets, plateau, radix, cells):
    """The multilinear design of a coarse level's node fit
    (:func:`~diag_plugin.fuzzy.wang_mendel._fit_nodes`): each fine rule (``fine``: its set
    index per input) at its set centres in the coarse partition (``blocks`` fine sets per
    coarse set, ``nsets`` coarse sets, ``plateau`` per input, ``radix`` of the coarse keys,
    ``cells`` coarse cells in all), and for every corner of its coarse cell with a positive
    weight: the row, the node's index among the nodes met and the weight. Returned in numpy's
    order (corner by corner, rows ascending within each) with the nodes ascending — the same
    arithmetic in the same order as the numpy code it replaces, so the same bits, without its
    dozens of small array calls per fit."""
    n, d = fine.shape
    lower = np.empty((n, d), np.int64)
    upper_w = np.empty((n, d), np.float64)
    lower_w = np.empty((n, d), np.float64)
    for k in range(d):
        b = blocks[k]
        hi = nsets[k] - 1.0
        pl = plateau[k]
        for r in range(n):
            t = (fine[r, k] - 0.5 * (b - 1)) / b
            if t < 0.0:
                t = 0.0
            elif t > hi:
                t = hi
            j = np.int64(math.floor(t))
            if j > nsets[k] - 2:
                j = nsets[k] - 2
            u = (t - j - 0.5 * pl) / (1.0 - pl)
            if u < 0.0:
                u = 0.0
            elif u > 1.0:
                u = 1.0
            lower[r, k] = j
            upper_w[r, k] = u
            lower_w[r, k] = 1.0 - u
    corners = 1 << d
    total = 0
    key = np.empty(corners * n, np.int64)
    rows = np.empty(corners * n, np.int64)
    vals = np.empty(corners * n, np.float64)
    mark = np.full(cells, -1, np.int64)
    for c in range(corners):
        for r in range(n):
            w = upper_w[r, 0] if c & 1 else lower_w[r, 0]
            for k in range(1, d):
                w = w * (upper_w[r, k] if (c >> k) & 1 else lower_w[r, k])
            if w > 0.0:
                kk = 0
                for k in range(d):
                    kk += (lower[r, k] + ((c >> k) & 1)) * radix[k]
                key[total] = kk
                rows[total] = r
                vals[total] = w
                mark[kk] = 0
                total += 1
    nodes = np.empty(cells, np.int64)
    m = 0
    for kk in range(cells):
        if mark[kk] == 0:
            mark[kk] = m
            nodes[m] = kk
            m += 1
    col = np.empty(total, np.int64)
    for i in range(total):
        col[i] = mark[key[i]]
    return nodes[:m].copy(), rows[:total].copy(), col, vals[:total].copy()


@nb.njit(cache=True, nogil=True)
def smooth_gram(nodes, radix, nsets):
    """``P.T @ P`` of the node fit's smoothness prior (one row of 1, -2, 1 per second
    difference along an input where both neighbours are nodes; ``nodes`` ascending): small
    integers summed, so exactly the dense product, without forming ``P``."""
    k = nodes.size
    d = radix.size
    out = np.zeros((k, k))
    at = np.empty(3, np.int64)
    v = np.array([1.0, -2.0, 1.0])
    for j in range(d):
        for i in range(k):
            idx = (nodes[i] // radix[j]) % nsets[j]
            if idx <= 0 or idx >= nsets[j] - 1:
                continue
            b = np.searchsorted(nodes, nodes[i] - radix[j])
            a = np.searchsorted(nodes, nodes[i] + radix[j])
            if (
                b >= k
                or a >= k
                or nodes[b] != nodes[i] - radix[j]
                or nodes[a] != nodes[i] + radix[j]
            ):
                continue
            at[0], at[1], at[2] = b, i, a
            for p in range(3):
                for q in range(3):
                    out[at[p], at[q]] += v[p] * v[q]
    return out


@nb.njit(cache=True, nogil=True)
def sets_filled(pos, top, bottom, per_cell):
    """:func:`~diag_plugin.selection.sets.sets_for_data`'s search: the most sets from ``top``
    down to ``bottom`` for which the cells the rows of ``pos`` (each sample's place in every
    input's span, finite) occupy hold ``per_cell`` samples on average, else ``bottom`` — the
    same set indices (``floor(pos · (sets - 1) + 0.5)`` clipped) and counts in one loop per
    count tried, through one table of ``top^d`` cells; a count's loop stops at the first
    cell that makes it too many (cells are only ever added: the count fails then)."""
    n, d = pos.shape
    cells = 1
    for _ in range(d):
        cells *= top
    seen = np.zeros(cells, np.bool_)
    keys = np.empty(n, np.int64)
    for sets in range(top, bottom - 1, -1):
        occupied = 0
        done = n  # rows whose cells are marked (a count stops once it is too many)
        for r in range(n):
            key = 0
            mul = 1
            for k in range(d):
                t = math.floor(pos[r, k] * (sets - 1) + 0.5)
                if t < 0.0:
                    t = 0.0
                elif t > sets - 1:
                    t = sets - 1
                key += np.int64(t) * mul
                mul *= sets
            keys[r] = key
            if not seen[key]:
                seen[key] = True
                occupied += 1
                if n < per_cell * occupied:  # this count fails whatever the other rows hold
                    done = r + 1
                    break
        for r in range(done):
            seen[keys[r]] = False
        if n >= per_cell * occupied:
            return sets
    return bottom


@nb.njit(cache=True, nogil=True)
def normal_equations(r, col, w, sw, y, n_rules, k):
    """``A.T @ A`` and ``A.T @ (sw · y)`` of a coarse level's node fit from its sparse design
    (:func:`coarse_corners`' ``r``, ``col``, ``w``: row, node and weight of each corner; the
    design ``A[r, col] = w · sw[r]``), summed over each rule's own corners only — a rule meets
    at most ``2^d`` nodes, where the dense product runs over every rule × node × node. The
    same sums in another order: equal to the dense product to rounding, not to the bit
    (used to score candidates, :func:`~diag_plugin.fuzzy.wang_mendel.sparse_node_fit`)."""
    m = r.size
    start = np.zeros(n_rules + 1, np.int64)
    for i in range(m):
        start[r[i] + 1] += 1
    for i in range(n_rules):
        start[i + 1] += start[i]
    fill = start[:-1].copy()
    at = np.empty(m, np.int64)
    for i in range(m):
        at[fill[r[i]]] = i
        fill[r[i]] += 1
    M = np.zeros((k, k))
    rhs = np.zeros(k)
    for row in range(n_rules):
        a, b = start[row], start[row + 1]
        s = sw[row]
        for p in range(a, b):
            ip = at[p]
            vp = w[ip] * s
            cp = col[ip]
            rhs[cp] += vp * (s * y[row])
            for q in range(a, b):
                iq = at[q]
                M[cp, col[iq]] += vp * (w[iq] * s)
    return M, rhs


@nb.njit(cache=True, nogil=True)
def coarse_rules(keys, count, qsum, qsq, radix, blocks, coarse_radix, out_lo, yquant):
    """A coarse level's rules of an averaged (``wm-avg``) model from its fine cells
    (:meth:`~diag_plugin.fuzzy.wang_mendel.WangMendelRegressor.level_rules`): each fine key
    with samples taken to its coarse key (every set index ``// blocks``), the integer
    accumulators summed per coarse key in ascending order, and each cell's conclusion and
    spread from the sums — the numpy code's integer sums (exact in any order) and its
    element-wise arithmetic in its order, so the same bits without its dozen array calls."""
    d = radix.size
    m = 0
    for i in range(keys.size):
        if count[i] > 0:
            m += 1
    ck = np.empty(m, np.int64)
    src = np.empty(m, np.int64)
    j = 0
    for i in range(keys.size):
        if count[i] > 0:
            rem = keys[i]
            out = 0
            for k in range(d):
                idx = rem // radix[k]
                rem = rem - idx * radix[k]
                out += (idx // blocks[k]) * coarse_radix[k]
            ck[j] = out
            src[j] = i
            j += 1
    order = np.argsort(ck, kind="mergesort")
    u = 0
    for t in range(m):
        if t == 0 or ck[order[t]] != ck[order[t - 1]]:
            u += 1
    ukeys = np.empty(u, np.int64)
    ucount = np.zeros(u, np.int64)
    usum = np.zeros(u, np.int64)
    usq = np.zeros(u, np.int64)
    g = -1
    for t in range(m):
        o = order[t]
        if t == 0 or ck[o] != ck[order[t - 1]]:
            g += 1
            ukeys[g] = ck[o]
        s = src[o]
        ucount[g] += count[s]
        usum[g] += qsum[s]
        usq[g] += qsq[s]
    conc = np.empty(u)
    sd = np.empty(u)
    for g in range(u):
        mean = usum[g] / ucount[g]
        conc[g] = out_lo + mean * yquant
        v = usq[g] / ucount[g] - mean * mean
        if v < 0.0:
            v = 0.0
        sd[g] = math.sqrt(v) * yquant
    return ukeys, conc, ucount, sd
