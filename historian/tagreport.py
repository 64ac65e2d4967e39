"""Per-tag report of the historian: metadata, sampling interval and data quality (what
``diag tags`` shows; mixed into :class:`historian.store.Historian`)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from .sampling import nice_period_us, snap_near
from .times import period_us, to_us
from .window import summarize, summary_frame


class TagReport:
    """``tag_report``. Needs ``self.tags()``, ``self._tag(name)`` and
    ``self._read_raw(tag_id, start, end)``."""

    def tag_report(self, start=None, end=None, *, flat="30min") -> pd.DataFrame:
        """Per tag: metadata, sampling interval and the data-quality summary over its own
        time span (or [start, end)); what ``diag tags`` shows."""
        tags = self.tags()
        rows = {}
        for name, lo, hi in zip(tags["name"], tags["lo"], tags["hi"], strict=True):
            tag_id = self._tag(name)[0]
            s = to_us(start) if start is not None else np.iinfo(np.int64).min
            e = to_us(end) if end is not None else np.iinfo(np.int64).max
            ts, v, q = self._read_raw(tag_id, s, e)
            dt = int(np.median(np.diff(ts))) if len(ts) > 2 else 1_000_000
            # judged on the tag's own period (its median spacing, rounded as a model's
            # period is), each sample at its nearest grid point: jitter is no gap
            own = nice_period_us(dt, 0.05) if dt > 0 else 1_000_000
            s2 = snap_near(ts[0], own) if start is None and len(ts) else s
            e2 = snap_near(ts[-1], own) + own if end is None and len(ts) else e
            if not len(ts) and (start is None or end is None):
                s2, e2 = 0, 1
            row = summarize(ts, v, q, s2, e2, own, lo=_num(lo), hi=_num(hi), flat=period_us(flat))
            row["interval_s"] = dt / 1e6 if len(ts) > 2 else np.nan
            rows[name] = row
        report = summary_frame(rows).reset_index()
        report["interval_s"] = [rows[n]["interval_s"] for n in report["tag"]]
        meta = tags.rename(columns={"name": "tag"}).drop(columns=["id"])
        return meta.merge(report, on="tag", how="left")


def _num(x):
    return None if x is None or (isinstance(x, float) and np.isnan(x)) else float(x)
