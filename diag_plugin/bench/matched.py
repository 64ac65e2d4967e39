"""Detection at a matched false-alarm rate: the yardstick every detector is judged with.

Two detectors compared each at its own default limits are not compared: one that alarms more
detects more. Here every method gives **one alarm score per sample**, and its limit is set so
that its fault-free alarm rate on *calibration runs* — fault-free runs none of the methods
learned from — equals the same target, per sample or in alarm episodes per hour. Then
detection, delay, episodes and naming are counted on yet other runs (fault-free scoring runs
show the matched rate holds out of sample), at several targets: a detection-vs-false-alarm
curve.

The score of a method with statistics ``x_1 … x_k`` (each already divided by its own limit:
a unit's test residual by its threshold on the side it leaves, its combined ``T²`` by its
limit; PCA's ``T²`` and ``Q`` by theirs) is ``max_i d_i`` where ``d_i`` is statistic ``i``
*after the on/off delays* (:func:`delayed_score`): with ``on`` samples to switch on and
``off`` to switch off, ``d(t) = max(min_{on}(x)(t), min(d(t−1), max_{off}(x)(t)))`` — the
rolling minimum over the last ``on`` samples, the rolling maximum over the last ``off``.
By induction ``d(t) > λ`` exactly when an on/off-delayed alarm on ``x > λ``
(:class:`~diag_plugin.diagnose.symptoms.OnOffDelay`) is on at ``t``, for *every* ``λ``: so
scaling all of a method's limits by one factor ``λ`` and applying its delays per statistic,
as the unit does per test, is one threshold on one scalar. Delays applied after the maximum
instead would let different statistics take turns to hold an alarm on; per statistic is how
a unit (and a PCA chart per statistic) runs. Every method gets the same delays.

A unit with an oscillation hold (``oscillation_window_s``, :class:`~diag_plugin.diagnose.
unitloops.OscillationHold`: armed by ``K`` side changes within ``K`` windows, kept while the
test is on or both sides were on within the window) adds per test :func:`oscillation_score`
from its two sides' delayed ratios ``d⁺``, ``d⁻``: ``a(t)``, the best chain of ``K + 1``
samples alternating in side within the last ``K·w`` (the largest min of their ratios),
``b(t)`` that of 2 samples within the last ``w``, and ``h(t) = max(min(a, b)(t),
min(max(b, d⁺, d⁻)(t), h(t − 1)))``: the alarm at ``λ`` has ``K`` changes within ``K·w``
exactly where ``a > λ``, both sides within ``w`` where ``b > λ``, and ``h(t) > λ`` exactly
where the hold at ``λ`` is armed, so the held alarm is again one threshold on one scalar
(``K = 1``: the hold of e2ea008, ``min(max_w d⁺, max_w d⁻)`` but for one sample on both).

Counting, so a method cannot win by being unknown or by alarming more:

* a sample where a method knows nothing (score NaN) is *not in alarm*, and stays in every
  denominator (fault-free share, detection rate): unknown is never a detection;
* the limit is the smallest ``λ`` whose calibration rate is at most the target (per sample:
  share of samples with ``d > λ``; per hour: alarm episodes — a sample in alarm whose
  previous sample was not, runs never joined — per hour, the smallest ``λ`` above which the
  rate never again exceeds the target, since episodes need not fall monotonically with ``λ``);
* a target the calibration runs cannot resolve (fewer than :data:`MIN_EXPECTED` samples or
  episodes expected at it) is flagged ``supported = False``: its limit is read off the tail
  of a few samples.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numba
import numpy as np

from diag_plugin.diagnose.unitloops import OSCILLATION_CHANGES
from diag_plugin.diagnose.unittags import side_ratio

__all__ = [
    "MIN_EXPECTED",
    "Limit",
    "TailLevel",
    "calibrate",
    "calibrate_leaving_out",
    "delayed_score",
    "episode_count",
    "episode_ids",
    "episode_names",
    "naming",
    "oscillation_score",
    "episode_interval",
    "method_score",
    "side_ratio",
    "split_spread",
    "tail_levels",
]

#: a target is resolved by the calibration runs when at least this many alarm samples (per
#: sample) or episodes (per hour) are expected at it
MIN_EXPECTED = 5


@numba.njit(cache=True)
def _delay_score_kernel(x, on, off):  # pragma: no cover - numba
    n, m = x.shape
    out = np.empty_like(x)
    for j in range(m):
        prev = -np.inf
        for t in range(n):
            lo = np.inf
            if t + 1 >= on:
                for k in range(t - on + 1, t + 1):
                    v = x[k, j]
                    lo = min(lo, v if v == v else -np.inf)
            else:
                lo = -np.inf
            hi = -np.inf
            for k in range(max(0, t - off + 1), t + 1):
                v = x[k, j]
                hi = max(hi, v if v == v else -np.inf)
            d = max(lo, min(prev, hi))
            out[t, j] = d
            prev = d
    return out


def delayed_score(x: np.ndarray, on: int = 1, off: int = 1) -> np.ndarray:
    """Per column, the statistic after on/off delays of ``on``/``off`` samples (see module
    doc): ``d > λ`` exactly where the delayed alarm of ``x > λ`` is on, for any ``λ``.
    NaN (unknown) counts as not over; a column wholly unknown stays NaN."""
    if on < 1 or off < 1:
        raise ValueError("delays are counted in samples and must be ≥ 1")
    a = np.asarray(x, float)
    one = a.ndim == 1
    a2 = np.ascontiguousarray(a[:, None] if one else a)
    d = _delay_score_kernel(a2, int(on), int(off))
    d[np.isneginf(d)] = np.nan  # never over any limit: nothing known over the windows
    return d[:, 0] if one else d


@numba.njit(cache=True)
def _chains(v, first, last, step, out):  # pragma: no cover - numba
    # from sample ``first`` to ``last`` by ``step`` (±1), out[t, a, j]: over the samples from
    # ``first`` to t, the best chain of j + 1 samples alternating in side whose sample nearest
    # t is on side a (0 above, 1 below): the largest min of its samples' side values v[·, ·]
    # (-inf: none). A chain through t is t's value and the best shorter one begun on the
    # other side before it
    k = out.shape[2]
    for t in range(first, last + step, step):
        for a in range(2):
            for j in range(k):
                new = v[t, a]
                if j > 0:
                    new = min(new, out[t - step, 1 - a, j - 1]) if t != first else -np.inf
                out[t, a, j] = max(out[t - step, a, j], new) if t != first else new
    return out


@numba.njit(cache=True)
def _swing_score_kernel(up, down, window, k):  # pragma: no cover - numba
    # per column the best chain of k + 1 samples alternating in side within each window
    # [t - w + 1, t]: a block's suffix (chains from s to the block's end, by their first
    # sample's side) joined to the next block's prefix (from its start to t, by their last
    # sample's side), blocks of w samples (van Herk / Gil-Werman): O(n k²) a column
    n, m = up.shape
    res = np.empty((n, m))
    v = np.empty((n, 2))
    pre = np.empty((n, 2, k + 1))
    suf = np.empty((n, 2, k + 1))
    for c in range(m):
        for t in range(n):
            a, b = up[t, c], down[t, c]
            v[t, 0] = a if a == a else -np.inf
            v[t, 1] = b if b == b else -np.inf
        for lo in range(0, n, window):
            hi = min(lo + window, n) - 1
            _chains(v, lo, hi, 1, pre)
            _chains(v, hi, lo, -1, suf)
        for t in range(n):
            s = t - window + 1
            best = max(pre[t, 0, k], pre[t, 1, k])
            if s > 0 and s % window != 0:  # the window begins in the block before t's
                for a in range(2):  # the chain's first side
                    best = max(best, suf[s, a, k])
                    for i in range(1, k + 1):  # its first i samples there, the rest after
                        e = a if i % 2 == 1 else 1 - a  # the side of its i-th sample
                        rest = k + 1 - i
                        f = 1 - e if rest % 2 == 1 else e  # the side of its last sample
                        best = max(best, min(suf[s, a, i - 1], pre[t, f, rest - 1]))
            res[t, c] = best if best > -np.inf else np.nan
    return res


@numba.njit(cache=True)
def _armed_kernel(arm, keep):  # pragma: no cover - numba
    # per column h(t) = max(arm(t), min(keep(t), h(t - 1))): h > λ exactly where, at λ, the
    # hold armed at some sample and was kept on every sample since
    n, m = arm.shape
    out = np.empty((n, m))
    for j in range(m):
        prev = -np.inf
        for t in range(n):
            a, b = arm[t, j], keep[t, j]
            h = max(a if a == a else -np.inf, min(b if b == b else -np.inf, prev))
            out[t, j] = h
            prev = h
    return out


@numba.njit(cache=True)
def _settled_kernel(du, dd, arm0, both0, opens, quiet, window, k):  # pragma: no cover - numba
    # per column the hold's statistic where settles open (opens[t, j] > 0: the bound in
    # samples), row by row. At a level λ a settle at t disarms the hold when the column was
    # off at λ over the ``quiet`` rows before t (calm), i.e. when λ ≥ M(t), the largest output
    # score O there (O = max(d, h): on or held); from t its symptoms pass unseen until the
    # bound, then the hold starts afresh. So the levels fall into regimes [L_r, U_r) sharing
    # one history: the hold restarts at B[r] (rows before it pass through). In a regime the
    # hold is the unsettled rule begun at B[r]: its chains over windows clipped at B[r] (a
    # prefix from B[r], P) until a window lies past it (then the run's own, arm0 / both0),
    # h = max(min(arm, both), min(max(both, d), h(t − 1))). The score at t is the largest λ
    # whose regime's hold is over it: max over r of min(h_r, U_r) where h_r > L_r
    n, m = du.shape
    out = np.full((n, m), -np.inf)
    kw = k * window
    for j in range(m):
        cap = 2
        for t in range(n):
            if opens[t, j] > 0:
                cap += 1
        lv = np.empty(cap)
        bs = np.empty(cap, np.int64)
        hs = np.empty(cap)
        ps = np.empty((cap, 2, k + 1))
        nl = np.empty(cap)
        nb = np.empty(cap, np.int64)
        nh = np.empty(cap)
        npf = np.empty((cap, 2, k + 1))
        r_n = 1
        lv[0], bs[0], hs[0] = -np.inf, 0, -np.inf
        ps[0] = -np.inf
        big = np.empty(n)  # O: the column's output score (on or held)
        tmp = np.empty((2, k + 1))
        for t in range(n):
            o = opens[t, j]
            if o > 0:
                lim = -np.inf  # M: calm at every level from it
                for q in range(max(0, t - quiet[j]), t):
                    lim = max(lim, big[q])
                q_n = 0
                for r in range(r_n):
                    lo_r = lv[r]
                    hi_r = lv[r + 1] if r + 1 < r_n else np.inf
                    if lo_r < lim:  # the levels of it below M: the settle not seen
                        nl[q_n], nb[q_n], nh[q_n] = lo_r, bs[r], hs[r]
                        npf[q_n] = ps[r]
                        q_n += 1
                    if hi_r > lim:  # those at or above M: unseen until the bound, then afresh
                        b2 = max(bs[r], t + o)
                        nl[q_n], nb[q_n] = max(lo_r, lim), b2
                        if b2 == bs[r]:
                            nh[q_n] = hs[r]
                            npf[q_n] = ps[r]
                        else:
                            nh[q_n] = -np.inf
                            npf[q_n] = -np.inf
                        q_n += 1
                r_n = 0
                for r in range(q_n):  # one history per restart: neighbours of one B merge
                    if r_n > 0 and nb[r] == bs[r_n - 1]:
                        continue
                    lv[r_n], bs[r_n], hs[r_n] = nl[r], nb[r], nh[r]
                    ps[r_n] = npf[r]
                    r_n += 1
            a_up, a_dn = du[t, j], dd[t, j]
            d = max(a_up, a_dn)
            best = -np.inf
            for r in range(r_n):
                b = bs[r]
                if t < b:
                    continue
                if t < b + kw:  # the chains' windows reach back past B: from B on
                    for a in range(2):
                        v = a_up if a == 0 else a_dn
                        for c in range(k + 1):
                            new = v
                            if c > 0:
                                new = min(v, ps[r, 1 - a, c - 1]) if t > b else -np.inf
                            tmp[a, c] = max(ps[r, a, c], new) if t > b else new
                    ps[r] = tmp
                    arm = max(ps[r, 0, k], ps[r, 1, k])
                else:
                    arm = arm0[t, j]
                both = max(ps[r, 0, 1], ps[r, 1, 1]) if t < b + window else both0[t, j]
                h = max(min(arm, both), min(max(both, d), hs[r]))
                hs[r] = h
                hi_r = lv[r + 1] if r + 1 < r_n else np.inf
                if h > lv[r]:
                    best = max(best, min(h, hi_r))
            out[t, j] = best
            big[t] = max(d, best)
    return out


def oscillation_score(
    up: np.ndarray,
    down: np.ndarray,
    on: int,
    off: int,
    window: int,
    changes: int | None = None,
    opens: np.ndarray | None = None,
    quiet: int | np.ndarray = 1,
) -> np.ndarray:
    """Per column (a test) the oscillation hold's statistic (module doc) from its two sides'
    delayed ratios (``up``: ``r / high``, ``down``: ``r / low``): over ``λ`` exactly where the
    hold of the alarms at ``λ`` is armed, ``changes`` side changes (default the hold's
    :data:`~diag_plugin.diagnose.unitloops.OSCILLATION_CHANGES`) within ``changes`` ×
    ``window`` samples and since then on every sample the test on or both sides on within
    ``window``; NaN throughout for a window of 0 (no hold), NaN where never armed.

    ``opens`` (samples × columns, the settle's bound in samples where one opens on the
    test: :attr:`~diag_plugin.diagnose.unit.Unit.openings_seen`; None: none) and ``quiet``
    (samples, per column or one) apply the hold's settle rule as the unit does: at each level
    a settle opening on a test off (neither on nor held) for ``quiet`` samples disarms the
    hold, and the test's alarms until its bound pass as they are, unseen by it
    (:func:`_settled_kernel`; :class:`~diag_plugin.diagnose.unitloops.OscillationHold`)."""
    u = np.asarray(up, float).reshape(len(up), -1)
    if window < 1 or not u.size:
        return np.full(u.shape, np.nan)
    k = OSCILLATION_CHANGES if changes is None else int(changes)
    du = np.ascontiguousarray(delayed_score(u, on, off))
    dd = np.ascontiguousarray(delayed_score(np.asarray(down, float).reshape(u.shape), on, off))
    arm = _swing_score_kernel(du, dd, k * int(window), k)
    both = _swing_score_kernel(du, dd, int(window), 1)
    op = None if opens is None else np.asarray(opens, np.int64).reshape(u.shape)
    if op is not None and (op > 0).any():
        qn = np.broadcast_to(np.asarray(quiet, np.int64), (u.shape[1],)).copy()
        h = _settled_kernel(_finite(du), _finite(dd), _finite(arm), _finite(both),
                            np.ascontiguousarray(op), qn, int(window), k)  # fmt: skip
    else:
        with np.errstate(invalid="ignore"):
            keep = np.fmax(both, np.fmax(du, dd))  # NaN only where all three are
        h = _armed_kernel(np.minimum(arm, both), keep)  # armed where both sides are, too
    h[np.isneginf(h)] = np.nan
    return h


def method_score(
    stats: np.ndarray, on: int = 1, off: int = 1, held: np.ndarray | None = None
) -> np.ndarray:
    """One alarm score per sample: the maximum over a method's statistics (columns, each over
    its own limit) after each statistic's own on/off delays, and over ``held`` (columns
    already delayed: :func:`oscillation_score`); NaN where none is known."""
    d = delayed_score(np.asarray(stats, float).reshape(len(stats), -1), on, off)
    if held is not None:
        d = np.c_[d, held]
    with np.errstate(all="ignore"):
        known = (~np.isnan(d)).any(axis=1)
        out = np.full(len(d), np.nan)
        out[known] = np.nanmax(d[known], axis=1)
    return out


def episode_count(alarm: np.ndarray) -> int:
    """Alarm episodes in one run: samples in alarm whose previous sample was not (the first
    sample counts when in alarm)."""
    a = np.asarray(alarm, bool)
    if not a.size:
        return 0
    return int(a[0]) + int(np.count_nonzero(a[1:] & ~a[:-1]))


def _finite(d: np.ndarray) -> np.ndarray:
    """Unknown (NaN) as never over any limit; +inf stays over every finite one."""
    return np.where(np.isnan(d), -np.inf, d)


def _survival(values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Per ``at``, how many of ``values`` are strictly greater."""
    v = np.sort(values)
    return v.size - np.searchsorted(v, at, side="right")


