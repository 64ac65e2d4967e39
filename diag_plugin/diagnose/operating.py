"""Where a unit's tests learned to answer, and which input left it (issue 34, item 5).

A test is *unknown* (the unit CHECK_FUNCTION) where its model has no rule: the plant is at an
operating point the unit never learned. :func:`learned_ranges` gives each test's inputs the range
its model learned — for a Wang–Mendel model the sets that carry a rule (Kościelny et al., eq. 5: a
rule exists only where training samples fell), from the lowest such set's centre minus half a step
to the highest's plus half a step; for a model without a rule grid (``linear``, ``narmax2``,
``track``) its nominal input span. :class:`OutsideLearned` names, per sample of CHECK_FUNCTION, the
input of an unknown test that is outside its range, its value, and when it left (carried from piece
to piece, as every stage's state is); of several such inputs, the one that left first (the plant
moved there first; the others followed). An input read with a lag (``FLOW[k-595]``) is judged by the
value the model reads, the one 595 samples back, and named so (``FLOW[k-595] = …``); the history it
needs is carried too. An unknown test whose tags have no value is named by every tag of the unit
without one and since when (:func:`gone_sentence`): one transmitter lost reads otherwise than the
whole feed gone.

Inside its range an input may have a gap the model does not bridge
(:meth:`~diag_plugin.fuzzy.wang_mendel.WangMendelRegressor.input_gaps`: empty fine sets between
values held for long, a set-point's few rates): its test is unknown there, and the input is named
as one outside, by a :class:`Range` with ``gap`` set — ``FEED_FLOW_SP = 12.7: in a gap of what the
unit learned (11.33 … 14) since T``, the learned values on either side and when it entered the gap
(:func:`model_gaps`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from diag_plugin.regressors import Columns, InputSpec


@dataclass(frozen=True)
class Range:
    """One input of one test and the range its model learned."""

    test: int  # index of the test in the unit's tests
    tag: str  # the model's tag name
    lo: float
    hi: float
    lag: int = 0  # samples back the model reads it
    #: a gap inside the range (:func:`model_gaps`): the input is off strictly between ``lo``
    #: and ``hi`` (not outside them), and ``near`` the learned values on either side
    gap: bool = False
    near: tuple[float, float] = (0.0, 0.0)
    #: the width of one of the input's fine sets for a rule grid (0 without one): a value
    #: within one step of ``lo`` or ``hi`` is at the edge of what was learned, where the outer
    #: set's rule carries too little of the firing weight (:meth:`OutsideLearned._in_a_gap`)
    step: float = 0.0

    @property
    def key(self) -> tuple[str, int]:
        """``(tag, lag)``: the value judged, as :meth:`OutsideLearned.columns` is given it."""
        return (self.tag, self.lag)


def model_ranges(model, specs: Sequence[str]) -> list[tuple[str, float, float]]:
    """``(tag, lo, hi)`` per plain input of ``model`` (derived inputs — ``dir()``,
    ``hour()`` — are left out): the extent of the sets that carry a rule, or the span."""
    out = []
    cells = None
    parts = getattr(model, "partitions_", None)
    if parts is not None and getattr(model, "keys_", np.empty(0)).size:
        cells = model.cell_indices()
    spans = getattr(model, "spans_", None)
    for j, spec in enumerate(specs):
        s = InputSpec.parse(spec)
        if s.fn != "":
            continue
        if cells is not None:
            p = parts[j]
            a, b = int(cells[:, j].min()), int(cells[:, j].max())
            lo, hi = p.lo + p.step * (a - 0.5), p.lo + p.step * (b + 0.5)
        elif spans is not None:
            lo, hi = float(spans[j][0]), float(spans[j][1])
        else:
            continue
        out.append((s.tags[0], float(lo), float(hi)))
    return out


def model_gaps(model, specs: Sequence[str]) -> list[tuple[int, str, float, float, float, float]]:
    """``(input, tag, lo, hi, a, b)`` per gap no level of ``model`` bridges in a plain input
    (:meth:`~diag_plugin.fuzzy.wang_mendel.WangMendelRegressor.unbridged_gaps`; none for a model
    without a rule grid): its values strictly between ``lo`` and ``hi`` own a fine set of the
    empty run, ``a`` and ``b`` the centres of the occupied sets on either side."""
    gaps = getattr(model, "unbridged_gaps", None)
    if gaps is None or not getattr(model, "keys_", np.empty(0)).size:
        return []
    out = []
    for j, (spec, g) in enumerate(zip(specs, gaps(), strict=False)):
        s = InputSpec.parse(spec)
        if s.fn != "" or not g.size:
            continue
        p = model.partitions_[j]
        for a, b in g.tolist():
            lo, hi = p.lo + p.step * (a + 0.5), p.lo + p.step * (b - 0.5)
            out.append((j, s.tags[0], lo, hi, p.lo + p.step * a, p.lo + p.step * b))
    return out


def model_steps(model, specs: Sequence[str]) -> list[float]:
    """Per plain input of ``model`` (as :func:`model_ranges`) the width of its fine sets for a
    rule grid, 0.0 for a model without one."""
    parts = getattr(model, "partitions_", None)
    grid = parts is not None and getattr(model, "keys_", np.empty(0)).size
    return [
        float(parts[j].step) if grid else 0.0
        for j, spec in enumerate(specs)
        if InputSpec.parse(spec).fn == ""
    ]


def learned_ranges(models: Mapping[str, object], tests: Sequence[str]) -> list[Range]:
    """Every test's plain inputs with their learned ranges (``models``: test name →
    :class:`~diag_plugin.diagnose.unit.TestModel`) and a rule grid's set width, and the gaps
    inside them its model does not bridge (:func:`model_gaps`)."""
    out = []
    for i, name in enumerate(tests):
        m = models[name]
        specs = [InputSpec.parse(s) for s in m.inputs]
        lags = [s.lag for s in specs if s.fn == ""]
        steps = model_steps(m.model, m.inputs)
        for (tag, lo, hi), lag, step in zip(
            model_ranges(m.model, m.inputs), lags, steps, strict=False
        ):
            out.append(Range(i, tag, lo, hi, lag, step=step))
        for j, tag, lo, hi, a, b in model_gaps(m.model, m.inputs):
            out.append(Range(i, tag, lo, hi, specs[j].lag, gap=True, near=(a, b)))
    return out


#: tags a sentence of tags without a value lists by name; beyond them, a count and these
SHORT = 3


def gone_sentence(names: Sequence[str], total: int, since: str) -> str:
    """Why a test is unknown when tags have no value: ``names`` the unit's tags without one,
    of ``total`` it reads, ``since`` when the first of them went. The whole feed gone reads
    ``no values from any of the 12 tags since T (source outage?)``; a few are named
    (``FW_FLOW, DRUM_P without a value since T``); more are counted, the first named
    (``7 of 12 tags without a value since T (FW_FLOW, DRUM_P, LVL, …)``)."""
    k = len(names)
    if k == total and total > 1:
        return f"no values from any of the {total} tags since {since} (source outage?)"
    if k <= SHORT:
        return f"{', '.join(names)} without a value since {since}"
    return f"{k} of {total} tags without a value since {since} ({', '.join(names[:SHORT])}, …)"


class OutsideLearned:
    """Names, per sample, the input outside what the unit learned (module doc)."""

    def __init__(
        self,
        ranges: Sequence[Range],
        names: Mapping[str, str] | None = None,
        tests: Sequence[Sequence[str]] = (),
        period_s: float = 0.0,
        first: Sequence[str] = (),
    ):
        self.ranges = list(ranges)
        #: model tags named before any other outside (hand valves: the operator moved them,
        #: the plant followed; :func:`~diag_plugin.diagnose.manual.manual_ranges`)
        self.first = frozenset(first)
        #: the sampling period (s): an input read ``L`` samples back left ``L`` periods
        #: before its model reads it (:meth:`_first_out`)
        self.period_s = float(period_s)
        self.names = dict(names or {})  # model tag → plant tag
        #: per test (by position) the model tags it reads, inputs and output
        self.test_tags = {i: frozenset(t) for i, t in enumerate(tests)}
        #: the unit's tags whose runs without a value are followed, and each one's start
        self.watch = list(dict.fromkeys(t for ts in tests for t in ts))
        self.gone: dict[str, pd.Timestamp] = {}
        self.since: dict[int, pd.Timestamp | None] = {}
        self.depth: dict[str, int] = {}  # per tag the longest lag judged
        for r in self.ranges:
            self.depth[r.tag] = max(self.depth.get(r.tag, 0), r.lag)
        #: per tag the lags its ranges read
        self._lags = {t: sorted({r.lag for r in self.ranges if r.tag == t}) for t in self.depth}
        self.tails: dict[str, np.ndarray] = {}
        # the watched tags idle() reads besides the ranges read at lag 0
        plain = {r.tag for r in self.ranges if r.lag == 0}
        self._watch_extra = [self.names.get(t, t) for t in self.watch if t not in plain]

    def reset(self) -> OutsideLearned:
        self.since = {}
        self.gone = {}
        self.tails = {t: np.full(d, np.nan) for t, d in self.depth.items()}
        return self

    def to_state(self) -> dict[str, Any]:
        """The carried state as JSON: each input's excursion start and each tag's last
        values for its lags (a restart judges ``TAG[k-L]`` at once, not after L samples)."""
        return {
            "since": {
                str(k): None if t is None else pd.Timestamp(t).isoformat()
                for k, t in self.since.items()
            },
            "tails": {
                t: [None if np.isnan(v) else float(v) for v in x] for t, x in self.tails.items()
            },
            "gone": {t: pd.Timestamp(v).isoformat() for t, v in self.gone.items()},
        }

    def load_state(self, state: Mapping[str, Any]) -> OutsideLearned:
        """Back from :meth:`to_state` (a tail saved for another depth starts empty)."""
        self.since = {
            int(k): None if t is None else pd.Timestamp(t)
            for k, t in state.get("since", {}).items()
        }
        for t, x in state.get("tails", {}).items():
            v = np.array([np.nan if a is None else a for a in x], float)
            if t in self.depth and v.size == self.depth[t]:
                self.tails[t] = v
        self.gone = {t: pd.Timestamp(v) for t, v in state.get("gone", {}).items()}
        return self

    def idle(self, value: Callable[[str, int], float]) -> bool:
        """True when :meth:`transform` of one row that is not reported would say nothing and
        change nothing: no input outside its range now (``value(plant tag, lag)``: the value
        ``lag`` samples back) nor before, and every watched tag with a value now and before.
        The live loop's shortcut: most cycles, for most units."""
        if self.gone or any(v is not None for v in self.since.values()):
            return False
        for r in self.ranges:
            x = value(self.names.get(r.tag, r.tag), r.lag)
            if (r.lo < x < r.hi) if r.gap else (x < r.lo or x > r.hi):  # NaN: not outside
                return False
            if x != x and r.lag == 0 and r.tag in self.test_tags.get(r.test, ()):
                return False  # a watched tag without a value: its start is followed
        return all(value(p, 0) == value(p, 0) for p in self._watch_extra)

    def sentence(self, r: Range, x: float, since) -> str:
        """``TAG = value outside what the unit learned (lo … hi) since T``."""
        head, tail = self._parts(r)
        return f"{head}{x:.4g}{tail}{pd.Timestamp(since).isoformat()}"

    def label(self, tag: str, lag: int) -> str:
        """The plant's tag, with the lag the model reads it at (``FT1[k-595]``) if any."""
        return self.names.get(tag, tag) + (f"[k-{lag}]" if lag else "")

    def _parts(self, r: Range) -> tuple[str, str]:
        """:meth:`sentence` before and after the value, up to the time (a gap's: ``TAG =
        value: in a gap of what the unit learned (a … b) since``)."""
        if r.gap:
            a, b = r.near
            return (
                f"{self.label(r.tag, r.lag)} = ",
                f": in a gap of what the unit learned ({a:.4g} … {b:.4g}) since ",
            )
        return (
            f"{self.label(r.tag, r.lag)} = ",
            f" outside what the unit learned ({r.lo:.4g} … {r.hi:.4g}) since ",
        )

    def transform(
        self, frame: pd.DataFrame | Columns, unknown: np.ndarray, report: np.ndarray
    ) -> np.ndarray:
        """Per row a sentence (``""`` elsewhere) for the rows in ``report`` (CHECK_FUNCTION): the
        input of an unknown test (``unknown``: rows × tests) outside its learned range that left it
        first (:meth:`_first_out`), ``TAG = value outside what the unit learned (lo … hi) since T``.
        Advances the carried start of every input's excursion. ``frame``: the piece under the
        models' tag names, or its :class:`~diag_plugin.regressors.Columns` (read once for the
        unit)."""
        read = dict.fromkeys([*self.tags, *self.watch])
        if isinstance(frame, Columns):
            cols = {t: frame.values(t) for t in read if t in frame.columns}
        else:
            have = set(frame.columns)
            cols = {t: frame[t].to_numpy(float) for t in read if t in have}
        return self.columns(self.lagged(cols), frame.index, unknown, report)

    def lagged(self, cols: Mapping[str, np.ndarray]) -> LaggedColumns:
        """Per range's :attr:`Range.key` the value its model reads at each row of ``cols``
        (model tag → this piece's values), from the history carried before the piece (NaN
        before any), made when first asked (:class:`LaggedColumns`); advances that history."""
        keys = []
        tails = {}
        for t, x in cols.items():
            d = self.depth.get(t, 0)
            if d == 0:  # read unlagged only: the piece itself, no history to carry
                keys.append((t, 0))
                continue
            tail = self.tails.get(t, np.full(d, np.nan))
            tails[t] = tail
            keys.extend((t, lag) for lag in self._lags[t])
            if 0 not in self._lags[t] and t in self.watch:  # its own gaps are followed
                keys.append((t, 0))
            n = len(x)
            # the last d values of the tail and the piece joined (a copy: not a view of the
            # caller's frame)
            self.tails[t] = x[n - d :].copy() if n >= d else np.concatenate([tail, x])[n:]
        return LaggedColumns(cols, tails, keys)

    @property
    def tags(self) -> list[str]:
        """The model tags whose ranges are judged."""
        return list(dict.fromkeys(r.tag for r in self.ranges))

    def columns(
        self,
        cols: Mapping[str, np.ndarray],
        idx: Sequence[pd.Timestamp] | pd.Index,
        unknown: np.ndarray,
        report: np.ndarray,
    ) -> np.ndarray:
        """:meth:`transform` of the rows ``idx`` given as arrays (:attr:`Range.key`, model
        tag and lag → the values the model reads at those rows; a key absent is not judged):
        the live loop's one row a cycle without a frame."""
        n = len(idx)
        out = np.full(n, "", dtype=object)
        at = np.flatnonzero(report)  # the rows to name (CHECK_FUNCTION: few, in most pieces)
        unk = unknown[at]
        gaps = self._gaps(cols, idx, at)
        judged, keys, col, lo, hi, test, gap = self._judged(cols)
        if not n or not judged:
            self._combination(cols, unk, at, np.ones(at.size, bool), out, gaps)
            return out
        # every judged range at once, at the rows to name and at the piece's end: a row is
        # named by the range outside there whose test is unknown and whose input left first
        # (:meth:`_first_out`)
        end = np.array([_last(cols, key) for key in keys], float)[col]
        with np.errstate(invalid="ignore"):  # NaN: not outside
            end_off = _off(end, lo, hi, gap)
            xa = np.empty((at.size, len(keys)))
            for c, key in enumerate(keys):
                xa[:, c] = _at(cols, key, at)
            xa = xa[:, col]
            cand = _off(xa, lo, hi, gap) & unk[:, test]
        named = cand.any(axis=1)
        by = self._first_out(cols, idx, at, cand, judged)
        hits = {int(p): at[named & (by == p)] for p in np.unique(by[named])}
        for p, k in enumerate(judged):
            r = self.ranges[k]
            hit = hits.get(p)
            if hit is None and not end_off[p]:
                self.since[k] = None
                continue
            carried = self.since.get(k)
            off = _outside(cols, r.key, r.lo, r.hi, r.gap)
            # the row each excursion started at (carried over the piece's start): for an
            # outside row, the last start at or before it
            starts = np.flatnonzero(off & ~np.r_[False, off[:-1]])
            if hit is not None:
                first = starts[np.searchsorted(starts, hit, side="right") - 1]
                head, tail = self._parts(r)
                # each excursion's start written once (the index read once for all of them)
                sts, inv = np.unique(first, return_inverse=True)
                when = [pd.Timestamp(t).isoformat() for t in _take(idx, sts)]
                if carried is not None and sts[0] == 0 and off[0]:
                    when[0] = pd.Timestamp(carried).isoformat()  # began in an earlier piece
                out[hit] = np.array(
                    [f"{head}{v:.4g}{tail}{when[w]}"
                     for v, w in zip(_at(cols, r.key, hit).tolist(), inv.reshape(-1).tolist(),
                                     strict=True)],
                    dtype=object,
                )  # fmt: skip
            if end_off[p]:
                last = starts[-1]  # the excursion the piece ends in
                self.since[k] = carried if (off.all() and carried is not None) else idx[last]
            else:
                self.since[k] = None
        self._combination(cols, unk, at[~named], ~named, out, gaps)
        return out

    def _first_out(
        self,
        cols: Mapping,
        idx: Sequence[pd.Timestamp] | pd.Index,
        at: np.ndarray,
        cand: np.ndarray,
        judged: Sequence[int],
    ) -> np.ndarray:
        """Per row to name (``at``; ``cand``: rows × judged ranges outside whose test is
        unknown) the range whose input left what it learned first: the plant moved there
        first, the others followed (a feed cut below any throughput learned, then the steam
        the operators set after it, then the condenser's valve). An input read ``L``
        samples back left ``L`` periods before its excursion's start as read; an excursion
        begun in an earlier piece left when carried; a hand valve's (:attr:`first`) before any.
        Ties, and rows with one range outside, go to the first range in order."""
        by = np.argmax(cand, axis=1)
        multi = cand.sum(axis=1) > 1
        if not multi.any():
            return by
        times = pd.DatetimeIndex(idx).as_unit("ns").asi8
        left = np.full(cand.shape, np.inf)
        for p in np.flatnonzero(cand[multi].any(axis=0)):
            k = judged[p]
            r = self.ranges[k]
            rows = np.flatnonzero(cand[:, p] & multi)
            off = _outside(cols, r.key, r.lo, r.hi, r.gap)
            starts = np.flatnonzero(off & ~np.r_[False, off[:-1]])
            first = starts[np.searchsorted(starts, at[rows], side="right") - 1]
            t = times[first].astype(float)
            carried = self.since.get(k)
            if carried is not None and off[0]:
                t[first == 0] = float(pd.Timestamp(carried).value)
            left[rows, p] = -np.inf if r.tag in self.first else t - r.lag * self.period_s * 1e9
        return np.where(multi, np.argmin(left, axis=1), by)

    def _gaps(self, cols: Mapping, idx: Sequence[pd.Timestamp] | pd.Index, at: np.ndarray) -> tuple:
        """At the rows ``at``, the watched tags read (model tags), which have no value
        (rows × tags) and since when (UTC ns, rows × tags), and the index's time zone;
        advances :attr:`gone` (each tag's start of the run without a value it ends in)."""
        watch = [t for t in self.watch if (t, 0) in cols]
        miss = np.zeros((at.size, len(watch)), bool)
        when = np.zeros((at.size, len(watch)), np.int64)
        if not len(idx):
            return watch, miss, when, None
        times = pd.DatetimeIndex(idx)
        ns = None  # the index as UTC ns, made when a tag has a gap
        for c, t in enumerate(watch):
            carried = self.gone.pop(t, None)
            if not at.size and _last(cols, (t, 0)) == _last(cols, (t, 0)):
                continue  # nothing to name, and a value at the end
            nan = np.isnan(np.asarray(cols[(t, 0)], float))
            if not nan.any():
                continue
            if ns is None:
                ns = times.as_unit("ns").asi8
            good = np.flatnonzero(~nan)
            # each row's run without a value starts after the last value before it
            first = np.r_[-1, good][np.searchsorted(good, at)] + 1
            miss[:, c] = nan[at]
            when[:, c] = ns[first]
            if carried is not None:  # a run begun in an earlier piece
                when[first == 0, c] = carried.value
            if nan[-1]:
                s0 = good[-1] + 1 if good.size else 0
                self.gone[t] = carried if s0 == 0 and carried is not None else times[s0]
        return watch, miss, when, times.tz

    def _gone_at(self, gaps: tuple, miss: np.ndarray, when: np.ndarray) -> np.ndarray:
        """:func:`gone_sentence` per row of ``miss`` (rows × the watched tags of ``gaps``:
        without a value) and ``when`` (each one's start, UTC ns): one per pattern and start."""
        watch, _, _, tz = gaps
        names = [self.label(t, 0) for t in watch]
        since = np.where(miss, when, np.iinfo(np.int64).max).min(axis=1)
        pats, inv = np.unique(np.c_[miss, since], axis=0, return_inverse=True)
        said = [
            gone_sentence(
                [nm for nm, m in zip(names, p[:-1], strict=True) if m],
                len(names),
                pd.Timestamp(int(p[-1]), tz=tz).isoformat(),
            )
            for p in pats
        ]
        return np.array(said, dtype=object)[inv.reshape(-1)]

    def _judged(self, cols: Mapping[tuple[str, int], np.ndarray]) -> tuple:
        """The ranges judged on a piece with the values ``cols`` (:attr:`Range.key` →
        values): their positions in :attr:`ranges`, the keys they read (once each), each
        one's key among those, its bounds, its test and whether it is a gap — the same for
        every piece that has the same keys, so made once for them."""
        have = frozenset(cols)
        cache = self.__dict__.setdefault("_judged_cache", {})
        if have not in cache:
            judged = [k for k, r in enumerate(self.ranges) if r.key in have]
            keys = list(dict.fromkeys(self.ranges[k].key for k in judged))
            at = {key: c for c, key in enumerate(keys)}
            cache[have] = (
                judged,
                keys,
                np.array([at[self.ranges[k].key] for k in judged], np.int64),
                np.array([self.ranges[k].lo for k in judged], float),
                np.array([self.ranges[k].hi for k in judged], float),
                np.array([self.ranges[k].test for k in judged], np.int64),
                np.array([self.ranges[k].gap for k in judged], bool),
            )
        return cache[have]

    def _tests_keys(self) -> dict[int, list[tuple[str, int]]]:
        """Per test (by position) the :attr:`Range.key` of each of its ranges, in order."""
        if "_tests" not in self.__dict__:
            tests: dict[int, list[tuple[str, int]]] = {}
            for r in self.ranges:
                tests.setdefault(r.test, []).append(r.key)
            self._tests = tests
        return self._tests

    def _in_a_gap(self, test: int, key: tuple[str, int], name: str, x: np.ndarray) -> np.ndarray:
        """The sentence of a test of one input that has no rule at the input's value though
        the value is inside its learned range (a gap between the values the window held:
        acceptance pass 10, a pasteuriser's new production rate between the runs' and the
        cleaning's flows): ``TAG = value: in a gap of what the unit learned (lo … hi)``; within
        one of a rule grid's set widths of ``lo`` or ``hi`` (:attr:`Range.step`), where the
        outer set's rule carries too little of the firing weight, ``TAG = value: at the edge of
        what the unit learned (lo … hi)`` (acceptance pass 11, an aeration basin's air valve at
        58.1 % against a day's 18.33 … 58.33: no gap there)."""
        r = next(r for r in self.ranges if r.test == test and r.key == key and not r.gap)
        span = f"({r.lo:.4g} … {r.hi:.4g})"
        edge = (x - r.lo <= r.step) | (r.hi - x <= r.step) if r.step > 0 else np.zeros(x.size, bool)
        return np.array(
            [f"{name} = {v:.4g}: " + ("at the edge of" if e else "in a gap of")
             + f" what the unit learned {span}"
             for v, e in zip(x.tolist(), edge.tolist(), strict=True)],
            dtype=object,
        )  # fmt: skip

    def _combination(self, cols, unk, rows_left, left, out, gaps) -> None:
        """The rows still unnamed (``rows_left``; ``unk``: the unknown tests at the rows to
        name, ``left`` of them those still unnamed; ``cols``: :attr:`Range.key` → values the
        model reads; ``gaps``: :meth:`_gaps` at the rows to name): each input of the first
        unknown test is inside what it learned, but not together (a grid cell without a
        rule; a test of one input: its value in a gap, :meth:`_in_a_gap`), or a tag it reads
        has no value (then every tag of the unit without one is
        named, :func:`gone_sentence`)."""
        tests = self._tests_keys()
        unk = unk[left]
        watch, miss, when = gaps[0], gaps[1][left], gaps[2][left]
        todo = np.ones(rows_left.size, bool)
        if miss.any():  # an unknown test reading a tag without a value now: named first
            lost = np.zeros(rows_left.size, bool)
            for j, own in self.test_tags.items():
                cs = [c for c, t in enumerate(watch) if t in own]
                lost |= unk[:, j] & miss[:, cs].any(axis=1)
            if lost.any():
                out[rows_left[lost]] = self._gone_at(gaps, miss[lost], when[lost])
                todo &= ~lost
        for j, tags in tests.items():
            if not todo.any():
                break
            mine = todo & unk[:, j]
            rows = rows_left[mine]
            if not rows.size:
                continue
            have = [t for t in tags if t in cols]
            # column by column (a frame of the columns, per test and piece, cost more)
            vals = np.empty((rows.size, len(have)))
            for c, t in enumerate(have):
                vals[:, c] = _at(cols, t, rows)
            names = [self.label(*t) for t in have]
            ok = np.isfinite(vals)
            full = ok.all(axis=1)
            # rows where an input read with a lag has no value and some of the unit's tags
            # have none now: named by all of the unit's without one
            m, w = miss[mine], when[mine]
            lost = m.any(axis=1) & ~full
            if lost.any():
                out[rows[lost]] = self._gone_at(gaps, m[lost], w[lost])
            full &= ~lost
            # rows with an input missing: one sentence per pattern of missing inputs
            holes = np.flatnonzero(~full & ~lost)
            if holes.size:
                pats, inv = np.unique(~ok[holes], axis=0, return_inverse=True)
                said = [", ".join(nm for nm, m in zip(names, p, strict=True) if m)
                        + " without a value" for p in pats]  # fmt: skip
                out[rows[holes]] = np.array(said, dtype=object)[inv.reshape(-1)]
            if full.any() and len(names) == 1:  # one input: no "together" to speak of
                out[rows[full]] = self._in_a_gap(j, have[0], names[0], vals[full, 0])
            elif full.any() and names:  # written input by input, then joined per row
                each = [[f"{nm} = {x:.4g}" for x in vals[full, c].tolist()]
                        for c, nm in enumerate(names)]  # fmt: skip
                out[rows[full]] = np.array(
                    [", ".join(parts) + ": each within what the unit learned, but not together"
                     for parts in zip(*each, strict=True)],
                    dtype=object,
                )  # fmt: skip
            elif full.any():
                out[rows[full]] = ": each within what the unit learned, but not together"
            todo[mine] = False


