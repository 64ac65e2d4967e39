"""Alignment of raw samples on a regular grid, and the per-tag data-quality summary.

Pure numpy on the stored representation (int64 µs UTC times), so the same functions serve
:meth:`historian.store.Historian.window`, its chunked iterator and ``diag tags``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .quality import BAD, UNCERTAIN
from .sampling import nice_period_us
from .times import US, from_us

SUMMARY_COLUMNS = [
    "samples",
    "good",
    "uncertain",
    "bad",
    "coverage",
    "gaps",
    "gap_s",
    "stale",
    "flat",
    "flat_s",
    "out_of_range",
    "first",
    "last",
]


def align(
    ts, value, quality, t0: int, period: int, n: int, how: str = "mean", hold: int = 0
) -> np.ndarray:
    """Values on the grid ``t0 + k·period`` (k < n) by the rule of :mod:`historian.sampling`:
    grid point ``t`` takes the mean (``how="mean"``) or the last (``how="last"``) usable
    sample in ``[t − period/2, t + period/2)``; with none there, the tag's last sample before
    that bin's end, if it is usable and no older than ``hold`` µs; else NaN. Bad-quality and
    NaN samples are not usable, and a newer unusable sample ends a hold.

    ``ts`` must be sorted and should start ``period/2 + hold`` before ``t0`` so the first grid
    points see what precedes them (then chunked reads give the same values as one read).
    """
    if how not in ("mean", "last"):
        raise ValueError(f"how must be 'mean' or 'last', not {how!r}")
    out = np.full(n, np.nan)
    if len(ts) == 0 or n <= 0:
        return out
    half = period // 2
    all_ts = ts
    usable_all = (quality < BAD) & np.isfinite(value)
    ts_u, value_u = (ts, value) if usable_all.all() else (ts[usable_all], value[usable_all])
    b = (ts_u - t0 + half) // period
    keep = (b >= 0) & (b < n)
    if not keep.all():
        b, value_u = b[keep], value_u[keep]
    if len(b) < 2 or np.all(b[1:] != b[:-1]):  # at most one sample per bin: mean == last
        out[b] = value_u
    elif how == "mean":
        s = np.bincount(b, weights=value_u, minlength=n)
        c = np.bincount(b, minlength=n)
        has = c > 0
        out[has] = s[has] / c[has]
    else:
        # times are sorted, so bins are non-decreasing: the last sample of each bin is where
        # the next bin starts
        ends = np.flatnonzero(np.r_[b[1:] != b[:-1], True])
        out[b[ends]] = value_u[ends]
    if hold > 0:
        empty = np.flatnonzero(np.isnan(out))
        if len(empty):
            grid = t0 + empty * period
            j = np.searchsorted(all_ts, grid - half + period, side="left") - 1
            ok = j >= 0
            j_ok = np.where(ok, j, 0)
            ok &= usable_all[j_ok] & (grid - all_ts[j_ok] <= hold)
            out[empty[ok]] = value[j_ok[ok]]
    return out


def align_pieces(
    pieces, t0: int, period: int, n: int, how: str = "mean", hold: int = 0, out=None
) -> np.ndarray:
    """:func:`align` of one tag's samples given as consecutive (ts, value, quality) pieces
    in time order (the row groups of the rolled months as decoded), the same values to the
    bit. When there is no hold and every piece is a regular series exactly on the grid (one
    sample per grid point ``t0 + k·period``, the pieces after one another), binning is an
    index computation: each piece's usable values are copied to its rows
    (:func:`_on_grid`) without joining the pieces first; else they are joined and aligned.
    ``out``: an array of ``n`` NaN to write the values into (a row of the window's block)."""
    out = np.full(n, np.nan) if out is None else out
    if hold == 0 and how in ("mean", "last") and _on_grid(pieces, t0, period, n, out):
        return out
    if not pieces:
        empty = np.empty(0, np.int64)
        pieces = [(empty, np.empty(0), empty)]
    joined = (np.concatenate(col) for col in zip(*pieces, strict=True))
    out[:] = align(*(pieces[0] if len(pieces) == 1 else joined), t0, period, n, how, hold)
    return out


def _on_grid(pieces, t0: int, period: int, n: int, out: np.ndarray) -> bool:
    """Whether every piece's times are ``t0 + k·period`` for consecutive k, each piece's
    after the one before, and then the aligned values (no hold) written into ``out`` (NaN
    before): grid point k holds its one sample when it is usable (mean and last of one sample
    are the sample), else NaN. ``out`` is unchanged when False is returned."""
    if n <= 0:
        return False
    spans = []  # (first grid index, piece) of each piece
    after = None  # the last grid index of the pieces so far
    for ts, value, quality in pieces:
        m = len(ts)
        if not m:
            continue
        k0, off = divmod(int(ts[0]) - t0, period)
        if off or int(ts[-1]) - int(ts[0]) != (m - 1) * period:
            return False
        if m > 1 and not np.all(ts[1:] - ts[:-1] == period):
            return False
        if after is not None and k0 <= after:
            return False
        after = k0 + m - 1
        spans.append((k0, value, quality))
    for k0, value, quality in spans:
        a, b = max(k0, 0), min(k0 + len(value), n)
        if a < b:
            v, q = value[a - k0 : b - k0], quality[a - k0 : b - k0]
            np.copyto(out[a:b], v, where=(q < BAD) & np.isfinite(v))
    return True


def _runs(mask: np.ndarray):
    """Start and end (exclusive) indices of the runs of True in a boolean array."""
    if not mask.any():
        return np.empty(0, np.int64), np.empty(0, np.int64)
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def flat_runs(t_u: np.ndarray, v_u: np.ndarray, flat_us: int) -> tuple[np.ndarray, np.ndarray]:
    """The runs of an unchanged value lasting at least ``flat_us`` µs among usable samples
    (times ``t_u``, values ``v_u``): each run's value and duration in µs."""
    if len(v_u) < 2:
        return np.empty(0), np.empty(0, np.int64)
    s_idx, e_idx = _runs(v_u[1:] == v_u[:-1])
    dur = t_u[e_idx] - t_u[s_idx]
    long = dur >= flat_us
    return v_u[s_idx[long]], dur[long]


def summarize(
    ts,
    value,
    quality,
    start: int,
    end: int,
    period: int,
    *,
    lo: float | None = None,
    hi: float | None = None,
    gap: int | None = None,
    flat: int | None = None,
    aligned: np.ndarray | None = None,
) -> dict:
    """Data-quality summary of one tag's raw samples over [start, end).

    - ``coverage``: fraction of grid points ``start + k·period`` holding a usable value,
      a sample counting for the grid point within half a period of it (jitter up to half a
      period does not empty a grid point; ``aligned``: the aligned column decides).
    - ``gaps`` / ``gap_s``: stretches without any sample longer than ``gap`` µs (default
      1.5 × the larger of the period and the tag's own period, its median sampling interval
      rounded as a model's period is), the window edges included, each sample taken at its
      own grid point (the nearest multiple of its own period): jitter is no gap, one missed
      sample is; ``stale``: the tag stopped reporting before the end (a trailing gap).
    - ``flat`` / ``flat_s``: runs of an unchanged good value lasting at least ``flat`` µs
      (default 30 min): a frozen transmitter or a stale value repeated by the gateway.
    - ``out_of_range``: good/uncertain values outside the tag's nominal range [lo, hi].
    """
    n_samples = len(ts)
    bad = int(np.count_nonzero(quality >= BAD))
    unc = int(np.count_nonzero(quality == UNCERTAIN))
    usable = (quality < BAD) & np.isfinite(value)
    dt_med = int(np.median(np.diff(ts))) if n_samples > 2 else period
    own = nice_period_us(dt_med, 0.05) if dt_med > 0 else period
    gap_us = int(gap) if gap is not None else int(1.5 * max(period, own))
    flat_us = int(flat) if flat is not None else 30 * 60 * US
    # gaps, edges included, between the samples' own grid points (jitter is no gap)
    on_grid = (ts + own // 2) // own * own
    edges = np.r_[start, on_grid, end] if n_samples else np.array([start, end])
    d = np.diff(edges)
    # a sample exactly at `start` means no leading gap; one period after the last sample is
    # still "on time"
    big = d > gap_us
    gaps = int(np.count_nonzero(big))
    gap_s = float(d[big].sum()) / US
    stale = bool(n_samples == 0 or (end - ts[-1]) > gap_us)
    # flat-lined stretches among usable values
    _, dur = flat_runs(ts[usable], value[usable], flat_us)
    flat_n, flat_s = len(dur), float(dur.sum()) / US
    oor = 0
    if lo is not None or hi is not None:
        v_u = value[usable]
        m = np.zeros(len(v_u), bool)
        if lo is not None and np.isfinite(lo):
            m |= v_u < lo
        if hi is not None and np.isfinite(hi):
            m |= v_u > hi
        oor = int(np.count_nonzero(m))
    if aligned is not None and len(aligned):
        coverage = float(np.count_nonzero(np.isfinite(aligned))) / len(aligned)
    else:
        n_bins = max(1, -(-(end - start) // period))
        b = (ts[usable] - start + period // 2) // period  # the nearest grid point
        filled = np.unique(b[(b >= 0) & (b < n_bins)])
        coverage = min(1.0, len(filled) / n_bins)
    return {
        "samples": n_samples,
        "good": int(n_samples - bad - unc),
        "uncertain": unc,
        "bad": bad,
        "coverage": coverage,
        "gaps": gaps,
        "gap_s": gap_s,
        "stale": stale,
        "flat": flat_n,
        "flat_s": flat_s,
        "out_of_range": oor,
        "first": from_us(ts[0]) if n_samples else pd.NaT,
        "last": from_us(ts[-1]) if n_samples else pd.NaT,
    }


def summary_frame(rows: dict[str, dict]) -> pd.DataFrame:
    frame = pd.DataFrame.from_dict(rows, orient="index", columns=SUMMARY_COLUMNS)
    frame.index.name = "tag"
    return frame


def _plain(v):
    if v is None or v is pd.NaT:
        return None
    if isinstance(v, np.generic):
        return v.item()
    return v


def summary_attrs(rows: dict[str, dict]) -> dict[str, dict]:
    """The summary as plain dicts (what ``frame.attrs["quality"]`` holds: safe for
    ``pd.concat`` and cheap for pandas to copy)."""
    return {tag: {k: _plain(row[k]) for k in SUMMARY_COLUMNS} for tag, row in rows.items()}


def quality_table(frame: pd.DataFrame) -> pd.DataFrame:
    """Per-tag data-quality summary of a window as a DataFrame (index ``tag``, columns
    :data:`SUMMARY_COLUMNS`)."""
    rows = frame.attrs.get("quality")
    if rows is None:
        raise ValueError("this frame carries no quality summary (not from Historian.window?)")
    table = summary_frame(rows)
    for col in ("first", "last"):
        table[col] = pd.to_datetime(table[col], utc=True)
    return table