@dataclass(frozen=True)
class Limit:
    """A method's limit ``λ`` on its score at one target, with what the calibration runs gave."""

    target: float
    per: str  # "sample" or "hour"
    limit: float
    share: float  # share of calibration samples with score > limit
    per_hour: float  # alarm episodes per hour on the calibration runs
    samples: int
    hours: float
    supported: bool

    def as_dict(self) -> dict:
        lim = self.limit if np.isfinite(self.limit) else None
        return {
            "target": self.target,
            "per": self.per,
            "limit": lim,
            "share": self.share,
            "per_hour": self.per_hour,
            "samples": self.samples,
            "hours": self.hours,
            "supported": self.supported,
        }


def rates(runs: Sequence[np.ndarray], limit: float, period_s: float) -> tuple[float, float]:
    """(share of samples with score > ``limit``, alarm episodes per hour) over ``runs``;
    unknown samples are not in alarm and stay in the denominators."""
    n = sum(len(r) for r in runs)
    if not n:
        return float("nan"), float("nan")
    on = [_finite(np.asarray(r, float)) > limit for r in runs]
    share = sum(int(a.sum()) for a in on) / n
    return share, sum(episode_count(a) for a in on) / (n * period_s / 3600.0)


def calibrate(
    runs: Sequence[np.ndarray], target: float, period_s: float, per: str = "sample"
) -> Limit:
    """The smallest limit whose rate on the fault-free calibration ``runs`` (each a score
    array, episodes never joined across runs) is at most ``target``: a share of samples
    (``per="sample"``) or alarm episodes per hour (``per="hour"``, the smallest limit above
    which the rate never exceeds the target)."""
    if per not in ("sample", "hour"):
        raise ValueError(f"per must be 'sample' or 'hour', not {per!r}")
    if not target > 0 or (per == "sample" and target >= 1):
        raise ValueError(f"target false-alarm rate {target!r} out of range")
    runs = [_finite(np.asarray(r, float)) for r in runs if len(r)]
    n = sum(len(r) for r in runs)
    if not n:
        raise ValueError("calibration: no samples")
    hours = n * period_s / 3600.0
    d = np.concatenate(runs)
    fin = np.unique(d[np.isfinite(d)])
    if not fin.size:
        lim = np.inf
    elif per == "sample":
        over = _survival(d, fin)  # samples above each candidate, falling
        ok = np.flatnonzero(over <= target * n)
        lim = float(fin[ok[0]]) if ok.size else np.inf
        # below the smallest finite value every known sample alarms: a limit there too
        if over[0] + np.count_nonzero(d == fin[0]) <= target * n:
            lim = -np.inf
    else:
        prev = np.concatenate([np.r_[-np.inf, r[:-1]] for r in runs])
        both = np.minimum(prev, d)
        ep = _survival(d, fin) - _survival(both, fin)
        bad = np.flatnonzero(ep > target * hours)
        if not bad.size:
            lim = float(fin[0])
        elif bad[-1] + 1 < fin.size:
            lim = float(fin[bad[-1] + 1])
        else:
            lim = np.inf
    share, ph = rates(runs, lim, period_s)
    expected = target * (n if per == "sample" else hours)
    return Limit(
        target=float(target),
        per=per,
        limit=float(lim),
        share=share,
        per_hour=ph,
        samples=n,
        hours=hours,
        supported=bool(expected >= MIN_EXPECTED),
    )


