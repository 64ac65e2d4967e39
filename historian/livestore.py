"""What the live loop stores, each call short and idempotent: blocks of samples and events.

The live loop polls the same tags every cycle, so its samples come as *blocks*: a time
vector ``ts`` (µs UTC, one per cycle) and ``values``/``quality`` matrices (cycles × tags).
:meth:`LiveStore.write_block` stores one block in one transaction through the bulk path
(Arrow ingest on SQLite, binary COPY on PostgreSQL) — the tag ids come from one bulk
``INSERT … ON CONFLICT DO NOTHING`` the first time, not a transaction per tag. Re-sending a
block stores nothing twice (the samples' primary key is (tag, ts)); re-sending events skips
those already stored (same time, unit and message). A SQLite database locked by another
writer fails after ``busy_timeout`` seconds instead of a minute: the caller retries.

:meth:`LiveStore.unchanged_runs` reads each tag's recent history for the live loop's stale
detection: how long its value has stayed unchanged at most, and its sampling period.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from sqlalchemy import insert, select

from . import coldstore, schema
from .quality import GOOD
from .store import Historian


class LiveStore:
    """The historian at ``url`` as the live loop's writer uses it (see module doc).

    :meth:`open` connects (and creates the schema); every other method opens on demand, so a
    database that is away at start is simply retried."""

    def __init__(self, url: str, *, busy_timeout: float = 2.0) -> None:
        self.url = url
        self.busy_timeout = float(busy_timeout)
        self.historian: Historian | None = None
        self._ids: dict[str, int] = {}

    def open(self) -> Historian:
        if self.historian is None:
            self.historian = Historian(self.url, busy_timeout=self.busy_timeout)
        return self.historian

    def close(self) -> None:
        h, self.historian = self.historian, None
        if h is not None:
            h.close()

    def reset(self) -> None:
        """Drop the connections and the tag-id cache after a failure (a restarted server needs
        new connections; a rolled-back transaction may have taken the tags it created with it,
        so cached ids are only trusted again once read from a committed transaction)."""
        self._ids.clear()
        h = self.historian
        if h is not None:
            try:
                h.close()
            except Exception:  # noqa: BLE001 - it is broken already
                pass
            self.historian = None

    def tag_ids(self, names: Sequence[str]) -> np.ndarray:
        """Ids of ``names`` (int64, in order), creating missing tags in one transaction.

        The ids read inside the transaction are cached only once it has committed: a commit
        that fails (a full disk) rolls the new tags back, and samples filed under their ids
        would belong to no tag — or, after a restart, to another one."""
        h = self.open()
        missing = [n for n in dict.fromkeys(names) if n not in self._ids]
        if missing:
            t = schema.tags
            got: dict[str, int] = {}
            with h._writing() as c:
                c.execute(h._insert(t).on_conflict_do_nothing(), [{"name": n} for n in missing])
                for i in range(0, len(missing), 900):  # SQLite's bound-parameter limit
                    part = missing[i : i + 900]
                    rows = c.execute(select(t.c.name, t.c.id).where(t.c.name.in_(part))).all()
                    got.update((str(n), int(i_)) for n, i_ in rows)
            self._ids.update(got)  # committed
        return np.fromiter((self._ids[n] for n in names), np.int64, count=len(names))

    def write_block(
        self,
        tags: Sequence[str],
        ts: np.ndarray,
        values: np.ndarray,
        quality: np.ndarray,
    ) -> int:
        """Store a block (``ts``: µs, k cycles; ``values``/``quality``: k × len(tags)) in one
        transaction; returns the rows added (0 for a block stored before)."""
        h = self.open()
        ts = np.asarray(ts, np.int64)
        k, n = len(ts), len(tags)
        if k == 0 or n == 0:
            return 0
        ids = self.tag_ids(list(tags))
        tag_id = np.tile(ids, k)
        t = np.repeat(ts, n)
        v = np.asarray(values, np.float64).reshape(-1)
        q = np.asarray(quality, np.int64).reshape(-1)
        rolled = h._segments(None, None)
        if rolled and any(seg["ts_max"] >= int(ts.min()) for seg in rolled):
            new = h._not_in_cold(rolled, tag_id, t, v, q, "ignore")  # a month rolled already
            tag_id, t, v, q = tag_id[new], t[new], v[new], q[new]
        return int(h._bulk.insert(tag_id, t, v, q, policy="ignore")) if len(t) else 0

    def missing_tags(self) -> list[str]:
        """Names of the cached tags whose id is no longer that tag's row in ``tags`` (the
        check behind the writer's "none lost"); the cache is dropped when any is found."""
        if not self._ids:
            return []
        h = self.open()
        t = schema.tags
        have: dict[str, int] = {}
        names = list(self._ids)
        with h.engine.connect() as c:
            for i in range(0, len(names), 900):
                part = names[i : i + 900]
                rows = c.execute(select(t.c.name, t.c.id).where(t.c.name.in_(part))).all()
                have.update((str(n), int(i_)) for n, i_ in rows)
        bad = [n for n, i in self._ids.items() if have.get(n) != i]
        if bad:
            self._ids.clear()
        return bad

    def write_events(self, events: Iterable[dict[str, Any]]) -> int:
        """Store diagnostic events (dicts with ``ts`` µs, ``unit``, ``message`` and optionally
        ``status``, ``severity``, ``quality``, ``fault``, ``certainty``), skipping those
        already stored; returns how many were added."""
        rows = [dict(e) for e in events]
        if not rows:
            return 0
        h = self.open()
        t = schema.diag_events
        lo, hi = min(r["ts"] for r in rows), max(r["ts"] for r in rows)
        with h._writing() as c:
            have = {
                (int(ts), u, m)
                for ts, u, m in c.execute(
                    select(t.c.ts, t.c.unit, t.c.message).where(t.c.ts >= lo, t.c.ts <= hi)
                )
            }
            new = []
            for r in rows:
                key = (int(r["ts"]), r["unit"], r["message"])
                if key in have:
                    continue
                have.add(key)
                new.append(
                    {
                        "ts": int(r["ts"]),
                        "unit": r["unit"],
                        "message": r["message"],
                        "status": int(r.get("status", 0)),
                        "severity": r.get("severity"),
                        "quality": int(r.get("quality", GOOD)),
                        "fault": r.get("fault"),
                        "certainty": r.get("certainty"),
                    }
                )
            if new:
                c.execute(insert(t), new)
        return len(new)

    def unchanged_runs(self, tags: Sequence[str], last: int = 10_000) -> dict[str, dict[str, Any]]:
        """Per tag with history: over its ``last`` Good samples, the longest time its value
        stayed exactly unchanged (``longest_s``), the median sampling period (``period_s``),
        whether it ever changed (``changed``) and the count (``n``)."""
        h = self.open()
        s = schema.samples
        known = {}
        t = schema.tags
        with h.engine.connect() as c:
            for name, tid in c.execute(select(t.c.name, t.c.id)):
                known[str(name)] = int(tid)
            out: dict[str, dict[str, Any]] = {}
            for tag in tags:
                tid = known.get(tag)
                if tid is None:
                    continue
                rows = c.execute(
                    select(s.c.ts, s.c.value)
                    .where(s.c.tag_id == tid, s.c.quality == GOOD, s.c.value.is_not(None))
                    .order_by(s.c.ts.desc())
                    .limit(last)
                ).all()
                if len(rows) < 3:
                    continue
                ts = np.array([r[0] for r in rows[::-1]], np.int64)
                v = np.array([r[1] for r in rows[::-1]], np.float64)
                out[tag] = _runs(ts, v)
        return out


