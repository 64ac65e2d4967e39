"""A plant unit at run time: residuals → symptoms → isolated faults → NE 107 status.

:class:`Unit` evaluates one unit file (see :mod:`diag_plugin.diagnose.unitfile`) over
consecutive pieces of aligned data (a historian window, or one row per live cycle). Every stage
carries its state from piece to piece — each model's design builder (lags, derived inputs),
the Butterworth filter, the on/off delays and latches — so a replay in chunks, a live loop and
one pass over the data give the same diagnosis.

Stages (all vectorised over samples and tests):

1. residual per test in % of the output's nominal span (Kościelny et al., eq. 6), or of the
   signal maximum (Laukonen et al., Sec. IV); NaN (*unknown*) where the model has no rule, an
   input is missing, stale or of bad quality; an answer of a coarser rule level behind a
   Wang–Mendel model's fine grid is divided by that level's learned residual scale
   (:func:`level_factor`), and for a test with ``spread = true`` by the local spread of the
   training outputs (:func:`spread_factor`);
2. optional causal 4th-order Butterworth low-pass (Laukonen et al., Sec. IV);
3. symptoms by crisp thresholds (Laukonen et al., Table III; Kościelny et al., Sec. 5) or by
   three-valued fuzzy evaluation (N, 0, P), then on/off delays and optional latching;
4. with a matrix: a certainty per fault — nearest signature (crisp) or rules (10)–(14) of
   Kościelny et al. (fuzzy) — and the isolated faults, never moved to other faults on fading
   symptoms alone (:mod:`diag_plugin.diagnose.isolation`);
5. NE 107 status: NORMAL without symptoms, the fault's status (FAILURE by default) when a fault
   is isolated, OFF_SPEC for symptoms no signature explains (or a unit without a matrix), and
   CHECK_FUNCTION when the diagnosis is unknown. An unknown test is never a symptom and never a
   fault.

With ``combined = true`` a unit-level test (Hotelling's T² of the scaled residuals) runs beside
the tests, and with ``isolation = "tags"`` the matrix is derived from the models and every alarm
names the tags that explain it, ranked by contribution (:mod:`diag_plugin.diagnose.unittags`).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import logging
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numba
import numpy as np
import pandas as pd

from diag_plugin.diagnose.combos import CombosGuard
from diag_plugin.diagnose.envelope import scaled
from diag_plugin.diagnose.equipment import (
    DONE,
    SETTLING,
    UNKNOWN_AGE,
    PieceReplay,
    PieceState,
    members,
    off_mask,
    output_tag,
    piece_ages,
    piece_envelopes,
    settling,
)
from diag_plugin.diagnose.fixed import FixedGuard
from diag_plugin.diagnose.fixed import apply as apply_fixed
from diag_plugin.diagnose.isolation import IsolationHold
from diag_plugin.diagnose.manual import (
    ManualGuard,
    chosen_ranges,
    chosen_tests,
    manual_ranges,
    own_ranges,
    own_spans,
)
from diag_plugin.diagnose.matrix import DiagnosticMatrix, MatrixError, load_matrix
from diag_plugin.diagnose.operating import OutsideLearned, learned_ranges
from diag_plugin.diagnose.pertest import each
from diag_plugin.diagnose.residuals import LowPass, supported
from diag_plugin.diagnose.running import segments
from diag_plugin.diagnose.saturation import Saturation, actuator_span
from diag_plugin.diagnose.settle import SettleGuard, prepend, settle_guard
from diag_plugin.diagnose.settle import apply as apply_settle
from diag_plugin.diagnose.symptoms import FixedThresholds, OnOffDelay, three_valued
from diag_plugin.diagnose.unitfile import SPREAD_FLOOR, TestSpec, UnitError, UnitFile, unit_path
from diag_plugin.diagnose.unitloops import (
    AlarmHold,
    Deadband,
    EpisodeHold,
    OscillationHold,
    ReleaseHold,
    RunningSpread,
    oscillation_samples,
    resolved_evaluation,
    spread_samples,
    warm_labels,
    warm_up,
    warming_up,
)
from diag_plugin.diagnose.unittags import (
    CombinedModel,
    Excursions,
    TestNames,
    Untested,
    derived_matrix,
    describe_top,
    top_columns_at,
    unbridge,
    with_ranked,
)
from diag_plugin.metrics import residual_pct
from diag_plugin.models.protocol import Prediction
from diag_plugin.regressors import Columns, DesignBuilder, max_lag, needed_tags, parse_specs
from diag_plugin.status import NE107, Quality, UnitStatus

log = logging.getLogger(__name__)

#: NE 107 priority when several apply (NAMUR: failure, function check, off-spec, maintenance)
PRIORITY = (NE107.FAILURE, NE107.CHECK_FUNCTION, NE107.OFF_SPEC, NE107.MAINTENANCE_REQUIRED)


@dataclass
class TestModel:
    """A test's model with what it needs to turn data into residuals."""

    name: str
    path: Path
    model: Any
    inputs: list[str]
    output: str
    span: float
    period: str
    #: the output variable's span (its metadata range, else the build window's): a loop's
    #: actuator at an edge of it is at its limit (:mod:`~.saturation`)
    out_range: tuple[float, float] | None = None

    def builder(self) -> DesignBuilder:
        return DesignBuilder(self.inputs, self.output, period=self.period)

    @property
    def tags(self) -> list[str]:
        return list(_needed_tags(tuple(self.inputs), self.output))


def _idle_rows(file: UnitFile, models: dict[str, TestModel]) -> list[str]:
    """``file:line`` of each ``[narrow]`` row naming a tag no test of the unit tests, of each
    ``[chosen]`` row that guards no test, and of each ``[manual]`` row naming a tag the unit
    neither reads nor lists in ``[build.skipped]``: a hand edit's typo, a row that would
    silently do nothing."""
    names = [t.name for t in file.tests]
    own = {s.tag for s in own_spans(models, names, file.narrow).values()}
    tested = sorted({output_tag(m.output) for m in models.values()})
    out = [
        f"{file.path}:{file.line_of('narrow', tag)}: [narrow] {tag}: no test of the unit tests "
        f"it (tested: {', '.join(tested)}); the row would do nothing"
        for tag in file.narrow
        if tag not in own
    ]
    sps = [getattr(t, "set_point", None) for t in file.tests]
    guarded = chosen_tests(models, names, sps, file.chosen)
    loops = ", ".join(sorted({s for s in sps if s}))
    out += [
        f"{file.path}:{file.line_of('chosen', tag)}: [chosen] {tag}: "
        + (f"not the set-point of a loop test of the unit ({loops or 'none'})" if tag not in sps
           else "no line reads a [chosen] set-point or the measurement a loop holds at one")
        + "; the row would do nothing"
        for tag in file.chosen
        if tag not in sps or not guarded
    ]  # fmt: skip
    known = {t for m in models.values() for t in m.tags} | set(file.build.get("skipped") or {})
    out += [
        f"{file.path}:{file.line_of('manual', tag)}: [manual] {tag}: not a tag of the unit (no "
        "test reads it); the row would do nothing"
        for tag in file.manual
        if tag not in known
    ]
    return out


@functools.lru_cache(maxsize=4096)
def _needed_tags(inputs: tuple[str, ...], output: str) -> tuple[str, ...]:
    """:func:`needed_tags` of a model's specs, parsed once (asked for every piece replayed)."""
    return tuple(needed_tags([*inputs, output]))


def load_test_model(name: str, path: Path, store: Any = None) -> TestModel:
    """The model of one test from its rule-base file (problems as ``file:line``). With a
    ``store`` (a :class:`~diag_plugin.diagnose.modelcache.ModelCache`) a Wang–Mendel model
    read before from the same bytes is taken from it, and one read now is kept in it."""
    from diag_plugin.rulebase.document import RuleBase, RuleBaseError

    data = None
    if store is not None:
        try:
            data = Path(path).read_bytes()
        except OSError:
            data = None  # RuleBase.load says why
        else:
            got = store.get(data)
            if got is not None and (tm := _cached_model(name, path, got)) is not None:
                return tm
    try:
        rb = RuleBase.load(path)
    except RuleBaseError as exc:
        raise UnitError(exc.problems) from None
    tm = model_of_test(name, rb)
    if data is not None:
        _keep_model(store, data, tm)
    return tm


def _keep_model(store: Any, data: bytes, tm: TestModel) -> None:
    """``tm``'s model in ``store`` under the file's bytes: a Wang–Mendel model's exact state
    and its conclusions as written, the test's variables as JSON (no pickle)."""
    from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor

    m = tm.model
    if type(m) is not WangMendelRegressor:
        return
    state = m.to_state()
    meta = {
        "params": state.pop("params"),
        "n_samples_seen": state.pop("n_samples_seen"),
        "n_skipped": state.pop("n_skipped"),
        "inputs": list(tm.inputs),
        "output": tm.output,
        "span": tm.span,
        "period": tm.period,
        "out_range": None if tm.out_range is None else list(tm.out_range),
    }
    arrays = dict(state)
    if m._conclusions is not None:
        arrays["conclusions"] = m._conclusions
    # the coarse levels' nodes: a least-squares fit per level that the first piece's replay
    # made (~0.05 CPU s of the bench's 45 tests), the same arrays whenever the rules are
    meta["node_levels"] = m.n_levels_
    for lv in range(1, m.n_levels_):
        for part, a in zip("kvf", m.level_nodes(lv), strict=True):
            arrays[f"nodes_{part}{lv}"] = a
    store.put(data, meta, arrays)


def _cached_model(name: str, path: Path, got: dict) -> TestModel | None:
    """The :class:`TestModel` :func:`_keep_model` kept, or None where the entry is not one."""
    from diag_plugin.fuzzy.wang_mendel import STATE_ARRAYS, WangMendelRegressor

    meta, arrays = got["meta"], got["arrays"]
    try:
        state = {
            "params": meta["params"],
            "n_samples_seen": meta["n_samples_seen"],
            "n_skipped": meta["n_skipped"],
            **{k: arrays[k] for k in STATE_ARRAYS},
        }
        m = WangMendelRegressor.from_state(state)
        if "conclusions" in arrays:
            m._conclusions = np.asarray(arrays["conclusions"], float)
        if int(meta["node_levels"]) != m.n_levels_:
            return None
        m._nodes = {
            lv: tuple(arrays[f"nodes_{part}{lv}"] for part in "kvf") for lv in range(1, m.n_levels_)
        }
        rng = meta["out_range"]
        return TestModel(
            name=name,
            path=Path(path),
            model=m,
            inputs=[str(v) for v in meta["inputs"]],
            output=str(meta["output"]),
            span=float(meta["span"]),
            period=meta["period"],
            out_range=None if rng is None else (float(rng[0]), float(rng[1])),
        )
    except (KeyError, TypeError, ValueError):
        return None