def calibrate_leaving_out(
    runs: Mapping[str, np.ndarray],
    scored: Sequence[str],
    target: float,
    period_s: float,
    per: str = "sample",
) -> dict[str, Limit]:
    """Per name in ``scored``, the limit :func:`calibrate` matches on the calibration ``runs``
    (name → score array) without that name's own run: for a faulty run whose fault-free
    samples are also calibration samples (SKAB's tuning runs), so that it is scored, as a
    held-out run is, at a limit it did not set. Its own normal samples after the fault, held in
    alarm by the off-delay, are otherwise the calibration's largest scores, and every fault
    they follow sits at or under the low targets' limits by construction."""
    return {
        n: calibrate([x for k, x in runs.items() if k != n], target, period_s, per) for n in scored
    }


@dataclass(frozen=True)
class TailLevel:
    """One value a method's score takes among the calibration's largest samples: the value,
    how many samples hold it, in how many alarm episodes (runs never joined) and which runs."""

    value: float
    samples: int
    episodes: int
    runs: tuple[int, ...]


def tail_levels(runs: Sequence[np.ndarray], share: float) -> list[TailLevel]:
    """The distinct values of the largest ``share`` of the calibration ``runs``' samples (each
    a score array; ties at the cut-off all in), largest first, each with its samples, its
    episodes (a run of consecutive samples at that value) and the runs (indices) holding it.

    A limit matched at a target under ``share`` is one of these values (or above them all), so
    their number is how many different limits the calibration can give there, and a value
    held by one episode is one event however many samples it spans: an off-delay holding a
    fault's alarm over the normal samples after it gives one value for all of them."""
    if not 0 < share < 1:
        raise ValueError(f"share {share!r} out of range")
    runs = [_finite(np.asarray(r, float)) for r in runs]
    n = sum(len(r) for r in runs)
    d = np.concatenate(runs) if runs else np.empty(0)
    fin = d[np.isfinite(d) | (d == np.inf)]
    if not fin.size:
        return []
    k = min(fin.size, max(1, int(np.ceil(share * n))))
    cut = np.sort(fin)[::-1][k - 1]
    out: dict[float, list] = {}
    for i, r in enumerate(runs):
        top = r >= cut
        for v in np.unique(r[top]):
            at = r == v
            ep = episode_count(at)
            rec = out.setdefault(float(v), [0, 0, []])
            rec[0] += int(at.sum())
            rec[1] += ep
            rec[2].append(i)
    return [
        TailLevel(v, c, e, tuple(w)) for v, (c, e, w) in sorted(out.items(), key=lambda kv: -kv[0])
    ]