def _runs(ts: np.ndarray, v: np.ndarray) -> dict[str, Any]:
    """Longest unchanged run (s) and median period (s) of one tag's samples."""
    change = np.r_[True, v[1:] != v[:-1]]  # a run starts where the value changes
    starts = ts[change]
    ends = np.r_[ts[np.flatnonzero(change)[1:] - 1], ts[-1]]  # last sample of each run
    longest = float((ends - starts).max()) / 1e6
    return {
        "longest_s": longest,
        "period_s": float(np.median(np.diff(ts))) / 1e6,
        "changed": bool(change[1:].any()),
        "n": len(ts),
    }


@dataclass
class RollResult:
    """What :func:`roll_closed` did: each month rolled as ``(month, samples in its file,
    seconds)``; ``no_cold``: the database has no cold folder (PostgreSQL without a recorded
    one), nothing was tried; ``error``: why it stopped (the months before it are rolled);
    ``left``: closed months still in the table afterwards."""

    done: list[tuple[str, int, float]] = field(default_factory=list)
    no_cold: bool = False
    error: BaseException | None = None
    left: bool = False


def roll_closed(
    url: str, before, *, stop: Callable[[], bool] = lambda: False, busy_timeout: float = 30.0
) -> RollResult:
    """Roll every month closed at ``before`` to the cold store on a connection of its own
    (the live writer's roll thread), one month at a time, stopping between months when
    ``stop()`` says so. Never raises: a failure is returned in ``error``."""
    out = RollResult()
    h = None
    try:
        h = Historian(url, busy_timeout=busy_timeout)
        if h.cold_dir is None:
            out.no_cold = True
            return out
        for month in h.months_to_roll(before):
            if stop():
                break
            t0 = time.perf_counter()
            end = coldstore.month_bounds(month)[1]
            if month in h.roll_months(pd.Timestamp(end, unit="us", tz="UTC")):
                rows = next(int(s["rows"]) for s in h._segments(None, None) if s["month"] == month)
                out.done.append((month, rows, time.perf_counter() - t0))
        out.left = bool(h.months_to_roll(before))
    except Exception as exc:  # noqa: BLE001 - handed back to the writer, never raised
        out.error = exc
        out.left = True
    finally:
        if h is not None:
            try:
                h.close()
            except Exception:  # noqa: BLE001 - the result stands
                pass
    return out


def history_runs(url: str, tags: Sequence[str], last: int = 10_000) -> dict[str, dict[str, Any]]:
    """:meth:`LiveStore.unchanged_runs` on a connection of its own (a reader beside the live
    loop's writer: it never holds up a write)."""
    store = LiveStore(url)
    try:
        return store.unchanged_runs(tags, last)
    finally:
        store.close()