def _take(idx: Sequence[pd.Timestamp] | pd.Index, at: np.ndarray) -> Sequence:
    """The timestamps of ``idx`` at positions ``at`` (one take from an index, not one
    lookup per position)."""
    if isinstance(idx, pd.Index):
        return idx.take(at)
    return [idx[i] for i in at.tolist()]


class LaggedColumns(Mapping):
    """Per :attr:`Range.key` (model tag, lag) the values a piece's rows read, each column
    made when first asked: the carried tail (the ``d`` values before the piece, ``d`` the
    tag's longest lag) and the piece joined, shifted by the lag. :meth:`last` and :meth:`at`
    read single rows without making it: a replay names few rows of most pieces, so most
    columns are never made (issue 34: one new array per lagged tag and piece was a first
    pass's 0.09 s of new memory at 200,000 rows)."""

    def __init__(
        self,
        cols: Mapping[str, np.ndarray],
        tails: Mapping[str, np.ndarray],
        keys: Sequence[tuple[str, int]],
    ) -> None:
        self._cols, self._tails = cols, tails
        self._keys = list(keys)
        self._have = frozenset(self._keys)
        self._made: dict[tuple[str, int], np.ndarray] = {}

    def __iter__(self):
        return iter(self._keys)

    def __len__(self) -> int:
        return len(self._keys)

    def __contains__(self, key: object) -> bool:
        return key in self._have

    def __getitem__(self, key: tuple[str, int]) -> np.ndarray:
        if key not in self._have:
            raise KeyError(key)
        if key not in self._made:
            t, lag = key
            x = self._cols[t]
            tail = self._tails.get(t)
            if tail is None or lag == 0:
                self._made[key] = x
            else:
                d, n = tail.size, len(x)
                self._made[key] = np.concatenate([tail, x])[d - lag : d - lag + n]
        return self._made[key]

    def last(self, key: tuple[str, int]) -> float:
        """The value at the piece's last row."""
        if key not in self._have:
            raise KeyError(key)
        t, lag = key
        x = self._cols[t]
        tail = self._tails.get(t)
        i = len(x) - 1 - (0 if tail is None else lag)
        return float(x[i]) if i >= 0 else float(tail[tail.size + i])

    def outside(self, key: tuple[str, int], lo: float, hi: float, gap: bool = False) -> np.ndarray:
        """Per row whether the value is below ``lo`` or above ``hi`` (``gap``: strictly
        between them; NaN: not), judged on the tail and the piece apart and joined as
        booleans (no column of floats made)."""
        t, lag = key
        x = np.asarray(self._cols[t], float)
        tail = self._tails.get(t)
        off = _off(x, lo, hi, gap)
        if tail is None or lag == 0:
            return off
        d = tail.size
        before = _off(tail, lo, hi, gap)
        return np.concatenate([before, off])[d - lag : d - lag + x.size]

    def at(self, key: tuple[str, int], rows: np.ndarray) -> np.ndarray:
        """The values at ``rows`` (positions in the piece) as floats."""
        if key not in self._have:
            raise KeyError(key)
        t, lag = key
        x = np.asarray(self._cols[t], float)
        tail = self._tails.get(t)
        if tail is None or lag == 0:
            return x[rows]
        back = np.asarray(rows, np.int64) - lag  # the row read: before the piece if < 0
        if not back.size or back.min() >= 0:
            return x[back]
        out = np.empty(back.size)
        inside = back >= 0
        out[inside] = x[back[inside]]
        out[~inside] = tail[tail.size + back[~inside]]
        return out