def episode_interval(episodes: int, hours: float, level: float = 0.95) -> tuple[float, float]:
    """The exact (Garwood) two-sided interval of an alarm-episode rate per hour from
    ``episodes`` counted in ``hours``: ``χ²_{α/2}(2k)/2`` to ``χ²_{1−α/2}(2k+2)/2`` over
    ``hours`` (``α = 1 − level``; the lower end 0 at ``k = 0``). Episodes, not samples, are
    the independent events of a fault-free run: one episode holds the on/off delays' several
    samples."""
    from scipy import stats

    if hours <= 0 or episodes < 0:
        raise ValueError("an interval needs hours > 0 and episodes ≥ 0")
    a = 1.0 - level
    lo = stats.chi2.ppf(a / 2, 2 * episodes) / 2 if episodes else 0.0
    hi = stats.chi2.ppf(1 - a / 2, 2 * episodes + 2) / 2
    return float(lo / hours), float(hi / hours)


def split_spread(
    pieces: Mapping[str, Sequence[np.ndarray]],
    n_cal: int,
    target: float,
    period_s: float,
    per: str = "sample",
    draws: int = 2000,
    seed: int = 0,
) -> dict[str, np.ndarray]:
    """How far a matched limit's out-of-sample rate moves by chance alone: per method
    (name → the score arrays of the same fault-free pieces, in the same order), over
    ``draws`` random splits of the pieces, ``n_cal`` of them set the limit
    (:func:`calibrate` at ``target``) and the others are scored at it (:func:`rates`: the
    share of samples in alarm, or episodes per hour with ``per="hour"``). Every method gets
    the same split in a draw, so the arrays returned (one rate per draw) pair up: their
    difference is one method's excess over another's on the same data. Where the pieces are
    exchangeable (fault-free, alike in length and start), the rate one fixed split gave is
    one draw of this distribution."""
    names = list(pieces)
    k = {len(pieces[n]) for n in names}
    if len(k) != 1:
        raise ValueError("every method needs the same pieces")
    n = k.pop()
    if not 0 < n_cal < n:
        raise ValueError(f"n_cal must leave pieces on both sides of the split (0 < {n_cal} < {n})")
    rng = np.random.default_rng(seed)
    out = {m: np.empty(draws) for m in names}
    which = 0 if per == "sample" else 1
    for i in range(draws):
        idx = rng.permutation(n)
        for m in names:
            p = pieces[m]
            lim = calibrate([p[j] for j in idx[:n_cal]], target, period_s, per).limit
            out[m][i] = rates([p[j] for j in idx[n_cal:]], lim, period_s)[which]
    return out