def model_of_test(name: str, rb: Any) -> TestModel:
    """The model of one test from its rule base as read from its file (``RuleBase(text,
    path)``: a Dask worker reads the text it made, the file is written by the client)."""
    from diag_plugin.rulebase.document import RuleBaseError

    try:
        model = rb.to_model()
    except RuleBaseError as exc:
        raise UnitError(exc.problems) from None
    lo, hi = rb.output.span
    return TestModel(
        name=name,
        path=rb.path,
        model=model,
        inputs=[v.spec for v in rb.inputs],
        output=rb.output.spec,
        span=float(hi - lo),
        period=rb.period,
        out_range=(float(lo), float(hi)),
    )


@numba.njit(cache=True, nogil=True)
def _hold_kernel(s, limit, last, run):  # pragma: no cover - numba
    # row by row (memory order); each column's state is its own. In place: ``s`` (the
    # caller's own array, C-ordered) gets the held symptoms and is returned — a new array of
    # the symptoms' size costs its first touch (page faults), about three times this pass
    n, m = s.shape
    for i in range(n):
        for j in range(m):
            x = s[i, j]
            if np.isnan(x):
                run[j] += 1
                if run[j] <= limit and not np.isnan(last[j]):
                    s[i, j] = last[j]
            else:
                last[j] = x
                run[j] = 0
    return s


@numba.njit(cache=True, nogil=True)
def _residual_kernel(
    out, j, at, y, yp, support, min_support, scale, table, level, spread, floor
):  # pragma: no cover - numba
    # Unit.residual row by row: supported (NaN below min_support), % of scale (eq. 6), the
    # answering level's factor (level_factor), the local spread's (spread_factor)
    has_level = level.shape[0] > 0
    has_spread = spread.shape[0] > 0
    for i in range(at.shape[0]):
        yhat = yp[i] if support[i] >= min_support else np.nan
        r = (y[i] - yhat) / scale * 100.0
        if has_level:
            lv = np.int64(level[i])
            r = r / (table[lv] if 0 <= lv < table.shape[0] else np.nan)
        if has_spread:
            sp = spread[i]
            r = r / (max(sp, floor) if np.isfinite(sp) else 1.0)
        out[j, at[i]] = r


def _names(names) -> pd.Index:
    """The column names ``names`` as an Index of their own, made from one kept per tuple of
    names (a view: its name is its own). A frame given a list builds its Index anew, a
    column of pandas strings each time: six per 7-day piece replayed (issue 34)."""
    return _names_index(tuple(names)).view()


@functools.lru_cache(maxsize=1024)
def _names_index(names: tuple[str, ...]) -> pd.Index:
    return pd.Index(list(names))


#: the kernels' empty arrays for a prediction without levels or spreads (never written)
_NONE = np.empty(0)
_NONE_INT8 = np.empty(0, np.int8)


def _on(s: np.ndarray) -> np.ndarray:
    """Where a symptom is on: nonzero and known (``nan_to_num(s) != 0`` in one compiled pass,
    without a temporary of the symptoms' size)."""
    a = np.ascontiguousarray(s, dtype=float)
    return _on_kernel(a.reshape(-1)).reshape(a.shape)


@numba.njit(cache=True, nogil=True)
def _on_kernel(s):  # pragma: no cover - numba
    out = np.empty(s.shape[0], np.bool_)
    for i in range(s.shape[0]):
        out[i] = s[i] > 0.0 or s[i] < 0.0  # NaN: neither
    return out


def _sticky(s: np.ndarray, carry: np.ndarray) -> np.ndarray:
    """Latch symptoms: once nonzero a column keeps that value (Laukonen et al., Sec. IV)."""
    out = s.copy()
    n, m = s.shape
    for j in range(m):
        if carry[j] != 0:
            out[:, j] = carry[j]
            continue
        on = np.flatnonzero(np.nan_to_num(s[:, j]) != 0)
        if on.size:
            out[on[0] :, j] = s[on[0], j]
            carry[j] = s[on[0], j]
    return out


#: a number in a ``why`` (a value, a bound, a count of seconds left), not one in a name
#: (``XMEAS16``, ``FT1[k-3]``): left out of the why's kind (:meth:`Diagnosis.intervals`)
NUMBER = r"(?<![\w.\[-])[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?"
_NUMBER = re.compile(NUMBER)


#: each :class:`Quality`'s name, by its number (:meth:`Diagnosis.to_frame`)
QUALITY_NAMES = {int(q): q.name for q in Quality}


@dataclass
class Diagnosis:
    """A unit's diagnosis per sample (all frames indexed by the samples' timestamps).

    ``residuals``: filtered residual per test (% of span, NaN unknown); ``symptoms``: −1/0/+1 or
    NaN (unknown) per test after delays; ``certainties``: per fault in [0, 1] (empty without a
    matrix); ``detected``: 1.0 any symptom, 0.0 none, NaN unknown; ``status``: NE 107 number;
    ``quality``: :class:`Quality` number; ``faults``: isolated faults joined by ``|``.
    Units with ``combined = true`` or ``isolation = "tags"`` also carry ``combined`` (columns
    ``T2``: the combined statistic, NaN unknown; ``s_T2``: its symptom 0/1 after the delays,
    NaN unknown or not a test), ``contributions`` (per tag its share of T², see
    :mod:`~diag_plugin.diagnose.unittags`) and ``top`` (``top1``, ``share1``, … on alarms).
    The replay computes the shares on the alarm samples only (what ``top`` ranks);
    ``contributions`` computes the others when first asked (the same values).
    """

    unit: str
    residuals: pd.DataFrame
    symptoms: pd.DataFrame
    certainties: pd.DataFrame
    detected: pd.Series
    status: pd.Series
    quality: pd.Series
    faults: pd.Series
    message: str = ""
    combined: pd.DataFrame | None = None
    #: ``contributions``, or what computes it when first asked (:class:`LazyShares`)
    _contributions: pd.DataFrame | Callable[[], pd.DataFrame] | None = field(
        default=None, repr=False
    )
    top: pd.DataFrame | None = None
    #: per sample of CHECK_FUNCTION the input outside what the unit learned (operating.py)
    why: pd.Series | None = None
    #: samples × pieces of equipment (``[equipment]``): 0 running, 1 stopped, 2 settling
    #: after its start (its tests off, not unknown: :mod:`~.equipment`); None without
    equipment: pd.DataFrame | None = None

    @property
    def contributions(self) -> pd.DataFrame | None:
        """Per sample each tag's share of T² (samples × tags; NaN unknown), or None without a
        combined test or isolation to tags; computed here, once, outside the alarm samples."""
        if callable(self._contributions):
            self._contributions = self._contributions()
        return self._contributions

    @property
    def top_tags(self) -> pd.DataFrame:
        """Per sample the tags that explain an alarm, best first (``top1``, ``share1``, …);
        empty columns for a unit without isolation to tags."""
        return self.top if self.top is not None else pd.DataFrame(index=self.status.index)

    def __len__(self) -> int:
        return len(self.status)

    def to_frame(self) -> pd.DataFrame:
        """One row per sample: ``status``, ``r_<test>``, ``s_<test>``, ``c_<fault>``,
        ``detected``, ``quality``, ``faults`` (index ``ts``); with a combined test or isolation
        to tags also ``T2``, ``s_T2`` and ``top1``, ``share1``, … (the tags on an alarm)."""
        parts = [
            self.status.rename("status"),
            self.residuals.add_prefix("r_"),
            self.symptoms.add_prefix("s_"),
            self.certainties.add_prefix("c_"),
            self.detected.rename("detected"),
            # by a table, not an enum per sample (1,000,000 rows: 2.3 → 0.1 CPU s, issue 34)
            self.quality.map(QUALITY_NAMES).rename("quality"),
            self.faults.rename("faults"),
        ]
        if self.combined is not None:
            parts.append(self.combined)
        if self.top is not None:
            parts.append(self.top)
        if self.why is not None and (self.why != "").any():
            parts.append(self.why.rename("why"))
        out = pd.concat(parts, axis=1)
        out.index.name = "ts"
        return out

    def at(self, i: int = -1) -> UnitStatus:
        """The :class:`UnitStatus` of sample ``i`` (default the last), for publishing."""
        ts = self.status.index[i]
        faults = self.faults.iloc[i]
        det = self.detected.iloc[i]
        return UnitStatus(
            unit=self.unit,
            ts=pd.Timestamp(ts),
            status=NE107(int(self.status.iloc[i])),
            quality=Quality(int(self.quality.iloc[i])),
            residuals=self.residuals.iloc[i].to_dict(),
            symptoms=self.symptoms.iloc[i].to_dict(),
            certainties=self.certainties.iloc[i].to_dict() if len(self.certainties.columns) else {},
            detected=None if np.isnan(det) else bool(det),
            faults=[f for f in str(faults).split("|") if f],
            message=self._message(i),
            tags=self._tags(i),
        )

    def _tags(self, i: int) -> list[tuple[str, float]]:
        if self.top is None:
            return []
        row = self.top.iloc[i]
        n = sum(1 for c in self.top.columns if c.startswith("top"))
        picks = range(1, n + 1)
        return [(row[f"top{k}"], float(row[f"share{k}"])) for k in picks if row[f"top{k}"]]

    def _message(self, i: int) -> str:
        """The unit's message, with the combined test and the top tags on an alarm."""
        parts = [self.message] if self.message else []
        if self.why is not None and self.why.iloc[i]:
            parts.append(str(self.why.iloc[i]))
        if self.combined is not None and self.combined["s_T2"].iloc[i] == 1:
            parts.append(f"combined test on (T² {self.combined['T2'].iloc[i]:.3g})")
        if self.top is not None:
            top = describe_top(self.top.iloc[i])
            if top:
                parts.append(top)
        return "; ".join(parts)

    def intervals(self) -> pd.DataFrame:
        """Runs of equal status, isolated faults and kind of ``why``: ``from``, ``to``
        (exclusive), ``status``, ``faults``, ``samples``, the tests with symptoms in the run
        and ``why`` at its start — the timeline a person reads. The kind of a ``why`` is its
        text with the numbers left out: a value moving on within "outside what the unit
        learned" is one run, "without a value" then "outside …" two (a run after a gap in
        the data read "without a value" for 127 s of which 94 s were values outside the
        learned range, SKAB)."""
        if not len(self.status):
            return pd.DataFrame(columns=["from", "to", "status", "faults", "samples", "tests"])
        st = self.status.to_numpy()
        fa = self.faults.to_numpy()
        change = (st[1:] != st[:-1]) | (fa[1:] != fa[:-1])
        why = None
        if self.why is not None:
            why = self.why.to_numpy(dtype=object)
            # the kinds of the distinct texts only (a replay repeats a few thousand texts over
            # its rows: 200,000 substitutions took ~0.5 CPU s), compared by their codes
            codes, texts = pd.factorize(self.why.fillna("").astype(str))
            kinds = [_NUMBER.sub("#", t) for t in texts.tolist()]  # not boxed one by one
            kind = pd.factorize(pd.Index(kinds, dtype=object))[0][codes]
            change |= kind[1:] != kind[:-1]
        starts = np.flatnonzero(np.r_[True, change])
        ends = np.r_[starts[1:], len(st)]  # exclusive
        idx = self.status.index
        period = (idx[1] - idx[0]) if len(idx) > 1 else pd.Timedelta(0)
        x = self.symptoms.to_numpy()
        sym = (x > 0) | (x < 0)  # a symptom: not 0, not unknown (NaN)
        names = list(self.symptoms.columns)
        if self.combined is not None:
            sym = np.c_[sym, self.combined["s_T2"].fillna(0).to_numpy() != 0]
            names.append("T2")
        on = np.logical_or.reduceat(sym, starts, axis=0) if sym.shape[1] else sym[starts]
        cols = {  # by column: a Timestamp boxed per run cost more than the rest
            "from": idx[starts],
            "to": idx[ends - 1] + period,
            "status": [NE107(s).name for s in st[starts].tolist()],
            "faults": fa[starts].tolist(),
            "samples": (ends - starts).tolist(),
            "tests": [
                ",".join(itertools.compress(names, r)) if any_on else ""
                for r, any_on in zip(on, on.any(axis=1).tolist(), strict=True)
            ],
        }
        if why is not None:
            cols["why"] = why[starts].tolist()
        return pd.DataFrame(cols, index=pd.RangeIndex(len(starts)))


