"""The shapes ``Historian.write_samples`` accepts, as per-tag numpy arrays.

- wide frame: DatetimeIndex (or a ``ts`` column), one column per tag; NaN cells are "no sample";
- long frame: columns ``tag``, ``ts``, ``value`` and optionally ``quality``;
- Series named by its tag, with a DatetimeIndex.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .times import index_us


def sorted_unique(ts, value, q):
    """Sort by time and keep the first of equal times (what the database would keep)."""
    if len(ts) > 1 and not np.all(ts[1:] > ts[:-1]):
        order = np.argsort(ts, kind="stable")
        ts, value, q = ts[order], value[order], q[order]
        first = np.r_[True, ts[1:] != ts[:-1]]
        ts, value, q = ts[first], value[first], q[first]
    return ts, value, q


def tag_arrays(data, quality):
    """Yield (tag, ts µs, value float64, quality int64) per tag from any accepted shape."""
    if isinstance(data, pd.Series):
        if data.name is None:
            raise ValueError("a Series needs its tag as name")
        ts = index_us(data.index)
        value = pd.to_numeric(data, errors="raise").to_numpy(np.float64, na_value=np.nan)
        q = quality_array(quality, len(ts), data.name)
        yield data.name, ts, value, q
        return
    if not isinstance(data, pd.DataFrame):
        raise TypeError("write_samples takes a DataFrame or a Series")
    cols = set(data.columns)
    if {"tag", "ts", "value"} <= cols:  # long
        ts_all = index_us(data["ts"])
        tag_codes, names = pd.factorize(data["tag"])
        value_all = pd.to_numeric(data["value"]).to_numpy(np.float64, na_value=np.nan)
        if "quality" in cols:
            q_all = data["quality"].to_numpy(np.int64)
        else:
            q_all = np.full(len(data), int(quality), np.int64)
        order = np.argsort(tag_codes, kind="stable")
        bounds = np.searchsorted(tag_codes[order], np.arange(len(names) + 1))
        for i, name in enumerate(names):
            sel = order[bounds[i] : bounds[i + 1]]
            yield name, ts_all[sel], value_all[sel], q_all[sel]
        return
    # wide
    if isinstance(data.index, pd.DatetimeIndex):
        ts = index_us(data.index)
        body = data
    elif "ts" in cols:
        ts = index_us(data["ts"])
        body = data.drop(columns=["ts"])
    else:
        raise ValueError("a wide frame needs a DatetimeIndex or a 'ts' column")
    for name in body.columns:
        value = pd.to_numeric(body[name]).to_numpy(np.float64, na_value=np.nan)
        if isinstance(quality, pd.DataFrame):
            q = quality[name].to_numpy(np.int64)
        else:
            q = np.full(len(value), int(quality), np.int64)
        present = ~np.isnan(value)
        if present.all():
            yield name, ts, value, q
        else:
            yield name, ts[present], value[present], q[present]


def quality_array(quality, n, name):
    if isinstance(quality, pd.Series):
        return quality.to_numpy(np.int64)
    if isinstance(quality, pd.DataFrame):
        return quality[name].to_numpy(np.int64)
    return np.full(n, int(quality), np.int64)