# ---------------------------------------------------------------- scoring at a limit


@dataclass
class FaultRun:
    """One faulty run as every method scores it: the fault, the run's name, the sample of the
    onset, the tags at fault (empty: no single tag is, naming not counted)."""

    fault: str
    run: str
    onset: int
    tags: tuple[str, ...] = ()
    #: where the fault is present (a labelled data set's anomaly labels); default: from the
    #: onset to the end
    active: np.ndarray | None = None


@dataclass
class Scored:
    """A method's score on one run, and (to name tags) its per-tag contributions."""

    score: np.ndarray
    contributions: object | None = None  # pandas DataFrame: per sample, per tag


def run_at(
    score: np.ndarray, onset: int, limit: float, period_s: float, active: np.ndarray | None = None
) -> dict:
    """A faulty run at ``limit``: the share of samples where the fault is present (``active``;
    default from ``onset`` on) in alarm (unknown counts as not), seconds to the first alarm at
    or after the onset, and alarm episodes after it."""
    on = _finite(np.asarray(score, float)) > limit
    after = on[onset:]
    hit = np.flatnonzero(after)
    present = after if active is None else on[np.asarray(active, bool)]
    return {
        "detection_rate": float(present.mean()) if present.size else float("nan"),
        "delay_s": float(hit[0] * period_s) if hit.size else None,
        "episodes": episode_count(after),
        "alarm_rows": np.flatnonzero(on),
    }


