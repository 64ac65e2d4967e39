"""Frozen values: a tag whose value (and source timestamp) has not changed for too long.

A PLC that stops updating keeps answering with its last values, all Good. :class:`StaleDetector`
marks a Good sample *stale* when the tag's value — and, where the source gives one (OPC UA),
its source timestamp — has stayed the same for longer than the tag's limit; the live loop then
stores and treats it as Uncertain, so the unit's tests that read it become unknown
(CHECK_FUNCTION), never a symptom.

The limit of a tag comes from its history unless ``stale_after`` fixes one for all tags
(:meth:`StaleDetector.fit`): ``factor`` × the longest time its value stayed unchanged in its
recent history, but at least ``min_periods`` sampling periods. A tag whose value never changed
in its history (a set point, a switch) is never stale: constancy is normal for it. A tag
without history is judged once it has been seen changing live, with the ``fallback`` limit.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from connectors.base import TagQuality


class StaleDetector:
    """Per-tag frozen-value detection, vectorised over the tag vector (module doc)."""

    def __init__(
        self,
        tags: Sequence[str],
        stale_after: float | None = None,
        *,
        factor: float = 3.0,
        min_periods: float = 10.0,
        fallback: float = 60.0,
    ) -> None:
        self.tags = list(tags)
        self.stale_after = stale_after
        self.factor = float(factor)
        self.min_periods = float(min_periods)
        self.fallback = float(fallback)
        n = len(self.tags)
        #: the limit per tag in seconds (inf: never stale; NaN: learned live, see module doc)
        self.limit_ = np.full(n, np.nan if stale_after is None else float(stale_after))
        self._last = np.full(n, np.nan)
        self._last_src = np.full(n, np.nan)
        self._last_good = np.zeros(n, bool)
        self._since = np.full(n, np.nan)
        self._seen_change = np.zeros(n, bool)

    def fit(self, runs: Mapping[str, Mapping[str, Any]]) -> StaleDetector:
        """Limits from each tag's history (``longest_s``, ``period_s``, ``changed`` as
        :meth:`historian.livestore.LiveStore.unchanged_runs` gives them). A fixed
        ``stale_after`` is kept."""
        if self.stale_after is not None:
            return self
        for i, tag in enumerate(self.tags):
            r = runs.get(tag)
            if r is None:
                continue
            if not r["changed"]:
                self.limit_[i] = np.inf
            else:
                self.limit_[i] = max(
                    self.factor * float(r["longest_s"]), self.min_periods * float(r["period_s"])
                )
        return self

    def update(
        self,
        t: float,
        values: np.ndarray,
        quality: np.ndarray,
        source_ts: np.ndarray | None = None,
        unread: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """One cycle at time ``t`` (seconds): the stale mask (Good samples frozen past their
        limit) and how long each tag has been unchanged (seconds, NaN when not Good).
        ``unread``: tags this cycle did not read (their source's poll late): they keep their
        clock, neither restarted nor judged (a Bad sample restarts it; a late poll on a
        loaded machine is no sign the value moved, and restarting there kept a frozen PLC
        from ever being judged stale: issue 34)."""
        good = (quality == TagQuality.GOOD) & np.isfinite(values)
        changed = values != self._last
        if source_ts is not None:  # NaN: the source gives none (Modbus)
            changed |= (source_ts != self._last_src) & ~np.isnan(source_ts)
        self._seen_change |= changed & good & self._last_good
        restart = changed | ~self._last_good | ~good  # a Bad stretch restarts the clock
        if unread is not None:
            restart &= ~unread
        self._since[restart] = t
        self._last = np.where(good, values, self._last)
        if source_ts is not None:
            self._last_src = np.where(good, source_ts, self._last_src)
        self._last_good = good if unread is None else np.where(unread, self._last_good, good)
        limit = np.where(
            np.isnan(self.limit_), np.where(self._seen_change, self.fallback, np.inf), self.limit_
        )
        age = np.where(good, t - self._since, np.nan)
        return good & (age > limit), age

    @property
    def judged(self) -> np.ndarray:
        """Tags that can be stale at all (a finite limit, or learned live after a change)."""
        return np.isfinite(self.limit_) | (np.isnan(self.limit_) & self._seen_change)