class Unit:
    """One unit: its tests' models, evaluation chain and matrix, with carried state.

    Use :meth:`load` for a unit file. :meth:`evaluate` takes consecutive pieces of an aligned
    frame holding :attr:`tags` (one row per sampling period; NaN = missing, stale or bad).
    """

    #: threads of a piece's per-test residuals (:func:`~.pertest.each`; ``diag diagnose``:
    #: one per core): the same residuals with any number
    workers: int = 1

    def __init__(
        self, file: UnitFile, models: dict[str, TestModel], matrix: DiagnosticMatrix | None
    ):
        self.file = file
        self.name = file.name
        self.models = models
        self.matrix = matrix
        self.tests = [t.name for t in file.tests]
        periods = {m.period for m in models.values()}
        if len(periods) > 1:
            raise UnitError([f"{file.path}:1: the tests' models have different periods {periods}"])
        self.period = periods.pop() if periods else "10s"
        self.period_s = pd.Timedelta(self.period).total_seconds()
        #: the file's evaluation with delays given in seconds turned into samples at the period
        self.ev = resolved_evaluation(file.evaluation, self.period)
        #: a list to collect, per evaluated piece, samples × tests where a settle opens for
        #: the oscillation hold (its bound in samples, 0 elsewhere; :meth:`_openings`), so a
        #: benchmark scores the hold's own settle rule (``bench.matched.oscillation_score``);
        #: None (default): not collected
        self.openings_seen: list[np.ndarray] | None = None
        #: per piece of equipment (``[equipment]``, :mod:`~.equipment`) its tests' positions
        self.equipment = list(getattr(file, "equipment", None) or [])
        self.equipment_tests = members(self.equipment, [models[t.name].output for t in file.tests],
                                       [models[t.name].tags for t in file.tests])  # fmt: skip
        #: a piece's start settles: its tests off until none of them has been on for the
        #: quiet time, at most its own ``settle_max_s`` (else the unit's state-change bound)
        hold_s = self.ev.get("state_settle_max_s") or self.ev.get("settle_max_s") or 0.0
        self.equipment_hold = int(math.ceil(float(hold_s) / self.period_s)) if self.equipment else 0
        self.equipment_holds = [
            self.equipment_hold if e.settle_max_s is None
            else int(math.ceil(e.settle_max_s / self.period_s - 1e-9))
            for e in self.equipment
        ]  # fmt: skip
        #: per piece its start's envelope (``[envelope.NAME]``, :mod:`~.envelope`; None: none)
        self.equipment_envelopes = piece_envelopes(
            self.equipment, self.equipment_tests, getattr(file, "envelope", None) or {},
            self.tests, self.period_s,
        )  # fmt: skip
        #: the tests judged by the spread of their residual (valve stiction), by position
        self.spread_cols = np.array(
            [i for i, t in enumerate(file.tests) if t.statistic == "spread"], np.int64
        )
        #: isolation to tags: a matrix derived from the models when no expert one is given
        self.tag_isolation = self.ev["isolation"] == "tags"
        self.derived = self.tag_isolation and matrix is None
        if self.derived:
            self.matrix = derived_matrix(self)
        #: the derived matrix read crisply isolates only a column the symptoms match exactly
        #: (a hypothesis consistent with every test); a pattern no tag's column explains (a
        #: process fault: a leak, fouling) names the ranking's first tag, as the combined test
        #: alone does (docs/how-to/unit-loops.md, "A leak the derived matrix cannot isolate")
        self.exact_only = self.derived and self.ev["symptoms"] == "crisp"
        #: the certainty an isolated fault needs (``certainty``, or 1 with :attr:`exact_only`)
        self.iso_certainty = 1.0 if self.exact_only else float(self.ev["certainty"])
        self.cmodel = (
            CombinedModel.of(self) if (self.ev["combined"] or self.tag_isolation) else None
        )
        #: the tags the tests in alarm name beside the shares of T² (a kept-out test's
        #: always, any test's where T² names none)
        self.test_names = None if self.cmodel is None else TestNames.of(self, self.cmodel.tags)
        #: the inputs no test models, ranked after a tested output that explains as much
        self.untested = None if self.cmodel is None else Untested.of(self, self.cmodel.tags)
        #: the measured inputs beyond what the unit learned that explain the tests in alarm
        self.excursions = None if self.cmodel is None else Excursions.of(self, self.cmodel.tags)
        self.level_points = level_points(self)
        #: per test the history its model reads (unknown for that many samples at start): its
        #: longest lag, and a rate's samples (``rate(TAG,L)`` reads L more)
        specs = [parse_specs([*models[t].inputs, models[t].output]) for t in self.tests]
        self.test_depth = np.array([max_lag(sp) for sp in specs], np.int64)
        spread = np.zeros(len(self.tests), bool)
        spread[self.spread_cols] = True
        self.warm_labels = warm_labels(self.tests, self.test_depth, spread)
        #: the tests reading a hand valve, unknown where it is outside its span, the tests
        #: of a ``[narrow]`` tag, unknown where their own tag is outside its span, and the
        #: tests a ``[chosen]`` set-point guards, unknown where it is outside (None: none)
        self.manual = ManualGuard.of(
            models, self.tests, file.manual, file.narrow, file.chosen, self._set_points()
        )
        #: the settle guard after an operator's set-point step (:mod:`~.settle`; None: off)
        self.settle: SettleGuard | None = settle_guard(self)
        #: the same steps found for the oscillation hold (its own state: the hold reads a
        #: settle's transient whether or not the guard suppresses its alarm; None: none)
        self.transients: SettleGuard | None = settle_guard(self)
        #: the tags constant over the build window (``[fixed]``): one moved, CHECK_FUNCTION
        self.fixed: FixedGuard | None = FixedGuard.of(self)
        #: the combinations of the discrete states it learned (``[states]``): another one,
        #: CHECK_FUNCTION (:mod:`~.combos`)
        self.combos: CombosGuard | None = CombosGuard.of(self)
        #: a loop's actuator at its limit named first (:mod:`~.saturation`; None: no loop)
        self.saturation = Saturation.of(self)
        #: no level bridges a gap of an input an operator chooses (:func:`unbridge`)
        unbridge(self)
        self.reset()

    # ------------------------------------------------------------ loading
    @classmethod
    def load(
        cls,
        path: str | Path,
        folder: str | Path = "rulebases",
        models_cache: dict[Path, TestModel | UnitError] | None = None,
        store: Any = None,
    ) -> Unit:
        """Load a unit file, its models and matrix; all problems at once as ``file:line``.

        ``models_cache`` (resolved rule-base path → loaded model or its error), shared between
        calls, reads each rule-base file once: units that name the same file share its model.
        ``store``: a :class:`~diag_plugin.diagnose.modelcache.ModelCache` of the models read
        before, by their files' bytes (``diag diagnose``).
        """
        file = UnitFile.load(unit_path(str(path), folder))
        problems: list[str] = []
        models: dict[str, TestModel] = {}
        cache = {} if models_cache is None else models_cache
        for t in file.tests:
            p = file.resolve(t.model)
            if not p.exists():
                problems.append(f"{file.path}:{t.line}: test {t.name!r}: model file {p} not found")
                continue
            key = p.resolve()
            if key not in cache:
                try:
                    cache[key] = load_test_model(t.name, p, store)
                except UnitError as exc:
                    cache[key] = exc
            got = cache[key]
            if isinstance(got, UnitError):
                problems.append(f"{file.path}:{t.line}: test {t.name!r}: its model is broken:")
                problems.extend("  " + q for q in got.problems)
            else:
                models[t.name] = dataclasses.replace(got, name=t.name, path=p)
        matrix = None
        if file.matrix_path is not None:
            line = file.line_of("unit", "matrix")
            try:
                matrix = load_matrix(file.matrix_path)
            except MatrixError as exc:
                problems.append(f"{file.path}:{line}: matrix {file.matrix_path} is broken:")
                problems.extend("  " + p for p in exc.problems)
            else:
                if set(matrix.tests) != {t.name for t in file.tests}:
                    problems.append(
                        f"{file.path}:{line}: matrix tests {matrix.tests} differ from the "
                        f"unit's tests {[t.name for t in file.tests]}"
                    )
        if not problems:
            problems += _idle_rows(file, models)
        if problems:
            raise UnitError(problems)
        return cls(file, models, matrix)

    def _set_points(self) -> list[str | None]:
        """Each test's ``set_point`` (None: none), in test order."""
        return [getattr(t, "set_point", None) for t in self.file.tests]

    @property
    def model_tags(self) -> list[str]:
        """Every tag the unit's models read, by the models' names."""
        return list(dict.fromkeys(t for m in self.models.values() for t in m.tags))

    @property
    def tags(self) -> list[str]:
        """Every tag the unit reads, by the plant's names (the file's ``[tags]`` mapping):
        its models', the tags constant over its build window (``[fixed]``) and its discrete
        states (``[states]``)."""
        return list(dict.fromkeys(self.file.tags.get(t, t) for t in self._own_tags()))

    def _own_tags(self) -> list[str]:
        """The models' tags, the ``[fixed]`` tags and the ``[states]`` tags (models' names)."""
        states = (getattr(self.file, "states", None) or {}).get("tags", [])
        rc = getattr(self.file, "running", None)
        run = [rc.tag] if rc is not None else []
        run += [e.rc.tag for e in getattr(self.file, "equipment", None) or []]
        return [*self.model_tags, *getattr(self.file, "fixed", {}), *states, *run]

    def _model_frame(self, frame: pd.DataFrame) -> pd.DataFrame:
        """The plant's columns under the models' tag names."""
        if not self.file.tags:
            return frame
        return frame.rename(columns={self.file.tags.get(t, t): t for t in self._own_tags()})

    @property
    def faults(self) -> list[str]:
        return [] if self.matrix is None else list(self.matrix.faults)

    @property
    def has_thresholds(self) -> bool:
        """Every test has thresholds, and the combined test (``combined = true``) its own."""
        tests = all(t.high is not None for t in self.file.tests)
        c = self.file.combined
        return tests and (not self.ev["combined"] or (c is not None and c.high is not None))

    # ------------------------------------------------------------ state
    def _steady(self) -> np.ndarray:
        """Per test whether its filter restarts after a gap at its first value rather than
        at rest (:class:`LowPass` ``steady``): the spread tests, whose normal value is
        their loop's running spread, never near zero."""
        steady = np.zeros(len(self.tests), bool)
        steady[self.spread_cols] = True
        return steady

    def _oscillation_hold(self) -> OscillationHold:
        """Every test's symptom held through an oscillation (:class:`OscillationHold`) over
        ``oscillation_window_s``; a window of 0 samples (no key): none held."""
        w = oscillation_samples(self.ev, self.period)
        return OscillationHold(np.full(len(self.tests), w, np.int64), quiet=self._quiet_n())

    def _release_hold(self) -> ReleaseHold | None:
        """The spread tests' release on the long window (:class:`ReleaseHold`): those with a
        ``release`` threshold, when the unit file gives ``release_window_s`` (else None)."""
        sec = float(self.ev.get("release_window_s", 0.0) or 0.0)
        rel = np.array([self.file.tests[j].release or np.nan for j in self.spread_cols], float)
        has = np.isfinite(rel)  # a spread test without one is not held: not read either
        if sec <= 0 or not has.any():
            return None
        cols = self.spread_cols[has]
        # each loop's valve and its span (unitloops.PinnedValves), as Saturation reads it
        acts = [self.file.tests[j].actuator for j in cols]
        return ReleaseHold(spread_samples(sec, self.period), cols, rel[has],
                           [self._loop_tests(j) for j in cols],
                           [actuator_span(self, a) if a else None for a in acts])  # fmt: skip

    def _loop_tests(self, j: int) -> np.ndarray:
        """The spread test ``j``'s loop's own tests, which raise its release hold
        (:class:`ReleaseHold`): the other tests whose model's output is the loop's
        measurement (its level and balance tests) or its actuator (the valve's test)."""
        t = self.file.tests[j]
        tags = {output_tag(self.models[t.name].output), t.actuator}
        return np.array([i for i, u in enumerate(self.file.tests) if i != j
                         and u.statistic != "spread"
                         and output_tag(self.models[u.name].output) in tags], np.int64)  # fmt: skip

    def _openings(self, cols: Columns, eq) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Where a settle opens in this piece, for the oscillation hold
        (:meth:`OscillationHold.transform`): samples × groups the settle's bound in samples
        (group 0: the settle guard's steps, every test; group 1 + k: those and piece k's
        starts, its tests), and each test's group; ``(None, None)`` where none can."""
        n = len(cols)
        unit = None
        if self.transients is not None:
            g = self.transients
            sp = np.column_stack([cols.values(lp.sp) if lp.sp in cols.columns
                                  else np.full(n, np.nan) for lp in g.loops])  # fmt: skip
            unit = g.openings(sp)
        starts = None if eq is None else eq[3]
        if unit is None and not (starts and any(s is not None for s in starts)):
            return None, None
        pieces = len(self.equipment) if starts else 0
        opens = np.zeros((n, 1 + pieces), np.int64)
        if unit is not None:
            opens[:] = unit[:, None]
        group = np.zeros(len(self.tests), np.intp)
        for k in range(pieces):
            if starts[k] is None:
                continue
            running, since = starts[k]
            at = running & (since == 0)
            opens[at, 1 + k] = np.maximum(opens[at, 1 + k], self.equipment_holds[k])
            group[self.equipment_tests[k]] = 1 + k
        return opens, group

    def reset(self) -> Unit:
        """Start from rest: no history, filters at zero, no symptom on."""
        self.builders = {n: m.builder() for n, m in self.models.items()}
        ev = self.ev
        self.lowpass = (
            LowPass(ev["lowpass"], ev["order"], steady=self._steady())
            if ev["lowpass"] > 0
            else None
        )
        self.delay = OnOffDelay(ev["on_delay"], ev["off_delay"])
        self.latched = np.zeros(len(self.tests))
        self.held = np.full(len(self.tests), np.nan)  # last known symptom per test
        self.unknown_run = np.zeros(len(self.tests), np.int64)
        self.isolation = IsolationHold(1, len(self.tests), len(self.faults))
        self.combined_delay = OnOffDelay(ev["on_delay"], ev["off_delay"])
        window = spread_samples(ev["spread_window_s"] or 600.0, self.period)
        self.spread = RunningSpread(window, len(self.spread_cols))
        self.deadband = Deadband(ev["deadband"], len(self.tests)) if ev["deadband"] > 0 else None
        self.oscillation = self._oscillation_hold()
        self.release_hold = self._release_hold()
        ntags = len(self.cmodel.tags) if self.cmodel is not None else 0
        self.episode = EpisodeHold(ntags)
        self.test_episode = EpisodeHold(ntags)  # the tests on's names (TestNames.fill)
        self.alarm_hold = AlarmHold(ev["off_delay"]) if ev["off_delay_s"] > 0 else None
        self._last_alarm: tuple | None = None  # (status, faults, top row) the hold repeats
        self.seen = 0  # samples since the start (the warm-up)
        self.was_running = True  # the last sample's run condition (running.py)
        #: per piece of equipment the samples since its last start (equipment.py); from
        #: rest UNKNOWN_AGE: a piece running at the first sample starts there
        self.eq_since = np.full(len(getattr(self, "equipment", ())), UNKNOWN_AGE, np.int64)
        #: per piece the samples in a row none of its tests was on since its start
        self.eq_quiet = np.full(len(getattr(self, "equipment", ())), DONE, np.int64)
        #: per piece what its envelope carries (equipment.py)
        self.eq_env = PieceState(getattr(self, "equipment_tests", ()))
        if getattr(self, "settle", None) is not None:
            self.settle.reset()
        if getattr(self, "transients", None) is not None:
            self.transients.reset()
        if getattr(self, "fixed", None) is not None:
            self.fixed.reset()
        if getattr(self, "combos", None) is not None:
            self.combos.reset()
        if getattr(self, "saturation", None) is not None:
            self.saturation.reset()
        if not hasattr(self, "outside"):
            guarded = self.manual.chosen if self.manual is not None else {}
            self.outside = OutsideLearned(
                chosen_ranges(guarded)
                + manual_ranges(learned_ranges(self.models, self.tests), self.file.manual)
                + own_ranges(self.models, self.tests, self.file.narrow),
                self.file.tags,
                [self.models[t].tags for t in self.tests],
                period_s=self.period_s,
                first=[*(self.file.manual or {}), *self.file.chosen],
            )
        self.outside.reset()
        return self

    def to_state(self) -> dict[str, Any]:
        """The carried state as JSON (restart a live loop where it stopped)."""
        return {
            "builders": {n: b.to_state() for n, b in self.builders.items()},
            "lowpass": None if self.lowpass is None else self.lowpass.to_state(),
            "delay": self.delay.to_state(),
            "latched": self.latched.tolist(),
            "held": [None if np.isnan(v) else float(v) for v in self.held],
            "unknown_run": self.unknown_run.tolist(),
            "isolation": self.isolation.to_state(),
            "combined_delay": self.combined_delay.to_state(),
            "spread": self.spread.to_state(),
            "deadband": None if self.deadband is None else self.deadband.state.tolist(),
            "oscillation": self.oscillation.to_state(),
            "release": None if self.release_hold is None else self.release_hold.to_state(),
            "episode": self.episode.to_state(),
            "test_episode": self.test_episode.to_state(),
            "alarm_hold": None if self.alarm_hold is None else self.alarm_hold.to_state(),
            "seen": self.seen,
            "outside": self.outside.to_state(),
            "last_alarm": None
            if self._last_alarm is None
            else [int(self._last_alarm[0]), self._last_alarm[1], self._last_alarm[2]],
            "settle": None if self.settle is None else self.settle.to_state(),
            "transients": None if self.transients is None else self.transients.to_state(),
            "fixed": None if self.fixed is None else self.fixed.to_state(),
            "combos": None if self.combos is None else self.combos.to_state(),
            "saturation": None if self.saturation is None else self.saturation.to_state(),
            "running": self.was_running,
            "equipment": self.eq_since.tolist(),
            "equipment_quiet": self.eq_quiet.tolist(),
            "equipment_envelope": self.eq_env.to_state(),
        }

    def load_state(self, state: dict[str, Any]) -> Unit:
        for n, b in self.builders.items():
            b.load_state(state["builders"][n])
        if self.lowpass is not None and state.get("lowpass"):
            self.lowpass = LowPass.from_state(state["lowpass"])
            self.lowpass.steady = self._steady()  # a state saved before it has none
        self.delay = OnOffDelay.from_state(state["delay"])
        self.latched = np.asarray(state["latched"], float)
        self.held = np.array([np.nan if v is None else v for v in state["held"]], float)
        self.unknown_run = np.asarray(state["unknown_run"], np.int64)
        self.seen = int(state.get("seen", 1 << 40))  # states saved before it: warmed up
        if "outside" in state:  # states saved before it: no excursion, no lag history
            self.outside.load_state(state["outside"])
        if "isolation" in state:  # states saved before it start without a held isolation
            self.isolation = IsolationHold.from_state(state["isolation"])
        if "combined_delay" in state:
            self.combined_delay = OnOffDelay.from_state(state["combined_delay"])
        if "spread" in state:  # states saved before issue 34 start these from rest
            self.spread.load_state(state["spread"])
            self.episode.load_state(state["episode"])
            if "test_episode" in state:  # a state saved before it had none
                self.test_episode.load_state(state["test_episode"])
            if self.deadband is not None and state.get("deadband") is not None:
                self.deadband.state = np.asarray(state["deadband"], float)
            if self.alarm_hold is not None and state.get("alarm_hold") is not None:
                self.alarm_hold.load_state(state["alarm_hold"])
                last = state.get("last_alarm")
                self._last_alarm = None if last is None else (last[0], last[1], last[2])
        if "oscillation" in state:  # a state saved before it starts the hold from rest
            self.oscillation.load_state(state["oscillation"])
        if self.release_hold is not None and state.get("release") is not None:
            self.release_hold.load_state(state["release"])  # saved before it: from rest
        if self.settle is not None and state.get("settle") is not None:
            self.settle.load_state(state["settle"])  # states saved before it: from rest
        if self.transients is not None and state.get("transients") is not None:
            self.transients.load_state(state["transients"])  # before it: from rest
        if self.fixed is not None and state.get("fixed") is not None:
            self.fixed.load_state(state["fixed"])  # states saved before it: from rest
        if self.combos is not None and state.get("combos") is not None:
            self.combos.load_state(state["combos"])  # states saved before it: from rest
        if self.saturation is not None and state.get("saturation") is not None:
            self.saturation.load_state(state["saturation"])
        self.was_running = bool(state.get("running", True))  # saved before it: running
        if len(state.get("equipment") or []) == len(self.eq_since):
            self.eq_since = np.asarray(state["equipment"], np.int64)
        else:  # a state saved before it: running long (not a start of unknown age)
            self.eq_since = np.full(len(self.eq_since), 1 << 40, np.int64)
        if len(state.get("equipment_quiet") or []) == len(self.eq_quiet):  # else: none open
            self.eq_quiet = np.asarray(state["equipment_quiet"], np.int64)
        self.eq_env.load_state(state.get("equipment_envelope"))  # saved before it: from rest
        return self

    # ------------------------------------------------------------ stages
    def columns(self, frame: pd.DataFrame) -> Columns:
        """The piece's columns read once, under the models' tag names (:class:`Columns`):
        what every builder and the reasons for CHECK_FUNCTION read."""
        rc = self.file.running
        read = [*self.model_tags, *([rc.tag] if rc is not None else [])]
        read += [e.rc.tag for e in self.equipment]
        # the [states] tags no model reads: the state settle watches their changes too
        read += [t for t in (getattr(self.file, "states", None) or {}).get("tags", ())
                 if t not in read]  # fmt: skip
        plant = {t: self.file.tags.get(t, t) for t in read}
        return Columns(frame, {t: p if p in frame.columns else t for t, p in plant.items()})

    def raw_residuals(self, frame: pd.DataFrame, cols: Columns | None = None) -> pd.DataFrame:
        """Residual per test in % (eq. 6 or of ``ymax``), NaN where unknown (a stopped piece
        of equipment's tests too); advances state. ``cols``: the piece's :meth:`columns`, if
        read already."""
        return self._residuals(frame, cols)[0]

    def _residuals(
        self, frame: pd.DataFrame, cols: Columns | None = None
    ) -> tuple[pd.DataFrame, tuple | None]:
        """:meth:`raw_residuals` and, of the same samples, where a piece of equipment's tests
        are off (:meth:`_equipment_off`, called once: it advances the pieces' starts)."""
        if cols is None:
            cols = self.columns(frame)
        # a test's residuals are one row of tests × samples (written in memory order, not a
        # column of samples × tests); turned to samples × tests once at the end
        out = np.full((len(self.tests), len(frame)), np.nan)
        moved, chosen = False, None
        if self.manual is not None:  # a tag missing from the piece: not outside (the models'
            # builders say which tag is missing, with its name)
            nan = np.full(len(frame), np.nan)

            def value(t: str) -> np.ndarray:
                return cols.values(t) if t in cols.columns else nan

            moved, chosen = self.manual.moved(value), self.manual.chosen_off(value)

        def row(j: int) -> None:  # test j's row of ``out`` (its own builder and model)
            t = self.file.tests[j]
            m = self.models[t.name]
            d = self.builders[t.name].transform(cols, lean=True)
            if d.positions.size:
                self._residual_into(out, j, d.positions, t, d.y, m.model.predict_detail(d.X))
                if self.manual is not None:  # a hand valve outside its span: unknown
                    self.manual.blank(out, j, d.positions, d.X, moved, d.y, chosen)

        each(row, len(self.file.tests), self.workers)  # the same rows in any thread (pertest)
        off = self._equipment_off(cols, len(frame))
        if off is not None and off[0] is not None:  # a stopped piece's tests: off
            out[off[0].T] = np.nan
        # samples × tests as a view of it (column-major): :meth:`filtered` writes the C-ordered
        # copy it filters in place, so no third array of the residuals' size
        raw = pd.DataFrame(out.T, index=frame.index, columns=_names(self.tests), copy=False)
        return raw, off

    def _residual_into(
        self, out: np.ndarray, j: int, at: np.ndarray, test: TestSpec, y: np.ndarray,
        pred: Prediction,
    ) -> None:  # fmt: skip
        """:meth:`residual` written into row ``j`` of ``out`` (tests × samples) at samples
        ``at``, in one compiled pass (the same operations in the same order, so the same
        bits)."""
        m = self.models[test.name]
        scale = test.ymax if self.ev["scale"] == "max" and test.ymax else m.span
        table = np.asarray(test.levels if test.levels is not None else (1.0,), float)
        none = _NONE
        level = _NONE_INT8 if pred.level is None else np.asarray(pred.level)
        spread = none if pred.spread is None or not test.spread else np.asarray(pred.spread)
        support = pred.support
        if not (isinstance(support, np.ndarray) and support.dtype == float
                and support.shape == np.shape(pred.y)):  # fmt: skip
            support = np.broadcast_to(np.asarray(support, float), np.shape(pred.y))
        _residual_kernel(out, j, at, np.asarray(y, float), np.asarray(pred.y, float),
                         np.ascontiguousarray(support), float(self.ev["min_support"]),
                         float(scale), table, level, spread, SPREAD_FLOOR)  # fmt: skip

    def residual(self, test: TestSpec, y: np.ndarray, pred: Prediction) -> np.ndarray:
        """A test's raw residual from its model's prediction: % of span (eq. 6) or of ``ymax``,
        NaN below ``min_support``, divided by the answering level's scale (:func:`level_factor`)
        and, for a test with ``spread = true``, by the local spread (:func:`spread_factor`)."""
        m = self.models[test.name]
        yhat = supported(pred, self.ev["min_support"])
        scale = test.ymax if self.ev["scale"] == "max" and test.ymax else m.span
        r = residual_pct(y, yhat, scale) / level_factor(test.levels, pred.level)
        return r / spread_factor(pred.spread) if test.spread else r

    def filtered(self, raw: pd.DataFrame) -> pd.DataFrame:
        """The residuals as judged: a spread test's column replaced by the running spread of
        its residual (:mod:`~diag_plugin.diagnose.unitloops`), then the low-pass filter."""
        if not self.spread_cols.size and self.lowpass is None:
            return raw
        # one C-ordered copy (``raw`` may be column-major, :meth:`raw_residuals`), replaced
        # and filtered in place
        x = np.array(raw.to_numpy(float), float, order="C")
        if self.spread_cols.size:
            x[:, self.spread_cols] = self.spread.transform(x[:, self.spread_cols])
        if self.lowpass is not None:
            x = self.lowpass.transform(x, overwrite=True)
        return pd.DataFrame(x, index=raw.index, columns=raw.columns, copy=False)

    def _limits(self) -> tuple[np.ndarray, np.ndarray]:
        lims = [t.limits or (np.nan, np.nan) for t in self.file.tests]
        lo = np.array([a for a, _ in lims], float)
        hi = np.array([b for _, b in lims], float)
        return lo, hi

    def _fuzzy_sets(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
        """Breakpoints ``(n1, n0, p0, p1)`` of each test's N, 0, P sets: the unit file's
        learned or edited ``fuzzy`` row, else ramps of ``fuzzy_width`` × half the band centred
        on the thresholds (μP = μ0 = 0.5 at ``high``, μN = μ0 = 0.5 at ``low``)."""
        k = (hi - lo) / 2.0
        half = self.ev["fuzzy_width"] * k / 2.0
        pts = np.stack([lo - half, lo + half, hi - half, hi + half])
        for i, t in enumerate(self.file.tests):
            if t.fuzzy is not None:
                pts[:, i] = t.fuzzy
        return tuple(pts)

    def symptoms(
        self,
        r: np.ndarray,
        opens: np.ndarray | None = None,
        group: np.ndarray | None = None,
        long: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Delayed (and latched) symptoms −1/0/+1/NaN, and the fuzzy memberships if fuzzy;
        ``opens``, ``group``: where a settle opens (:meth:`_openings`); ``long``: the spread
        tests' long-window spread (:meth:`ReleaseHold.long_spread`; None: no release)."""
        lo, hi = self._limits()
        no_th = np.isnan(hi)
        hi_ = np.where(no_th, 1.0, hi)
        lo_ = np.where(no_th, -1.0, lo)
        mem = None
        if self.ev["symptoms"] == "fuzzy":
            mu_n, mu_0, mu_p = three_valued(r, *self._fuzzy_sets(lo_, hi_))
            mem = np.stack([mu_n, mu_0, mu_p], axis=2)
            mem[:, no_th, :] = np.nan
        if self.deadband is not None:  # ISA-18.2: clears only back inside (1 − deadband) × it
            raw = self.deadband.transform(r, lo_, hi_)
        else:
            raw = FixedThresholds(high=hi_, low=lo_).transform(r)
        raw[:, no_th] = np.nan
        # ``raw`` is this call's own array: delayed, then held, in place (no new array of
        # the symptoms' size for either)
        s = self.delay.transform(raw, overwrite=True)
        # a spread test on stays on while its long window's spread is unusual (ReleaseHold)
        if self.release_hold is not None and long is not None:
            s = self.release_hold.transform(s, long, opens, group)
        # a swing across both thresholds is one alarm; a settle's transient none
        s = self.oscillation.transform(s, opens, group)
        # a test unknown for fewer samples than the on-delay keeps its last known symptom:
        # a brief gap neither clears a symptom nor flickers the unit to CHECK_FUNCTION
        s = _hold_kernel(
            np.ascontiguousarray(s), self.ev["on_delay"] - 1, self.held, self.unknown_run
        )
        if self.ev["latch"]:
            s = _sticky(s, self.latched)
        return s, mem

    def certainties(
        self, s: np.ndarray, mem: np.ndarray | None, on: np.ndarray | None = None
    ) -> np.ndarray:
        """Certainty per fault: nearest signature (crisp) or the normalised certainty factor
        of rules (10)–(14) (fuzzy, :meth:`DiagnosticMatrix.rules`); 0 while no symptom is on
        (the delays decide when there is something to isolate). ``on``: the samples with a
        symptom, if known (``_on(s).any(axis=1)``)."""
        assert self.matrix is not None
        order = [self.tests.index(t) for t in self.matrix.tests]
        if on is None:
            on = _on(s).any(axis=1)  # any test: the matrix's order does not matter
        # only the samples with a symptom are reasoned over (the rest are 0): a replay of
        # fault-free data skips the matrix, and its n × tests × faults arrays, almost entirely
        c = np.zeros((s.shape[0], len(self.faults)))
        rows = np.flatnonzero(on)
        if rows.size and mem is not None:
            c[rows] = self.matrix.rules(mem[rows][:, order, :]).certainty
        elif rows.size:
            c[rows] = self.matrix.nearest(s[rows][:, order]).certainties
        return c

    # ------------------------------------------------------------ evaluate
    def at_points(self, raw: pd.DataFrame, point: np.ndarray | None) -> pd.DataFrame:
        """The raw residuals with each level test that has operating points centred and
        scaled at its sample's point (``point``: :meth:`CombinedModel.point_of`):
        ``(r − point_center[k]) / point_scale[k]`` (:func:`level_points`); as they are for a
        unit without."""
        if self.level_points is None or point is None:
            return raw
        cols, center, scale = self.level_points
        x = raw.to_numpy(float, copy=True)
        x[:, cols] = (x[:, cols] - center[point]) / scale[point]
        return pd.DataFrame(x, index=raw.index, columns=raw.columns, copy=False)

    def evaluate(
        self, frame: pd.DataFrame, settle: SettleGuard | None = None,
        pieces: PieceReplay | None = None,
    ) -> Diagnosis:  # fmt: skip
        """Diagnose the next piece of data (continues the carried state). A unit with a run
        condition (``[running]``, :mod:`~.running`) judges only the samples where it runs:
        elsewhere its tags are read as missing and its status is CHECK_FUNCTION, not
        running; at each stop the alarm's carriers start from rest (:meth:`_stopped`).
        ``settle``: a settle guard made for the purpose, read and updated in place of the
        unit's own (:attr:`settle`, None: that one), which is left untouched: the build
        replays its window with one (:func:`~.settle.settle_ages`). ``pieces``: the
        pieces of equipment's holds to judge with and a list to collect, per piece of data,
        the age each piece's start settle judges each row at, their envelopes unread
        (:class:`~.equipment.PieceReplay`: the build replays its window so, what a piece's
        envelope is learned at, :func:`~.settle.settle_replay`); None: the unit's own."""
        guard = self.settle if settle is None else settle
        rc = self.file.running
        col = self.run_column(frame)
        if rc is None or col is None:
            return self._evaluate(frame, guard, pieces)
        runs = rc.runs(frame[col].to_numpy(float))
        if runs.all():
            self.was_running = True
            return self._evaluate(frame, guard, pieces)
        masked = frame.copy()
        masked.loc[~runs, [c for c in frame.columns if c != col]] = np.nan
        parts = []
        for a, b, on in self.run_segments(runs, guard):
            since = None if on or guard is None else int(guard.g[6])
            d = self._evaluate(masked.iloc[a:b], guard, pieces)
            if not on:
                d = not_running(d, rc.whys(frame[col].to_numpy(float)[a:b]))
                self._last_alarm = None
                if since is not None:  # the time stopped is no quiet time: an alarm at the
                    # last stop keeps the next start's settle shut (a fault is not hidden)
                    guard.g[6] = since
            parts.append(d)
        return concat(parts)

    def run_column(self, frame: pd.DataFrame) -> str | None:
        """The column of ``frame`` that holds the run condition's tag (``[running]``,
        :mod:`~.running`): its plant name, else its models' name (a build's window, read
        under the models' names with the run tag beside); None without a run condition or
        without the tag: the frame is judged throughout."""
        rc = self.file.running
        if rc is None:
            return None
        have = (self.file.tags.get(rc.tag, rc.tag), rc.tag)
        return next((c for c in have if c in frame.columns), None)

    def runs_of(self, frame: pd.DataFrame) -> np.ndarray:
        """Per row of ``frame`` whether the unit runs (:meth:`RunCondition.runs
        <diag_plugin.diagnose.running.RunCondition.runs>` of :meth:`run_column`; every row
        without one)."""
        col = self.run_column(frame)
        if col is None:
            return np.ones(len(frame), bool)
        return self.file.running.runs(frame[col].to_numpy(float))

    def run_segments(
        self, runs: np.ndarray, settle: SettleGuard | None = None
    ) -> Iterator[tuple[int, int, bool]]:
        """The runs of ``runs`` (per sample whether the unit runs), each ``(start, end,
        running)``, with the unit's carriers restarted as at run time: at each stop (a
        stretch stopped after one running, not the rest of a stop a piece of data began in)
        :meth:`_stopped` before it is yielded (``settle``: the guard it lets go of its holds),
        and :attr:`was_running` set after each. One rule for :meth:`evaluate` and for what
        is learned from residuals filtered as the unit filters them (the build's
        :class:`~diag_plugin.unitbuild.loops.HeldOut`: its filters restart at each stop as
        here, so a spread test's filter starts at its first value after a long stop)."""
        for a, b, on in segments(runs):
            if not on and self.was_running:
                self._stopped(settle)
            yield a, b, on
            self.was_running = on

    def _equipment_off(self, cols: Columns, n: int) -> tuple | None:
        """Samples × tests where a piece of equipment's tests are off (it is stopped,
        :mod:`~.equipment`; None: none), per stopped piece its samples and the reason,
        samples × pieces their states, and what the settle after each start reads
        (:func:`~.equipment.off_mask`); None without ``[equipment]``."""
        if not self.equipment:
            return None
        runs = {e.rc.tag: cols.values(e.rc.tag) for e in self.equipment
                if e.rc.tag in cols.columns}  # fmt: skip
        return off_mask(self.equipment, self.equipment_tests, runs, self.eq_since, self.tests, n)

    def _equipment_settle(self, eq, s: np.ndarray, r: np.ndarray, replay=None, index=None):
        """The stopped pieces' ``eq`` (:meth:`_equipment_off`) with each started piece's tests
        held off while it settles (:func:`~.equipment.settling`, from the symptoms ``s``
        before the hold; advances the pieces' quiet counts): ``(off, said, state)`` or None
        where nothing is off, and samples × tests where a settle holds a test (None: none).
        ``replay``: :meth:`evaluate`'s ``pieces`` (its holds, its envelopes unread; the
        rows' ages appended to its list, ``index`` theirs)."""
        if eq is None:
            return None, None
        off, said, state, starts = eq
        envs, holds = self.equipment_envelopes, self.equipment_holds
        if replay is not None:
            envs, holds = [None] * len(self.equipment), replay.holds
        u = scaled(r, *self._limits()) if any(envs) else None
        held, why, where = settling(self.equipment, self.equipment_tests, starts, _on(s),
                                    holds, self._quiet_n(), self.eq_quiet, self.tests, u,
                                    envs, self.eq_env, int(self.ev["on_delay"]),
                                    self.period_s)  # fmt: skip
        if replay is not None:
            replay.seen.append((index, piece_ages(starts, where, s.shape[0])))
        if held is None and why:  # only the whys of alarms an envelope raised
            off = np.zeros(s.shape, bool) if off is None else off
            said = [*said, *why]
        if held is not None:
            state[where & (state == 0)] = SETTLING
            off = held if off is None else off | held
            said = [*said, *why]
        return (None if off is None else (off, said, state)), held

    def _quiet_n(self) -> int:
        """The settle's quiet time in samples (:func:`~.settle.quiet_samples`)."""
        if getattr(self, "_quiet", None) is None:
            from diag_plugin.diagnose.settle import quiet_samples

            self._quiet = quiet_samples(self)
        return self._quiet

    def _stopped(self, settle: SettleGuard | None) -> None:
        """At a stop: what carries an alarm forward starts from rest (the residual filter,
        the spread tests' window, the tests' and the combined test's on/off delays, the held
        symptoms, the deadband, the unit's off-delay and its last alarm, the isolation and
        episode holds, the valve-at-limit rule), so none is carried across the stop into the
        next start (:mod:`~.running`); the settle guard lets go of every held set-point but
        the run tag's (:meth:`~.settle.SettleGuard.forget_holds`: the start is the state
        change it settles). The models' histories, the settle's other state and the
        operating-point guards go on (they read the stopped samples as missing)."""
        ev = self.ev
        if self.lowpass is not None:
            self.lowpass = LowPass(ev["lowpass"], ev["order"], steady=self._steady())
        self.spread = RunningSpread(spread_samples(ev["spread_window_s"] or 600.0, self.period),
                                    len(self.spread_cols))  # fmt: skip
        self.delay = OnOffDelay(ev["on_delay"], ev["off_delay"])
        self.combined_delay = OnOffDelay(ev["on_delay"], ev["off_delay"])
        self.held[:] = np.nan
        self.unknown_run[:] = 0
        if self.deadband is not None:
            self.deadband = Deadband(ev["deadband"], len(self.tests))
        self.oscillation = self._oscillation_hold()
        self.release_hold = self._release_hold()
        self.isolation = IsolationHold(1, len(self.tests), len(self.faults))
        self.episode = EpisodeHold(len(self.cmodel.tags) if self.cmodel is not None else 0)
        if self.alarm_hold is not None:
            self.alarm_hold = AlarmHold(ev["off_delay"])
        self._last_alarm = None
        if self.saturation is not None:
            self.saturation.reset()
        rc = self.file.running
        for g in (settle, self.transients):
            if g is not None:
                g.forget_holds(None if rc is None else rc.tag)

    def _evaluate(
        self, frame: pd.DataFrame, settle: SettleGuard | None, pieces: PieceReplay | None = None
    ) -> Diagnosis:
        """:meth:`evaluate` of a piece judged throughout, ``settle`` its settle guard,
        ``pieces`` :meth:`evaluate`'s."""
        point = self.cmodel.point_of(frame) if self.cmodel is not None else None
        cols = self.columns(frame)  # read once: the builders and the reasons
        raw, off = self._residuals(frame, cols)  # off: a stopped piece's tests (equipment.py)
        raw = self.at_points(raw, point)
        # the spread tests' long window (ReleaseHold) reads their raw residuals, as the
        # short one (filtered) does
        long = None
        if self.release_hold is not None:
            rh = self.release_hold
            long = rh.long_spread(raw.iloc[:, rh.cols].to_numpy(float),
                                  rh.valve_readings(cols.values, len(raw)))  # fmt: skip
        r = self.filtered(raw)
        # what the warm-up reads of the raw residuals, taken now: the raw array is let go
        # before the symptoms and the combined test make theirs (one n × tests array fewer
        # at the replay's peak; a first pass pays the first touch of every new page)
        raw_known = np.isfinite(raw.to_numpy())
        del raw
        opens, group = self._openings(cols, off)
        if self.openings_seen is not None:
            self.openings_seen.append(np.zeros((len(r), len(self.tests)), np.int64)
                                      if opens is None else opens[:, group])  # fmt: skip
        s, mem = self.symptoms(r.to_numpy(), opens, group, long)
        n, T = s.shape
        # a started piece's tests held off while it settles (equipment.py): from their
        # symptoms, then off as a stopped piece's (the combined test never reads them)
        off, held = self._equipment_settle(off, s, r.to_numpy(), pieces, frame.index)
        if held is not None:
            x = r.to_numpy(float, copy=True)
            x[held] = np.nan
            r = pd.DataFrame(x, index=r.index, columns=r.columns, copy=False)
            if mem is not None:
                mem[held] = np.nan
        if off is not None:  # a stopped piece's tests: off, neither on nor unknown
            s[off[0]] = np.nan
        known = ~np.isnan(s) if off is None else ~np.isnan(s) | off[0]
        active = _on(s).any(axis=1)
        c_on = np.zeros(n, bool)
        combined = None
        if self.cmodel is not None:
            t2, _ = self.cmodel.evaluate(r.to_numpy(), point, shares=False)  # shares: alarms
            s_t2 = np.full(n, np.nan)
            if self.ev["combined"] and self.cmodel.high is not None:
                with np.errstate(invalid="ignore"):
                    raw_c = np.where(np.isnan(t2), np.nan, (t2 > self.cmodel.high) * 1.0)
                s_t2 = self.combined_delay.transform(raw_c[:, None])[:, 0]
                if self.release_hold is not None and long is not None:
                    # once on, held while a loop's long spread is unusual (ReleaseHold)
                    s_t2 = self.release_hold.combined(s_t2, long, opens)
                c_on = _on(s_t2)
            combined = pd.DataFrame(
                {"T2": t2, "s_T2": s_t2}, index=frame.index, columns=_names(("T2", "s_T2"))
            )
        tests_on = active
        active = active | c_on
        detected = np.where(active, 1.0, np.where(known.all(axis=1), 0.0, np.nan))
        # Good only when every test was evaluated on this very sample; a symptom held over a
        # gap (see symptoms) is Uncertain, like OPC UA's Uncertain_LastUsableValue
        fresh = known & ~np.isnan(r.to_numpy())
        if off is not None:
            fresh |= off[0]
        quality = np.where(
            fresh.all(axis=1),
            Quality.GOOD,
            np.where(known.any(axis=1), Quality.UNCERTAIN, Quality.BAD),
        ).astype(np.int8)
        status = np.where(
            active, NE107.OFF_SPEC, np.where(np.isnan(detected), NE107.CHECK_FUNCTION, NE107.NORMAL)
        ).astype(np.int8)
        faults = np.full(n, "", dtype=object)
        cert = np.empty((n, 0))
        if self.matrix is not None:
            cert = self.certainties(s, mem, tests_on)
            status, faults = self._isolate(cert, active, status, s)
        top = shares = None
        if self.cmodel is not None:
            # the tags named: each one's share averaged over the alarm episode so far; the
            # shares computed on the alarm samples only (the episode and the ranking read
            # no others; the rest when Diagnosis.contributions is asked for)
            shares = LazyShares(self.cmodel, r.to_numpy(), active, frame.index, point)
            r_on, s_on = r.to_numpy()[active], s[active]
            # a kept-out test in alarm names its own tags
            shares.share_at = self.test_names.name(shares.share_at, r_on, s_on)
            if self.excursions is not None:  # an input beyond what the unit learned
                before = shares.share_at
                shares.share_at = self.test_names.fill_named(
                    self.excursions.name(before, r.to_numpy(), s, cols.values, active),
                    before,
                    self.test_names.on_values(r_on, s_on),
                )
            held = self.episode.transform_at(shares.share_at, active)
            # and any test in alarm where the held shares name none (T² unknown, or 0)
            held_on = self.test_episode.transform_at(self.test_names.on_values(r_on, s_on), active)
            held = self.test_names.fill(held, held_on)
            # the ranking's columns as arrays (the alarm hold edits them), one frame at the end
            top = top_columns_at(held, self.cmodel.tags, active, untested=self.untested)
        alone = (active if self.exact_only else c_on & ~tests_on) & (faults == "")
        if alone.any():  # the combined test alone (or symptoms no column explains, with
            # exact_only): the unit fails, at the best-ranked tag
            status[alone] = NE107.FAILURE
            faults[alone] = top["top1"][alone] if self.tag_isolation else "unit"
            faults[alone & (faults == "")] = "unit"
        if self.exact_only and top is not None and active.any():
            # the exact column and the ranking's first tag both named where the first tag's
            # column holds every symptom on (a small fault fires only some of its tests)
            at = np.flatnonzero(active)
            order = [self.tests.index(t) for t in self.matrix.tests]
            faults[at] = with_ranked(self.matrix, faults[at], top["top1"][at], s[at][:, order])
        saturated = None
        if self.saturation is not None:  # a loop's valve at its limit: named first
            which, sat_text, first = self.saturation.transform(cols, _on(s), active)
            if (which >= 0).any():
                self.saturation.name_first(which, sat_text, faults, top, first)
                saturated = (which >= 0, sat_text)
        # the states in a combination never learned; a tag constant over the build window
        # moved: read before the off-delay, which repeats only an alarm the unit shows (one
        # they make CHECK_FUNCTION, never seen, would surface after it as a FAILURE with no
        # symptom on and no test to name: issue 34 item 6, run 171 of the pasteuriser)
        guarded = [
            guard.transform(frame.index, self._fixed_values(frame, guard))
            for guard in (self.combos, self.fixed)
            if guard is not None
        ]
        repeated = None
        if self.alarm_hold is not None:
            shown = active
            for held, _ in guarded:
                shown = shown & ~held
            detected, status, faults, top, repeated = self._hold_alarm(
                shown, detected, status, faults, top
            )
        settled = None
        if settle is not None:  # an operator's set-point step: its alarm suppressed
            settled = self._settle(settle, frame.index, cols, r, active, detected, status,
                                   faults)  # fmt: skip
        message = ""
        checking = status == NE107.CHECK_FUNCTION
        unknown = np.isnan(s) if off is None else np.isnan(s) & ~off[0]
        rows, warm, left = self._warming(unknown, raw_known)
        judged = unknown
        if warm.any():
            judged = unknown.copy()
            judged[rows] &= ~warm
        why = self.outside.transform(cols, judged, checking)
        if warm.any():
            why[rows] = warming_up(
                why[rows], warm, left, checking[rows], self.warm_labels, self.period_s
            )
        if settled is not None:
            why = prepend(why, *settled)
        if off is not None:  # a stopped piece of equipment: its tests off, said
            for at, text in off[1]:
                why = prepend(why, at, np.full(n, text, dtype=object))
        if saturated is not None:
            why = prepend(why, *saturated)
        # the states in a combination never learned; a tag constant over the build window
        # moved (its text first: the more telling)
        for held, text in guarded:
            if held.any():
                apply_fixed(held, status, faults, detected)
                if top is not None:  # no tag named where the diagnosis is unknown
                    for c, col in top.items():
                        col[held] = "" if c.startswith("top") else np.nan
                why = prepend(why, held, text)
        if repeated is not None and repeated.any():  # an alarm held on: said why, after
            said = repeated & (status != NE107.CHECK_FUNCTION)  # the reasons above (a stop)
            why = np.asarray(why, dtype=object).copy()
            text, had = held_text(self.ev), why[said]
            why[said] = np.where(had.astype(bool), had + f"; {text}", text)
        if not self.has_thresholds:
            missing = [t.name for t in self.file.tests if t.high is None]
            if self.ev["combined"] and (self.file.combined is None or self.cmodel.high is None):
                missing.append("the combined test")
            message = f"no thresholds for {', '.join(missing)}: run `diag unit learn {self.name}`"
            status[:] = NE107.CHECK_FUNCTION
        idx = frame.index
        equipment = None
        if self.equipment:  # per piece: running, stopped or settling (equipment.py)
            state = off[2] if off is not None else np.zeros((n, len(self.equipment)), np.int8)
            equipment = pd.DataFrame(state, index=idx, columns=[e.name for e in self.equipment])
        return Diagnosis(
            unit=self.name,
            residuals=r,
            symptoms=pd.DataFrame(s, index=idx, columns=_names(self.tests), copy=False),
            certainties=pd.DataFrame(cert, index=idx, columns=_names(self.faults), copy=False),
            detected=pd.Series(detected, index=idx),
            status=pd.Series(status, index=idx),
            quality=pd.Series(quality, index=idx),
            faults=pd.Series(faults, index=idx),
            message=message,
            combined=combined,
            _contributions=shares,
            top=None if top is None else pd.DataFrame(top, index=idx, columns=_names(top)),
            why=pd.Series(why, index=idx),
            equipment=equipment,
        )

    def _fixed_values(self, frame: pd.DataFrame, guard: FixedGuard) -> np.ndarray:
        """The piece's values of a guard's tags (``[fixed]``, ``[states]``; rows × tags; NaN
        where absent)."""
        out = np.full((len(frame), len(guard.tags)), np.nan)
        for j, (t, p) in enumerate(zip(guard.tags, guard.plant, strict=True)):
            c = p if p in frame.columns else t
            if c in frame.columns:
                out[:, j] = frame[c].to_numpy(float)
        return out

    def _warming(
        self, unknown: np.ndarray, raw_known: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The tests unknown only for the warm-up, and the samples each still needs
        (:func:`~diag_plugin.diagnose.unitloops.warm_up`), on the rows that can be warming
        up (returned first: those before the longest lag is seen, and those a spread window
        still fills; elsewhere no test is): ``rows``, then ``rows × tests`` arrays. Advances
        :attr:`seen`. ``raw_known``: where the raw residuals (before the spread and the
        filter) are finite, samples × tests."""
        n = len(raw_known)
        lag_rows = max(0, min(n, int(self.test_depth.max(initial=0)) - self.seen))
        spread_left = None
        if self.spread_cols.size:  # the spread ran on this piece (Unit.filtered)
            spread_left = self.spread.left_
            filling = np.flatnonzero((spread_left > 0).any(axis=1))
            rows = np.union1d(np.arange(lag_rows), filling)
        else:
            rows = np.arange(lag_rows)
        seen = self.seen + rows
        self.seen += n
        left_at = np.zeros((rows.size, raw_known.shape[1]), np.int64)
        if spread_left is not None:
            left_at[:, self.spread_cols] = spread_left[rows]
        test = np.zeros(raw_known.shape[1], bool)
        test[self.spread_cols] = True
        warm, left = warm_up(unknown[rows], raw_known[rows], seen, self.test_depth, left_at, test)
        return rows, warm, left

    def _settle(self, g, index, cols, r, active, detected, status, faults):
        """The settle guard ``g`` (:mod:`~diag_plugin.diagnose.settle`) over the piece, in
        place on ``status`` and ``faults``; returns the suppressed samples and their whys."""
        n = len(index)
        sp = np.column_stack(
            [cols.values(lp.sp) if lp.sp in cols.columns else np.full(n, np.nan) for lp in g.loops]
        )
        loop_r = r.to_numpy()[:, g.tests]
        u = None if g.envelope is None else scaled(r.to_numpy(), *self._limits())
        sup, why = g.transform(index, sp, loop_r, active, detected == 1.0, u)
        apply_settle(status, faults, sup)
        return sup | (why != ""), why  # and the alarms an envelope raised: their why

    def _hold_alarm(self, active, detected, status, faults, top):
        """The unit's off-delay (:class:`~diag_plugin.diagnose.unitloops.AlarmHold`): a
        sample within it repeats the last alarm sample's status, faults and tags (``top``:
        the ranking's columns as arrays, :func:`~.unittags.top_columns_at`, edited in
        place; a column at a time, not rows of a frame of strings)."""
        src = self.alarm_hold.sources(active)
        held = np.flatnonzero(src >= 0)
        repeated = src >= 0
        detected, status, faults = detected.copy(), status.copy(), faults.copy()
        if held.size:
            detected[held] = 1.0
            status[held] = status[src[held]]
            faults[held] = faults[src[held]]
            if top is not None:
                for col in top.values():
                    col[held] = col[src[held]]
        carried = np.flatnonzero(src == -1)
        if carried.size and self._last_alarm is not None:
            st, fa, row = self._last_alarm
            detected[carried], status[carried], faults[carried] = 1.0, st, fa
            repeated[carried] = True
            if top is not None:
                for c, v in row.items():
                    top[c][carried] = v
        on = np.flatnonzero(active)
        if on.size:
            i = on[-1]
            row = {} if top is None else {c: _plain(v[i]) for c, v in top.items()}
            self._last_alarm = (int(status[i]), str(faults[i]), row)
        return detected, status, faults, top, repeated

    def _hold_isolation(self, iso: np.ndarray, s: np.ndarray, on: np.ndarray, n: int) -> np.ndarray:
        """:class:`~diag_plugin.diagnose.isolation.IsolationHold` over the alarm samples
        ``on`` of the piece's ``n`` (``iso``: their isolated faults, ``s``: every sample's
        symptoms): the hold sees every run of alarm samples, and one sample without a symptom
        before a run (and after the last) where the piece has such samples — what it does on
        every one of them (it forgets its reference) is done once."""
        if not on.size:
            if n:
                self.isolation.has_ref[:] = False
            return iso
        gap = np.r_[on[0] > 0, np.diff(on) > 1]
        at = np.arange(on.size) + np.cumsum(gap)  # each alarm sample's place among them
        m = on.size + int(gap.sum()) + int(on[-1] < n - 1)
        iso_m = np.zeros((m, 1, iso.shape[1]), bool)
        s_m = np.zeros((m, 1, s.shape[1]))
        iso_m[at, 0] = iso
        s_m[at, 0] = s[on]
        return self.isolation.transform(iso_m, s_m)[at, 0, :]

    def _isolate(
        self, cert: np.ndarray, active: np.ndarray, status: np.ndarray, s: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Isolated faults: those with the highest certainty, at least ``certainty``; with
        ``hold_isolation`` fading symptoms do not move them to other faults
        (:mod:`~diag_plugin.diagnose.isolation`)."""
        n = cert.shape[0]
        # only the alarm samples can isolate a fault: the rest are reasoned over as the
        # samples without a symptom they are (the hold forgets its reference on them)
        on = np.flatnonzero(active)
        c = np.nan_to_num(cert[on], nan=0.0)
        best = c.max(axis=1) if c.shape[1] else np.zeros(on.size)
        iso_on = (c >= self.iso_certainty - 1e-12) & (c >= best[:, None] - 1e-12)
        if self.ev["hold_isolation"]:
            iso_on = self._hold_isolation(iso_on, s, on, n)
        fault_status = np.array(
            [int(self.file.fault_status.get(f, NE107.FAILURE)) for f in self.faults], np.int8
        )
        rank = {int(s): i for i, s in enumerate(PRIORITY)}
        prio = np.array([rank[int(s)] for s in fault_status])
        out_status = status.copy()
        faults = np.full(n, "", dtype=object)
        some = iso_on.any(axis=1)
        rows = on[some]
        if not rows.size:
            return out_status, faults
        # one pass per distinct pattern of isolated faults, not per sample
        patterns, inverse = np.unique(iso_on[some], axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        for k, pat in enumerate(patterns):
            sel = np.flatnonzero(pat)
            at = rows[inverse == k]
            faults[at] = "|".join(self.faults[j] for j in sel)
            out_status[at] = fault_status[sel[np.argmin(prio[sel])]]
        return out_status, faults


class LazyShares:
    """Each tag's share of T² per sample for :class:`Diagnosis`: those of the alarm samples
    (``at``) computed now (the episode's ranking reads them), the others when called."""

    def __init__(
        self,
        cmodel: CombinedModel,
        r: np.ndarray,
        at: np.ndarray,
        index,
        point: np.ndarray | None = None,
    ) -> None:
        self.cmodel, self.r, self.at, self.index = cmodel, r, np.asarray(at, bool), index
        self.point = point  # each sample's operating point (CombinedModel.point_of)
        self.share_at = cmodel.shares(r, self.at, point)

    def __call__(self) -> pd.DataFrame:
        out = np.empty((self.r.shape[0], len(self.cmodel.tags)))
        out[self.at] = self.share_at
        out[~self.at] = self.cmodel.shares(self.r, ~self.at, self.point)
        return pd.DataFrame(out, index=self.index, columns=self.cmodel.tags, copy=False)


class _Concat:
    """The contributions of consecutive pieces (frames or :class:`LazyShares`), concatenated
    when called."""

    def __init__(self, parts: list) -> None:
        self.parts = parts

    def __call__(self) -> pd.DataFrame:
        return pd.concat([p() if callable(p) else p for p in self.parts])


def held_text(ev: dict[str, Any]) -> str:
    """Why a unit is in alarm with no symptom on: its off-delay holds the alarm it showed
    (the tag named is the alarm's)."""
    return f"no symptom on: the alarm held for the unit's off-delay ({ev['off_delay_s']:g} s)"


def _plain(v):
    """A numpy scalar as a plain Python value (the carried state is JSON)."""
    return v.item() if hasattr(v, "item") else v


def level_points(unit: Unit) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The tests with operating points of their own (a level test after ``diag unit
    accept``: ``point_center``, ``point_scale`` in the unit file), as the columns, and their
    centres and scales, points × those tests; None where no test has them. Each needs the
    ``[combined]`` operating points that place a sample, as many as it lists: else
    :class:`UnitError`."""
    tests = [(j, t) for j, t in enumerate(unit.file.tests) if t.point_center is not None]
    if not tests:
        return None
    cm = unit.cmodel
    have = 0 if cm is None or cm.centers is None or cm.point_at is None else len(cm.point_at)
    problems = [
        f"{unit.file.path}:{t.line}: test {t.name!r} lists {len(t.point_center)} operating "
        f"points, [combined] has {have}: run `diag unit learn {unit.name}` again"
        for _, t in tests
        if len(t.point_center) != have
    ]
    if problems:
        raise UnitError(problems)
    cols = np.array([j for j, _ in tests], np.intp)
    center = np.array([t.point_center for _, t in tests], float).T
    scale = np.array([t.point_scale for _, t in tests], float).T
    return cols, np.ascontiguousarray(center), np.ascontiguousarray(scale)


def level_factor(levels: tuple[float, ...] | None, level: np.ndarray | None) -> np.ndarray | float:
    """What a residual is divided by, per sample: 1 where the fine grid answered (or the
    method has no levels), the learned scale of the coarser level that answered, NaN (unknown)
    at a level the unit never calibrated (``levels`` None: the fine grid only)."""
    if level is None:
        return 1.0
    table = np.asarray(levels if levels is not None else (1.0,), float)
    lv = np.asarray(level, np.int64)
    ok = (lv >= 0) & (lv < table.size)
    return np.where(ok, table[np.clip(lv, 0, table.size - 1)], np.nan)


def spread_factor(spread: np.ndarray | None) -> np.ndarray | float:
    """What a residual is divided by for the local spread: the answering rules' spread relative
    to the model's (``Prediction.spread``), never below :data:`SPREAD_FLOOR`; 1 where unknown
    or for methods without it."""
    if spread is None:
        return 1.0
    return np.where(np.isfinite(spread), np.maximum(spread, SPREAD_FLOOR), 1.0)


def broken_status(name: str, ts: pd.Timestamp, message: str) -> UnitStatus:
    """What a unit that cannot be evaluated reports: CHECK_FUNCTION with Bad quality."""
    return UnitStatus(
        unit=name, ts=ts, status=NE107.CHECK_FUNCTION, quality=Quality.BAD, message=message
    )


def not_running(d: Diagnosis, why: str | np.ndarray) -> Diagnosis:
    """``d`` (a piece where the unit is stopped, :mod:`~.running`) as not judged: no test's
    symptom, no alarm, no fault, no tag named; CHECK_FUNCTION with ``why`` (one text, or
    one per sample)."""
    n = len(d.status)
    idx = d.status.index
    top = None
    if d.top is not None:
        top = d.top.copy()
        for c in top.columns:
            top[c] = "" if str(c).startswith("top") else np.nan
    return dataclasses.replace(
        d,
        symptoms=d.symptoms * np.nan,
        certainties=d.certainties * 0.0,
        detected=pd.Series(np.full(n, np.nan), index=idx),
        status=pd.Series(np.full(n, NE107.CHECK_FUNCTION, np.int8), index=idx),
        faults=pd.Series(np.full(n, "", dtype=object), index=idx),
        top=top,
        why=pd.Series(np.full(n, why, dtype=object) if isinstance(why, str) else why, index=idx),
    )


def concat(parts: list[Diagnosis]) -> Diagnosis:
    """One diagnosis from consecutive pieces (as :meth:`Unit.evaluate` returned them)."""
    if len(parts) == 1:
        return parts[0]
    first = parts[0]

    def cat(attr: str):
        return pd.concat([getattr(p, attr) for p in parts])

    def opt(attr: str):
        got = [getattr(p, attr) for p in parts]
        return None if any(g is None for g in got) else pd.concat(got)

    return Diagnosis(
        unit=first.unit,
        residuals=cat("residuals"),
        symptoms=cat("symptoms"),
        certainties=cat("certainties"),
        detected=cat("detected"),
        status=cat("status"),
        quality=cat("quality"),
        faults=cat("faults"),
        message=first.message,
        combined=opt("combined"),
        _contributions=None
        if any(p._contributions is None for p in parts)
        else _Concat([p._contributions for p in parts]),
        top=opt("top"),
        why=opt("why"),
        equipment=opt("equipment"),
    )