def ranked_tags(contributions, rows: np.ndarray, k: int = 3) -> list[str]:
    """Tags by how often they are among the ``k`` largest contributions over ``rows`` (the
    samples in alarm after the onset), as :func:`~diag_plugin.bench.plant.rank_by_top`
    counts a unit's ``top1``…``top3``."""
    from diag_plugin.bench.plant import rank_by_top, top_from_contributions

    if contributions is None or not len(rows):
        return []
    sel = contributions.iloc[rows]
    top = top_from_contributions(sel.fillna(-np.inf), k)
    return rank_by_top(top, np.ones(len(top), dtype=bool), k)


def episode_ids(rows: np.ndarray) -> np.ndarray:
    """Per alarm row (sorted sample indices), the number of its alarm episode (0, 1, …): rows
    one sample apart are one episode, as :func:`episode_count` counts them."""
    r = np.asarray(rows, np.int64)
    if not r.size:
        return np.zeros(0, np.int64)
    return np.r_[0, np.cumsum(np.diff(r) != 1)]


def episode_names(contributions, rows: np.ndarray, k: int = 3) -> list[str]:
    """Per alarm episode of ``rows`` (:func:`episode_ids`), the tag named first over its rows:
    :func:`ranked_tags`' first tag with the rows restricted to the episode's, for all episodes
    at once. The ranking, as :func:`~diag_plugin.bench.plant.rank_by_top` makes it: most often
    among the per-sample ``top1``…``top<k>``, then the smaller mean rank, then the order it
    meets the tags in — by ``top1`` first, within one column by its count there, then by
    first appearance (pandas' stable ``value_counts``). An episode whose rows have no known
    contribution names ``""`` (no tag: :func:`~diag_plugin.bench.plant.top_from_contributions`
    names none where a contribution is unknown); it counts among the episodes, not as named
    right. Empty without contributions or rows."""
    from diag_plugin.bench.plant import top_from_contributions

    rows = np.asarray(rows, np.int64)
    if contributions is None or not rows.size:
        return []
    cols = contributions.columns
    top = top_from_contributions(contributions.iloc[rows].fillna(-np.inf), k)
    ep = episode_ids(rows)
    n_ep, m = int(ep[-1]) + 1, len(cols)
    cnt = np.zeros(n_ep * m, np.int64)
    rsum = np.zeros(n_ep * m, np.int64)
    first_r = np.zeros(n_ep * m, np.int64)  # the first column the tag appears in (0: none)
    cnt_first = np.zeros(n_ep * m, np.int64)  # its count in that column
    pos_first = np.zeros(n_ep * m, np.int64)  # its first row in that column
    for r in range(top.shape[1], 0, -1):  # from the last column, so the first one wins
        col = cols.get_indexer(top[f"top{r}"])
        named = col >= 0  # "": no tag named there (its contribution unknown)
        key = ep[named] * m + col[named]
        c = np.bincount(key, minlength=n_ep * m)
        cnt += c
        rsum += r * c
        seen, at = np.unique(key, return_index=True)
        first_r[seen] = r
        cnt_first[seen] = c[seen]
        pos_first[seen] = np.flatnonzero(named)[at]
    cand = np.flatnonzero(cnt)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = rsum[cand] / cnt[cand]  # rank_by_top's float mean rank, ties exactly as there
    order = np.lexsort((pos_first[cand], -cnt_first[cand], first_r[cand], mean, -cnt[cand],
                        cand // m))  # fmt: skip
    best = cand[order]
    lead = np.r_[True, best[1:] // m != best[:-1] // m]  # each episode's best candidate
    out = [""] * n_ep  # an episode with no contribution known names no tag
    for b in best[lead]:
        out[b // m] = str(cols[b % m])
    return out


def naming(named: Sequence[str], episodes: Sequence[str], tags: Sequence[str]) -> dict:
    """A run's naming against its faulted ``tags``: ``first_right`` (the tag named first,
    ``named[0]``, is one), per episode the tag named (``episode_tags``), how many are faulted
    tags (``episodes_right``) and their share (None without episodes), and whether the name
    changed between consecutive episodes (``name_changed``: what an operator sees as the
    method changing its mind)."""
    right = sum(t in tags for t in episodes)
    return {
        "first_right": bool(tags) and bool(named) and named[0] in tags,
        "episode_tags": list(episodes),
        "episodes_right": int(right),
        "episode_share": right / len(episodes) if episodes else None,
        "name_changed": any(a != b for a, b in zip(episodes[:-1], episodes[1:], strict=True)),
    }


#: the naming counts summed per fault and per method over the runs with a faulted tag
NAMING_SUMS = ("named_first", "episodes_right", "episodes_named", "name_changed_runs")


def _naming_sums(runs: Sequence[dict]) -> dict[str, int]:
    return {
        "named_first": sum(r["first_right"] for r in runs),
        "episodes_right": sum(r["episodes_right"] for r in runs),
        "episodes_named": sum(len(r["episode_tags"]) for r in runs),
        "name_changed_runs": sum(r["name_changed"] for r in runs),
    }


def curve(
    methods: dict[str, dict],
    targets: Sequence[float],
    period_s: float,
    per: str = "sample",
    fault_runs: Sequence[FaultRun] = (),
    top: int = 3,
) -> dict:
    """Detection against false alarms, every method at the same targets.

    ``methods[name]`` holds ``"calibration"`` (score arrays of fault-free runs none of the
    methods learned from), ``"free"`` (score arrays of other fault-free runs, to show the
    rate holds out of sample) and ``"faults"`` (a :class:`Scored` per entry of
    ``fault_runs``, same order). Returns per target and method the calibrated :class:`Limit`,
    the fault-free scoring rates with the alarm episodes behind them and the exact 95 %
    interval of their rate per hour (:func:`episode_interval`), and per fault the mean
    detection rate, median delay, mean episodes after the onset and the runs whose faulted
    tag is among the ``top`` tags named over the samples in alarm after the onset (a run
    without such an alarm names nothing; ``in_top``), those whose tag named first is a
    faulted tag (``named_first``), and over each alarm episode after the onset the tag named
    first over its rows (:func:`episode_names`, :func:`naming`): the episodes named right
    (``episodes_right`` of ``episodes_named``) and the runs whose name changed between
    episodes (``name_changed_runs``). Naming is counted over the runs with a faulted tag.
    """
    out: dict = {"per": per, "targets": list(targets), "period_s": period_s, "points": []}
    faults = list(dict.fromkeys(f.fault for f in fault_runs))
    for target in targets:
        point: dict = {"target": target, "methods": {}}
        for name, m in methods.items():
            lim = calibrate(m["calibration"], target, period_s, per)
            share, ph = rates(m["free"], lim.limit, period_s) if m["free"] else (None, None)
            free_ep = free_ci = None
            if m["free"]:  # the episodes behind the rate, and how far chance alone moves it
                free_h = sum(len(r) for r in m["free"]) * period_s / 3600.0
                free_ep = sum(episode_count(_finite(np.asarray(r, float)) > lim.limit)
                              for r in m["free"])  # fmt: skip
                free_ci = list(episode_interval(free_ep, free_h)) if free_h > 0 else None
            rows = {}
            for f in faults:
                per_run = []
                for fr, sc in zip(fault_runs, m["faults"], strict=True):
                    if fr.fault != f:
                        continue
                    r = run_at(sc.score, fr.onset, lim.limit, period_s, fr.active)
                    ar = r.pop("alarm_rows")
                    ar = ar[ar >= fr.onset]
                    named = ranked_tags(sc.contributions, ar, top)[:top]
                    r["top"] = named
                    r["in_top"] = bool(fr.tags) and any(t in named for t in fr.tags)
                    r["named_counted"] = bool(fr.tags)
                    r.update(naming(named, episode_names(sc.contributions, ar, top), fr.tags))
                    r["run"] = fr.run
                    per_run.append(r)
                delays = [r["delay_s"] for r in per_run if r["delay_s"] is not None]
                counted = [r for r in per_run if r["named_counted"]]
                rows[f] = {
                    "detection_rate": float(np.mean([r["detection_rate"] for r in per_run])),
                    "delay_s": float(np.median(delays)) if delays else None,
                    "detected_runs": len(delays),
                    "episodes": float(np.mean([r["episodes"] for r in per_run])),
                    "in_top": sum(r["in_top"] for r in counted),
                    "named_runs": len(counted),
                    **_naming_sums(counted),
                    "runs": len(per_run),
                    "per_run": per_run,
                }
            det = [rows[f]["detection_rate"] for f in faults]
            counted = [rows[f] for f in faults if rows[f]["named_runs"]]
            point["methods"][name] = {
                "limit": lim.as_dict(),
                "free_share": share,
                "free_per_hour": ph,
                "free_episodes": free_ep,
                "free_per_hour_95": free_ci,
                "faults": rows,
                "mean_detection": float(np.mean(det)) if det else None,
                "in_top": sum(r["in_top"] for r in counted),
                "named_runs": sum(r["named_runs"] for r in counted),
                **{k: sum(r[k] for r in counted) for k in NAMING_SUMS},
            }
        out["points"].append(point)
    return out