def _last(cols: Mapping, key) -> float:
    """The value of ``cols[key]`` at the last row (:meth:`LaggedColumns.last`)."""
    return cols.last(key) if isinstance(cols, LaggedColumns) else cols[key][-1]


def _outside(cols: Mapping, key, lo: float, hi: float, gap: bool = False) -> np.ndarray:
    """Per row whether ``cols[key]`` is outside ``[lo, hi]`` (``gap``: strictly inside
    ``(lo, hi)``; :meth:`LaggedColumns.outside`; NaN: not outside)."""
    if isinstance(cols, LaggedColumns):
        return cols.outside(key, lo, hi, gap)
    return _off(np.asarray(cols[key], float), lo, hi, gap)


def _off(x, lo, hi, gap):
    """Whether ``x`` is off what was learned: below ``lo`` or above ``hi``, or, where
    ``gap``, strictly between them (a gap inside the range; scalars or arrays, broadcast;
    NaN: not off)."""
    with np.errstate(invalid="ignore"):
        return np.where(gap, (x > lo) & (x < hi), (x < lo) | (x > hi))


def _at(cols: Mapping, key, rows: np.ndarray) -> np.ndarray:
    """The values of ``cols[key]`` at ``rows`` as floats (:meth:`LaggedColumns.at`)."""
    if isinstance(cols, LaggedColumns):
        return cols.at(key, rows)
    return np.asarray(cols[key], float)[rows]
