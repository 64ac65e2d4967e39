"""A unit's thresholds from a fault-free window: residuals the models did not see, held to a
false-alarm budget.

``diag unit learn`` (:func:`learn_thresholds`) works in three steps.

1. **Residuals the model did not see.** Residuals of the very samples a model was trained on
   are smaller than any it will see later, and thresholds learned from them alarm on the next
   fault-free day. Each test's residuals over the window are *cross-fitted*: the window is cut
   into ``blocks`` consecutive time blocks, and block ``b``'s residuals come from a model that
   did not see block ``b`` (:func:`held_out`): the plant's own model with the block's samples
   taken out of its exact integer accumulators (Wang–Mendel ``wm-avg``), else a model
   retrained (same rule-base file: spans, sets, method, locks) on the other blocks. When the
   model's training range (its file's ``[training] from``/``to``) lies wholly outside the window,
   its own residuals are already out of sample and are used as they are.
2. **Levels and spread.** Where a Wang–Mendel model's fine grid has no rule a coarser level
   answers, less exactly. Each level's residual scale (RMS relative to the fine level's, over
   the window) is learned, and a residual answered at level ``l`` is divided by it, so a coarse
   answer needs a proportionally larger deviation to raise a symptom. A level seen on fewer
   than :data:`MIN_LEVEL_SAMPLES` samples of the window shares the scale of the coarser levels
   it is pooled with until that many are seen (:func:`level_scales`); levels beyond the last
   full pool stay unknown. Each test is also tried
   in units of its model's local spread (the spread of the training outputs of the rules that
   answered, :func:`~diag_plugin.diagnose.unit.spread_factor`), and keeps that form where its
   thresholds come out tighter relative to its residual's RMS (a deviation of a given share
   of the usual one then counts sooner).
3. **The budget.** The scaled residuals are filtered as the unit filters them, and each test's
   two thresholds are placed so that the unit's false alarms (episodes with the on/off delays)
   come at the declared rate per hour of operation, all tests together
   (:mod:`diag_plugin.learn.budget`), saying when the window is too short to show that rate
   and what window would.

With ``combined = true`` or ``isolation = "tags"`` in the unit's ``[evaluation]`` step 3 also
learns the unit-level test and the tag directions (:func:`learn_combined`,
:mod:`diag_plugin.diagnose.unittags`): each test's centre, robust scale and the shrunk
covariance of the scaled residuals, the combined statistic's threshold under its share
(:data:`~diag_plugin.diagnose.unittags.COMBINED_SHARE`) of the same budget, on T² computed from
the cross-fitted residuals with those parameters learned without the block they score, and
each model's mean gain per input tag (:func:`model_gains`).

A test whose residual is missing or exactly zero over the window gets a message naming it and
what to do; nothing is written then.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from diag_plugin.diagnose.residuals import supported
from diag_plugin.diagnose.unit import Unit, level_factor, spread_factor
from diag_plugin.diagnose.unitfile import WHY, CombinedSpec, hours
from diag_plugin.learn.budget import TestBudget, calibrate
from diag_plugin.models.protocol import REASON_NAN, REASON_OUTSIDE, Prediction
from diag_plugin.models.series import autocorrelation

#: samples skipped at the start of a learning window (and of each run in it): the filter
#: starts from rest
SETTLE_SAMPLES = 500
#: the default false-alarm budget: alarms per hour of operation of a unit (about one in six
#: weeks); a plant policy, not something data can tell, so `diag unit learn` prints it
DEFAULT_FAR = 0.001
#: time blocks of the learning window for cross-fitting
DEFAULT_BLOCKS = 5
#: a coarser level answering fewer samples of the window than this is not calibrated
MIN_LEVEL_SAMPLES = 30
#: an input whose values over a fold's training rows lie within this share of their size
#: (at least of 1) never varied there (:func:`unseen_inputs`)
UNSEEN_TOL = 1e-9
#: a test whose thresholds lie beyond this many times its output's span (residuals in % of
#: span or of the maximum) gets a warning naming it: no fault-free residual reaches them
WIDE_LIMITS = 10.0
#: the least threshold on either side of 0 (a band around 0 even for a biased residual)
FLOOR = 1e-4
#: what such a warning says (``diag unit build`` prints each, not among its first notes only)
WIDE_SAID = "no fault-free residual reaches them"
#: known residual values a test needs in the window
MIN_KNOWN = 30
#: ``by_run`` of :func:`learn_thresholds`: the cross-fitting's blocks cut every run (window)
#: into equal spans, block ``b`` the ``b``-th span of each (:func:`block_of`)
WITHIN_RUNS = "within"
#: samples without data that separate two runs of a window (the unit's filter forgets its
#: state after as many, :class:`~diag_plugin.diagnose.residuals.LowPass`)
RUN_GAP = 100


class LearnError(ValueError):
    """The window cannot give thresholds; ``problems`` name each test and what to do."""

    def __init__(self, problems: list[str]):
        super().__init__("\n".join(problems))
        self.problems = problems


@dataclass
class TestResiduals:
    """A test's raw residuals over the window (index = the window's), the level that answered
    each and why each unknown one is unknown."""

    raw: np.ndarray
    level: np.ndarray | None
    unknown: dict[str, int]
    source: str
    #: the answering rules' spread relative to the model's (None: the method keeps none)
    spread: np.ndarray | None = None
    #: where its piece of equipment was stopped (its test off, not unknown: not among the
    #: ``unknown`` reasons; None: no piece, or it ran throughout) and the piece's name
    stopped: np.ndarray | None = None
    piece: str = ""


@dataclass
class Learned:
    """What :func:`learn_thresholds` learned, and what it rests on."""

    limits: dict[str, tuple[float, float]]
    samples: dict[str, int]
    window: tuple[str, str]
    far: float
    blocks: int
    ymax: dict[str, float]
    #: residual scale per rule level and test (level 0 first, 1.0)
    levels: dict[str, list[float]]
    #: per test: residuals in units of the model's local spread (tighter thresholds so)
    spread: dict[str, bool]
    budgets: dict[str, TestBudget]
    #: per test: share of the window unknown, per reason (keys of WHY)
    unknown: dict[str, dict[str, float]]
    #: per test: where its residuals came from
    sources: dict[str, str]
    period: str = "10s"
    warnings: list[str] = field(default_factory=list)
    #: the unit-level test and tag directions (``combined`` or ``isolation = "tags"``)
    combined: CombinedSpec | None = None
    #: per test: breakpoints (n1, n0, p0, p1) of its N, 0, P sets (:func:`fuzzy_sets`)
    fuzzy: dict[str, tuple[float, float, float, float]] = field(default_factory=dict)
    #: per test: what ``diag unit accept`` kept of the unit's thresholds before it, written
    #: beside the test's ``[learned]`` row (:func:`~diag_plugin.unitbuild.accept.never_narrower`)
    kept: dict[str, dict] = field(default_factory=dict)
    #: the filtered, scaled residuals the thresholds were learned from (settled rows; not
    #: written: ``diag unit accept`` reads each window's spread from it)
    body: pd.DataFrame | None = None
    #: per level test, with operating points: each point's centre and relative scale of its
    #: raw residual (:func:`level_points`)
    level_points: dict[str, tuple[list[float], list[float]]] = field(default_factory=dict)
    #: per test of a piece of equipment: the share of the window it was off (its piece
    #: stopped; not unknown) and the piece
    off: dict[str, tuple[float, str]] = field(default_factory=dict)
    #: the scaled held-out residuals over the whole window, before the filter (not written:
    #: a start's envelope is learned from them, as the thresholds are,
    #: :class:`~diag_plugin.unitbuild.loops.HeldOut`)
    scaled: pd.DataFrame | None = None

    @property
    def independent(self) -> dict[str, int]:
        return {k: b.independent for k, b in self.budgets.items()}

    def notes(self) -> dict[str, dict]:
        """The unit file's ``[learned]`` rows: per test its expected false-alarm rate, how the
        thresholds were set, whether the window supports the budget, its unknown share and
        why, and where its residuals came from."""
        out = {}
        for name, b in self.budgets.items():
            why = {k: v for k, v in self.unknown[name].items() if v > 0}
            out[name] = {
                "far": float(f"{b.rate:.3g}"),
                "method": b.method,
                "supported": bool(b.supported),
                "hours": round(b.hours, 1),
                "hours_needed": float(f"{b.hours_needed:.3g}"),
                "independent": int(b.independent),
                "unknown": round(b.unknown, 5),
                **{f"unknown_{k}": round(v, 5) for k, v in why.items()},
                **(
                    {"off": round(self.off[name][0], 5), "off_equipment": self.off[name][1]}
                    if name in self.off
                    else {}
                ),
                "residuals": self.sources[name],
                **self.kept.get(name, {}),
            }
        return out


def _window(frames) -> pd.DataFrame:
    frames = [f for f in frames if len(f)]
    if not frames:
        raise LearnError(["the learning window holds no data"])
    return pd.concat(frames) if len(frames) > 1 else frames[0]


def _training_range(rb) -> tuple[pd.Timestamp, pd.Timestamp] | None:
    """The range the model file says it was trained on (``[training] from``/``to``)."""
    tr = rb.training
    try:
        a, b = pd.Timestamp(str(tr["from"])), pd.Timestamp(str(tr["to"]))
    except (KeyError, ValueError):
        return None
    a = a.tz_localize("UTC") if a.tzinfo is None else a
    b = b.tz_localize("UTC") if b.tzinfo is None else b
    return a, b


def block_of(
    index: pd.DatetimeIndex,
    blocks: int,
    data: np.ndarray | None = None,
    within: bool = False,
    runs: np.ndarray | None = None,
    whole: np.ndarray | None = None,
) -> np.ndarray:
    """Time block (0 … blocks − 1) of each timestamp. A window of several runs (stretches of
    data separated by more than :data:`RUN_GAP` samples without, ``data`` False) is cut between
    runs, consecutive runs grouped into at most ``blocks`` blocks (leave-runs-out: a run's
    residuals come from models that never saw it); otherwise equal spans of time. ``within``
    (and ``data``): each run cut into ``blocks`` equal spans of its own, block ``b`` the
    ``b``-th of every run (``diag unit accept``: each window an operating point, so a block
    held out leaves the models most of every point). ``runs``: each row's run given (the
    caller knows where its runs are: ``diag unit accept``'s windows), not found from the
    gaps in ``data``. ``whole`` (with ``within``): each row True where its run is held out
    whole, as a build holds its window's runs out (``diag unit accept``'s old windows, their
    runs split at gaps of more than :data:`RUN_GAP` rows): two or more such runs grouped into
    at most ``blocks`` blocks, the other runs (the accepted window) each cut in spans; a
    single such run is cut in spans too, as a build cuts a window of one run."""
    if runs is not None:
        if len(runs) != len(index):
            raise ValueError(f"runs has {len(runs)} rows, the index {len(index)}")
        data = np.ones(len(index), bool)  # the runs are given: only their sizes matter
    if within and data is not None and data.size == len(index):
        run = runs_of(data) if runs is None else np.asarray(runs, np.int64)
        out = np.zeros(len(index), np.int64)
        held = [r for r in np.unique(run) if whole is not None and bool(whole[run == r].all())]
        held = held if len(held) >= 2 else []
        for r in np.unique(run):
            rows = np.flatnonzero(run == r)
            if r in held:
                out[rows] = held.index(r) * min(blocks, len(held)) // len(held)
            else:
                out[rows] = block_of(index[rows], blocks)
        return out
    if data is not None and data.size == len(index):
        run = runs_of(data) if runs is None else np.asarray(runs, np.int64)
        n = int(run.max()) + 1 if run.size else 0
        if n >= 2:
            groups = min(blocks, n)
            return (np.maximum(run, 0) * groups // n).astype(np.int64)
    t = (index - index[0]) / (index[-1] - index[0] + pd.Timedelta(1, "ns"))
    return np.minimum((np.asarray(t, float) * blocks).astype(np.int64), blocks - 1)


def settled(data: np.ndarray) -> np.ndarray:
    """Rows whose filtered residual has settled: each run's first :data:`SETTLE_SAMPLES` are
    left out (a quarter of a shorter run), as the filter starts from rest in every run."""
    run = runs_of(data)
    keep = np.ones(data.size, bool)
    for r in np.unique(run):
        rows = np.flatnonzero(run == r)
        n = int(np.count_nonzero(data[rows]))
        first = rows[data[rows]][0] if n else rows[0]
        settle = SETTLE_SAMPLES if n > 4 * SETTLE_SAMPLES else n // 4
        keep[first : first + settle] = False
    return keep


def equipment_settled(unit: Unit, frame: pd.DataFrame, filtered: pd.DataFrame) -> pd.DataFrame:
    """``filtered`` with a piece of equipment's tests (``[equipment]``,
    :mod:`~diag_plugin.diagnose.equipment`) unknown where it has not settled: stopped, and
    each of its runs' first samples as :func:`settled` leaves out a window's (its starts'
    transients, as a unit-wide run condition's starts are left out)."""
    eqs = getattr(unit, "equipment", None)
    if not eqs:
        return filtered
    x = None
    for e, cols in zip(eqs, unit.equipment_tests, strict=True):
        col = unit.file.tags.get(e.rc.tag, e.rc.tag)
        if not cols.size or col not in frame.columns:
            continue
        runs = e.rc.runs(frame[col].to_numpy(float))
        out = ~(runs & settled(runs))
        if out.any():
            x = filtered.to_numpy(float, copy=True) if x is None else x
            x[np.ix_(out, cols)] = np.nan
    if x is None:
        return filtered
    return pd.DataFrame(x, index=filtered.index, columns=filtered.columns)


def runs_of(data: np.ndarray) -> np.ndarray:
    """Run number of each row (stretches of data separated by more than RUN_GAP rows
    without); rows in a gap take the run before them (the first run's number before it)."""
    start = np.flatnonzero(data)
    if not start.size:
        return np.zeros(data.size, np.int64)
    gaps = np.diff(start) - 1
    new = np.r_[0, (gaps > RUN_GAP).astype(np.int64)]
    run_of_data = np.cumsum(new)
    out = np.zeros(data.size, np.int64)
    out[start] = run_of_data
    filled = np.maximum.accumulate(np.where(data, np.arange(data.size), 0))
    return out[filled]


#: ``mapper(fn, items, args)``: ``[fn(item, *args) for item in items]``, in any number of
#: processes, in order (``diag unit build`` passes its worker pool's,
#: :func:`diag_plugin.unitbuild.parallel.map_tests`)
Mapper = Callable[[Callable[..., Any], Sequence[Any], tuple], list[Any]]


def _serial(fn: Callable[..., Any], items: Sequence[Any], args: tuple) -> list[Any]:
    return [fn(it, *args) for it in items]


def test_residuals(
    unit: Unit,
    frame: pd.DataFrame,
    blocks: int,
    cross_fit: bool | None,
    mapper: Mapper | None = None,
    by_run: bool | str = True,
    runs: np.ndarray | None = None,
    whole: np.ndarray | None = None,
    point: np.ndarray | None = None,
) -> dict[str, TestResiduals]:
    """Raw residuals of every test over ``frame``, each block's from a model that did not see
    that block (see :func:`held_out`); ``cross_fit`` False: the models' own residuals;
    ``by_run`` False: equal time blocks even where the window holds several runs;
    :data:`WITHIN_RUNS`: every run cut into equal time blocks (:func:`block_of`). Each
    test's are independent of the others': ``mapper`` may compute them in several
    processes. ``runs``: each row's run, where the caller knows them; ``whole``: the rows of
    runs held out whole (:func:`block_of`); ``point``: each row's operating point (``diag
    unit accept``), a linear test's folds fitted with an intercept per point
    (:func:`_cross_fitted`)."""
    frame = unit._model_frame(frame)
    names = [t.name for t in unit.file.tests]
    args = (unit, frame, blocks, cross_fit, by_run, runs, whole, point)
    got = (mapper or _serial)(_test_residual, names, args)
    missing = [r for r in got if isinstance(r, str)]
    if missing:
        raise LearnError(missing)
    return dict(zip(names, got, strict=True))


def _test_residual(
    name: str,
    unit: Unit,
    frame: pd.DataFrame,
    blocks: int,
    cross_fit: bool | None,
    by_run: bool | str = True,
    given: np.ndarray | None = None,
    whole: np.ndarray | None = None,
    point: np.ndarray | None = None,
) -> TestResiduals | str:
    """One test's residuals for :func:`test_residuals` (a message if the window lacks a tag
    its model reads)."""
    from diag_plugin.diagnose.equipment import learnable_for, output_tag, owner
    from diag_plugin.regressors import DesignBuilder
    from diag_plugin.rulebase.document import RuleBase

    t = next(t for t in unit.file.tests if t.name == name)
    m = unit.models[t.name]
    # a piece of equipment's test learns from the rows where it runs (diagnose/equipment.py)
    eq = owner(getattr(unit, "equipment", ()), output_tag(m.output))
    own = learnable_for(frame, eq)
    try:
        d = DesignBuilder(m.inputs, m.output, period=m.period).transform(own)
    except KeyError as exc:
        return f"test {t.name}: {exc.args[0]}: learn over a window that holds them"
    rows = frame.index.get_indexer(d.index)
    if cross_fit is False or blocks < 2:
        pred, source = m.model.predict_detail(d.X), "the model's own (not cross-fitted)"
    else:
        data = frame.notna().any(axis=1).to_numpy()
        runs = data if by_run else None
        within = by_run == WITHIN_RUNS
        given = given if by_run else None
        block = block_of(frame.index, blocks, runs, within, given, whole)
        said = held_out_said(block, blocks, runs_of(data) if given is None else given, within)
        block = block[rows] if len(rows) else rows
        pred, source = held_out(
            RuleBase.load(m.path), m.model, d, block, blocks, t.name, force=bool(cross_fit),
            said=said if by_run else f"{blocks} time blocks",
            point=point[rows] if point is not None and len(rows) else None,
        )  # fmt: skip
    raw = np.full(len(frame), np.nan)
    raw[rows] = unit.residual(_fine_only(t), d.y, pred)
    level = spread = None
    if pred.level is not None:
        level = np.full(len(frame), -1, np.int64)
        level[rows] = pred.level
    if pred.spread is not None:
        spread = np.full(len(frame), np.nan)
        spread[rows] = pred.spread
    stopped = None
    if eq is not None and eq.rc.tag in frame.columns:
        stopped = eq.stopped(frame[eq.rc.tag].to_numpy(float))
    # its stopped rows are off, not unknown: the reasons are counted on its running rows
    why = _unknown_reasons(len(frame), rows, d.y, pred, unit, stopped)
    return TestResiduals(
        raw, level, why, source, spread, stopped if stopped is not None and stopped.any()
        else None, "" if eq is None else eq.name,
    )  # fmt: skip


def held_out_said(
    block: np.ndarray, blocks: int, run: np.ndarray | None = None, within: bool = False
) -> str:
    """What the cross-fitting held out, as its note says it (``block``: each row's block,
    :func:`block_of`; ``run``: each row's run, None where runs were not looked for): the
    time blocks, the runs held out whole (a window of several runs, as ``diag unit build``
    holds them out), or every run cut in ``blocks`` spans (:data:`WITHIN_RUNS`)."""
    n = len(np.unique(block))
    runs = len(np.unique(run)) if run is not None and len(run) else 1
    if within and runs >= 2:
        cut = sum(len(np.unique(block[run == r])) > 1 for r in np.unique(run))
        if cut < runs:
            return (f"{n} blocks ({runs - cut} runs each held out whole, {cut} cut in "
                    f"{blocks} spans)")  # fmt: skip
        return f"{n} time blocks (each of the {runs} runs cut in {blocks} spans)"
    if run is not None and runs >= 2:
        if n == runs:
            return f"{n} runs (each held out whole)"
        return f"{n} groups of consecutive runs (of {runs}; each run held out whole)"
    return f"{n} time blocks"


def held_out(
    rb,
    model,
    d,
    block: np.ndarray,
    blocks: int,
    test: str,
    *,
    force: bool = False,
    said: str | None = None,
    point: np.ndarray | None = None,
):
    """Each time block's prediction by the model without that block's samples.

    * The model was trained on a range the window overlaps (its file's ``[training]``) and
      keeps exact accumulators (``wm-avg``): each block's samples inside that range are taken
      out of it (:meth:`WangMendelRegressor.without`), so the block is predicted by the model
      the plant runs, minus the block. A block whose samples the model never had (its data
      were not the training data) is predicted by the model as it is.
    * The window lies outside the training range: the model's own prediction (out of sample).
    * Otherwise (other methods, no training range, or ``force``): a model trained from scratch
      on the window's other blocks.

    Returns the prediction over all rows of ``d`` and a sentence saying how it was made
    (``said``: what the blocks are, :func:`held_out_said`; default ``blocks`` time blocks)."""
    said = said or f"{blocks} time blocks"
    trained = _training_range(rb)
    idx = d.index
    outside = trained is not None and len(idx) and (trained[1] <= idx[0] or trained[0] > idx[-1])
    if not force and outside:
        return model.predict_detail(d.X), "the model's own (trained outside the window)"
    exact = getattr(model, "method", None) == "wm-avg" and hasattr(model, "without")
    if force or trained is None or not exact:
        return _cross_fitted(rb, d.X, d.y, block, blocks, test, point), (
            f"cross-fitted: retrained without each of {said}"
        )
    n = len(d.y)
    parts = []
    unseen = 0
    usable = np.isfinite(d.X).all(axis=1) & np.isfinite(d.y)
    inside = np.asarray((idx >= trained[0]) & (idx < trained[1]))
    for b in range(blocks):
        held = block == b
        if not held.any():
            continue
        take = held & inside & usable
        fold = model
        if take.any():
            try:
                fold = model.without(rb.new_model().fit(d.X[take], d.y[take]))
            except ValueError:
                unseen += 1  # the block's samples were never in the model
        parts.append((held, rb.predictor(fold).predict_detail(d.X[held])))
    pred = _assemble(n, parts)
    how = f"cross-fitted: the model without each of {said}"
    if unseen:
        how += f" ({unseen} block(s) never in the model: its own prediction there)"
    return pred, how


def _assemble(n: int, parts) -> Prediction:
    """One prediction over ``n`` rows from per-block predictions ``(rows mask, prediction)``."""
    ys, sup, reason = np.full(n, np.nan), np.zeros(n), np.full(n, 2, np.int8)
    level, spread = np.full(n, -1, np.int8), np.full(n, np.nan)
    has_level = has_spread = False
    for held, p in parts:
        ys[held], sup[held], reason[held] = p.y, p.support, p.reason
        if p.level is not None:
            level[held], has_level = p.level, True
        if p.spread is not None:
            spread[held], has_spread = p.spread, True
    return Prediction(ys, sup, reason, level if has_level else None, spread if has_spread else None)


def _fine_only(t):
    """The test with every level counted at scale 1 and no spread: the plain residual."""
    from dataclasses import replace

    return replace(t, levels=tuple([1.0] * 64), spread=False)


def _cross_fitted(
    rb, X, y, block, blocks: int, test: str, point: np.ndarray | None = None
) -> Prediction:
    """Each block predicted by a model trained from scratch on the other blocks; a linear
    test's with an intercept per operating point where ``point`` gives each row's
    (:func:`~diag_plugin.models.linear.within_merge`, as ``diag unit accept`` merges its
    windows: each fold is then the line the unit runs, less the block)."""
    from diag_plugin.models.linear import is_line

    usable = np.isfinite(X).all(axis=1) & np.isfinite(y)
    parts = []
    for b in range(blocks):
        held = block == b
        train = usable & ~held
        if train.sum() < MIN_KNOWN:
            raise LearnError(
                [
                    f"test {test}: only {int(train.sum())} usable samples outside time block "
                    f"{b + 1} of {blocks}: learn over a longer window or with fewer --blocks"
                ]
            )
        if held.any():
            model = rb.new_model().fit(X[train], y[train])
            if point is not None and is_line(model):
                model = _within_fold(rb, model, X, y, train, point)
            pred = rb.predictor(model).predict_detail(X[held])
            parts.append((held, unseen_inputs(pred, X[train], X[held])))
    return _assemble(len(y), parts)


def _within_fold(rb, model, X, y, train: np.ndarray, point: np.ndarray):
    """A fold's line with an intercept per operating point (:func:`_cross_fitted`): one model
    per point over its training rows (a point with fewer than :data:`MIN_KNOWN` of them
    left out), merged by :func:`~diag_plugin.models.linear.within_merge`; ``model`` (the
    fold's one line) where fewer than two points remain."""
    from diag_plugin.models.linear import within_merge

    spans = [tuple(v) for v in model.spans_]
    parts = []
    for k in np.unique(point[train]):
        at = train & (point == k)
        if at.sum() >= MIN_KNOWN:
            parts.append(rb.new_model().set_params(input_spans=spans).fit(X[at], y[at]))
    if len(parts) < 2:
        return model
    return within_merge(parts)


def unseen_inputs(pred: Prediction, seen: np.ndarray, X: np.ndarray) -> Prediction:
    """``pred`` of rows ``X`` by a fold's model, unknown (``outside``) where an input the
    fold's training rows ``seen`` held at one value takes another: the fold never saw it
    vary, so its model says nothing of what a change does (a line through a pump's
    running rows only, extrapolated to its stopped ones, gave residuals of 10¹⁴ % of span;
    at run time the span guard keeps the plant's model to the range it learned)."""
    if not len(seen) or not len(X):
        return pred
    lo, hi = np.nanmin(seen, axis=0), np.nanmax(seen, axis=0)
    tol = UNSEEN_TOL * np.maximum(1.0, np.abs(lo))
    flat = np.isfinite(lo) & (hi - lo <= tol)
    if not flat.any():
        return pred
    other = (np.abs(X[:, flat] - lo[flat]) > tol[flat]).any(axis=1)
    if not other.any():
        return pred
    y, support, reason = pred.y.copy(), pred.support.copy(), pred.reason.copy()
    y[other], support[other], reason[other] = np.nan, 0.0, REASON_OUTSIDE
    return Prediction(y, support, reason, pred.level, pred.spread)


def _unknown_reasons(
    n: int,
    rows: np.ndarray,
    y: np.ndarray,
    pred: Prediction,
    unit: Unit,
    stopped: np.ndarray | None = None,
) -> dict[str, int]:
    """Samples of the window without a residual, counted by reason
    (:data:`~diag_plugin.diagnose.unitfile.WHY`); ``rows``: the window's row of each of
    ``y``'s. ``stopped`` (the window's rows where the test's piece of equipment was
    stopped): those rows are off, not unknown, and left out of every count, whatever else
    they lack (issue 34: not subtracted from a count over all rows)."""
    run = np.ones(n, bool) if stopped is None else ~stopped
    missing = np.ones(n, bool)
    missing[rows] = ~np.isfinite(y) | (pred.reason == REASON_NAN)
    on = run[rows]
    answered = np.isfinite(pred.y) & np.isfinite(y)
    no_rule = ~np.isfinite(pred.y) & np.isfinite(y) & (pred.reason != 1)
    low = answered & ~np.isfinite(supported(pred, unit.ev["min_support"]))
    return {
        "missing": int(np.count_nonzero(missing & run)),
        "no_rule": int(np.count_nonzero(no_rule & on)),
        "low_support": int(np.count_nonzero(low & on)),
        "level": 0,
    }


def level_scales(raw: np.ndarray, level: np.ndarray | None) -> list[float]:
    """Residual scale of each rule level relative to the fine grid's: the RMS of the residuals
    it answered over the RMS of the fine grid's, never below the finer level's. A level that
    answered fewer than :data:`MIN_LEVEL_SAMPLES` samples is pooled with the coarser levels
    after it until the pool holds that many, and the pool's scale is each of its levels'
    (a thin level between two well-used ones would otherwise leave the coarser one
    uncalibrated, its answers unknown); the list stops before a pool that never fills. A fine
    grid answering fewer than that is pooled the same way into the reference (scale 1)."""
    if level is None:
        return [1.0]
    ok = np.isfinite(raw)

    def rms(sel: np.ndarray) -> tuple[float, int]:
        k = int(sel.sum())
        return (float(np.sqrt(np.mean(raw[sel] ** 2))) if k else math.nan), k

    top = int(level.max()) if level.size else 0
    # the reference: the fine grid, pooled with the coarser levels after it until it holds
    # MIN_LEVEL_SAMPLES (a model whose fine grid is thin everywhere — many inputs, a short
    # window — is judged at the finest level that answers enough, not left all unknown)
    first = 0
    base, k0 = rms(ok & (level == 0))
    while k0 < MIN_LEVEL_SAMPLES and first < top:
        first += 1
        base, k0 = rms(ok & (level >= 0) & (level <= first))
    if k0 < MIN_LEVEL_SAMPLES or not base > 0:
        return [1.0]
    out = [1.0] * (first + 1)
    pool = np.zeros(raw.shape, bool)
    pending = 0
    for lv in range(first + 1, top + 1):
        pool |= ok & (level == lv)
        pending += 1
        r, k = rms(pool)
        if k < MIN_LEVEL_SAMPLES:
            continue
        out.extend([max(r / base, out[-1])] * pending)
        pool[:] = False
        pending = 0
    return out


def learn_thresholds(
    unit: Unit,
    frames,
    *,
    far: float = DEFAULT_FAR,
    blocks: int = DEFAULT_BLOCKS,
    cross_fit: bool | None = None,
    spread: bool = True,
    by_run: bool | str = True,
    mapper: Mapper | None = None,
    points: pd.DataFrame | None = None,
    runs: np.ndarray | None = None,
    whole: np.ndarray | None = None,
    line_points: bool = False,
) -> Learned:
    """Thresholds of every test of ``unit`` from a window the user declares fault-free
    (``frames``: consecutive pieces of it), holding the unit to ``far`` false alarms per hour
    of operation (see the module doc). Raises :class:`LearnError` naming each test the window
    cannot serve and what to do. ``by_run`` :data:`WITHIN_RUNS`: the cross-fitting's block
    ``b`` is the ``b``-th of equal spans of every run (``diag unit accept``: each window an
    operating point, each point's residuals from models that saw most of it). ``by_run``
    False: equal spans of the whole window even where it holds several runs (each run's
    filter still settles on its own). ``mapper``: how the tests' residuals are computed
    (:data:`Mapper`; default one after the other in this process). ``points``: the unit's
    operating points (``diag unit accept``: one row per window it learned, the window's mean
    of each plant tag); with two or more, the combined test's residuals are centred at each
    sample's nearest point and its scale and covariance are the pooled within-point ones
    (:func:`learn_combined`). ``runs``: each row's run (of the window ``frames`` make), where
    the caller knows them — accept's windows, however close in time — instead of runs found
    from gaps of more than :data:`RUN_GAP` rows; ``whole``: the rows of runs held out whole
    (:func:`block_of`). ``line_points``: a linear test too is fitted and centred per point
    (:func:`level_points`; ``diag unit accept`` where a ``[fixed]`` tag moved,
    :func:`~diag_plugin.unitbuild.accept.moved_fixed`)."""
    if blocks < 0 or blocks == 1:
        raise LearnError([f"blocks must be 0 (no cross-fitting) or at least 2, got {blocks}"])
    frame = _window(frames)
    ymax: dict[str, float] = {}
    if unit.ev["scale"] == "max":
        for t in unit.file.tests:
            out = unit.models[t.name].output.split("[")[0]
            out = unit.file.tags.get(out, out)
            v = frame[out].to_numpy(float) if out in frame else np.array([np.nan])
            m = float(np.nanmax(np.abs(v))) if np.isfinite(v).any() else np.nan
            if not np.isfinite(m) or m <= 0:
                raise LearnError(
                    [f"test {t.name}: the maximum of {out} over the window is not positive"]
                )
            t.ymax = ymax[t.name] = m
    data = frame.notna().any(axis=1).to_numpy()
    keep = settled(data)
    located = at = None
    if points is not None and len(points) >= 2:
        # each sample's operating point, placed as the combined test places it (the spans
        # over the settled samples it learns from)
        found = operating_points(frame.loc[keep], points, place=frame)
        if found is not None:
            at, fields = found
            located = (at[keep], fields)
    res = test_residuals(unit, frame, blocks, cross_fit, mapper, by_run, runs, whole,
                         at if line_points else None)  # fmt: skip
    problems = _check(res, unit)
    if problems:
        raise LearnError(problems)
    lp = {}
    if unit.ev["combined"] or unit.ev["isolation"] == "tags":
        blocked = block_of(frame.index, max(blocks, 1), data if by_run else None,
                           by_run == WITHIN_RUNS, runs if by_run else None, whole)  # fmt: skip
        lp = level_points(unit, frame, res, at, keep, blocked, line_points)
    # each test's residual, in units of its model's local spread where the model has one,
    # divided by the scale of the level that answered
    scaled, scales, in_spread = {}, {}, {}
    for t in unit.file.tests:
        r = res[t.name]
        in_spread[t.name] = bool(spread and r.spread is not None)
        x = r.raw / spread_factor(r.spread) if in_spread[t.name] else r.raw
        scales[t.name] = table = level_scales(x, r.level)
        if r.level is not None:
            i = np.clip(r.level, 0, len(table) - 1)
            x = x / np.where(r.level < len(table), np.asarray(table)[i], np.nan)
            r.unknown["level"] = int((np.isfinite(r.raw) & (r.level >= len(table))).sum())
        scaled[t.name] = x
    unit.reset()
    held = pd.DataFrame(scaled, index=frame.index, columns=unit.tests)
    filtered = unit.filtered(held)  # a copy: ``held`` is kept for the envelope
    unit.reset()
    filtered = equipment_settled(unit, frame, filtered)
    body = filtered[settled(frame.notna().any(axis=1).to_numpy())]
    problems = _check_body(body)
    if problems:
        raise LearnError(problems)
    from diag_plugin.diagnose.unittags import COMBINED_SHARE

    far_tests = far * (1.0 - COMBINED_SHARE) if unit.ev["combined"] else far
    budgets = calibrate(body, unit.period, far_tests, on_delay=unit.ev["on_delay"],
                        off_delay=unit.ev["off_delay"], mapper=mapper)  # fmt: skip
    off = {}
    for name, b in budgets.items():  # unknown over the whole window, as the reasons count it
        unknown = ~np.isfinite(scaled[name])
        stopped = res[name].stopped
        if stopped is not None:  # a piece of equipment stopped: its test off, not unknown
            unknown &= ~stopped
            off[name] = (float(np.mean(stopped)), res[name].piece)
        b.unknown = float(np.mean(unknown))
    limits = {
        k: (min(b.low, -FLOOR), max(b.high, FLOOR)) for k, b in budgets.items()
    }  # a band around 0 even for a biased residual
    spreads = set()
    for t in unit.file.tests:  # a spread is never negative: only its high side is a test
        if getattr(t, "statistic", "level") == "spread" and t.name in limits:
            limits[t.name] = (-limits[t.name][1], limits[t.name][1])
            spreads.add(t.name)
    fuzzy = {k: fuzzy_sets(body[k].to_numpy(), *limits[k]) for k in limits}
    idx = frame.index
    period = pd.Timedelta(unit.period)
    window = (idx[0].isoformat(), (idx[-1] + period).isoformat())
    unknown = {name: {k: v / len(frame) for k, v in r.unknown.items()} for name, r in res.items()}
    warnings = []
    dt_h = period / pd.Timedelta(hours=1)
    span = (len(frame) * dt_h, len(frame) - len(body), dt_h)  # the window, settling, period
    for name, b in budgets.items():
        if not b.supported:
            warnings.append(
                f"{name}: {too_few(b.hours, *span)} to support {far_tests:g} per hour (a "
                f"window of {hours(b.hours_needed)} would); thresholds extrapolated by a "
                f"{b.method} fit"
            )
    warnings += wide_limits(limits, in_spread, unit.ev["scale"] == "max")
    warnings += one_sided(
        {k: (b.low, b.high) for k, b in budgets.items() if k not in spreads}, body
    )
    combined = None
    if unit.ev["combined"] or unit.ev["isolation"] == "tags":
        block = blocked[keep]
        combined = learn_combined(
            unit,
            body,
            block,
            far * COMBINED_SHARE if unit.ev["combined"] else None,
            model_gains(unit, frame, mapper, scales, in_spread),
            located,
            mapper=mapper,
        )
        combined.responses = setpoint_responses(
            unit, frame.loc[body.index], body, combined, None if located is None else located[0]
        )
        n = combined.notes
        if unit.ev["combined"] and not n.get("supported", True):
            warnings.append(
                f"combined test: {too_few(n['hours'], *span)} to support {n['far']:g} per "
                f"hour (a window of {hours(n['hours_needed'])} would); threshold extrapolated "
                f"by a {n['method']} fit"
            )
    return Learned(
        limits=limits,
        samples={k: b.samples for k, b in budgets.items()},
        window=window,
        far=far,
        blocks=blocks if any("cross-fitted" in r.source for r in res.values()) else 0,
        ymax=ymax,
        levels=scales,
        spread=in_spread,
        budgets=budgets,
        unknown=unknown,
        sources={k: r.source for k, r in res.items()},
        period=unit.period,
        warnings=warnings,
        combined=combined,
        fuzzy=fuzzy,
        level_points=lp,
        body=body,
        off=off,
        scaled=held,
    )


def too_few(used_h: float, window_h: float, settling: int, dt_h: float) -> str:
    """What a test's budget was calibrated on, for the note that it is too short: ``used_h``
    hours of residual with a value (:func:`~diag_plugin.learn.budget.calibrate`'s ``hours``)
    out of the window's ``window_h`` (its rows × the period ``dt_h``), less ``settling`` rows
    left out while the filter settles (:func:`settled`: the first :data:`SETTLE_SAMPLES` of
    each run, a quarter of a shorter run) and the hours without a value (inputs missing or
    out of range, equipment stopped), said only from 1 % of the window. The figure was
    called "the window" until 2026-12-02, which read 72 h for a 96-h window at 3 min."""
    settle_h = settling * dt_h
    unknown_h = window_h - settle_h - used_h
    rest = f" and {hours(unknown_h)} without a value" if unknown_h >= 0.01 * window_h else ""
    return (
        f"{hours(used_h)} of residual — the window's {hours(window_h)} less "
        f"{hours(settle_h)} ({settling:,} samples) while the filter settles{rest} — show too "
        "few alarms"
    )


def wide_limits(
    limits: dict[str, tuple[float, float]], in_spread: dict[str, bool], of_max: bool = False
) -> list[str]:
    """A warning per test whose thresholds lie beyond :data:`WIDE_LIMITS` times its output's
    span (its residual in % of span, or of the maximum with ``of_max``; a test in units of
    its model's spread is not judged): no fault-free residual reaches such a band, so the
    test never alarms — a model that extrapolated where the cross-fitting held a block out."""
    unit = "% of its maximum" if of_max else "% of span"
    out = []
    for name, (lo, hi) in limits.items():
        if in_spread.get(name) or max(abs(lo), abs(hi)) <= 100.0 * WIDE_LIMITS:
            continue
        times = max(abs(lo), abs(hi)) / 100.0
        out.append(
            f"{name}: thresholds {lo:+.4g} … {hi:+.4g} {unit}, {times:.3g} times its output's "
            f"span: {WIDE_SAID} (a model that extrapolated where the "
            f"cross-fitting held a block out); build over a longer window or check its inputs"
        )
    return out


def one_sided(bounds: dict[str, tuple[float, float]], body: pd.DataFrame) -> list[str]:
    """A warning per test whose fault-free residual stays on one side of 0 over the window
    (its budget's bound on the other side past 0, ``bounds`` before the :data:`FLOOR`): that
    side's threshold is the floor, so any residual across 0 alarms -- a model that does not
    fit the window (a transmitter drifted since the build, another operating point; issue 34,
    H8: such a window wrote fuzzy ramps the unit file then refused to read)."""
    out = []
    for name, (lo, hi) in bounds.items():
        if lo < -FLOOR and hi > FLOOR:
            continue
        side, other, floor = ("above", "low", -FLOOR) if lo >= -FLOOR else ("below", "high", FLOOR)
        med = float(np.nanmedian(body[name].to_numpy(float))) if name in body else math.nan
        out.append(
            f"{name}: its residual stays {side} 0 over the window (median {med:+.4g}): its "
            f"{other} threshold is the floor {floor:g}, so any residual across 0 alarms; its "
            "model does not fit this window (a drifted transmitter, another operating "
            "point?): build over it, or learn over a window the model fits"
        )
    return out


def robust_sd(residual: np.ndarray) -> float:
    """1.4826 × the median absolute deviation of the finite values (0 when none)."""
    x = residual[np.isfinite(residual)]
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) if x.size else 0.0


def fuzzy_sets(residual: np.ndarray, low: float, high: float) -> tuple[float, float, float, float]:
    """Breakpoints ``(n1, n0, p0, p1)`` of a test's N, 0, P sets (our signed three-valued evaluation
    behind seed 001's big/small) from its fault-free residuals and its thresholds: each ramp is
    centred on its threshold (μ = 0.5 there, so the fuzzy and crisp evaluations detect at the same
    residual) and is two robust standard deviations (1.4826 × MAD) of the fault-free residual wide —
    a residual one standard deviation past the threshold is wholly N or P, one short of it wholly 0
    — never reaching past zero."""
    sd = robust_sd(residual)
    up, dn = min(sd, 0.999 * high), min(sd, 0.999 * -low)
    return (low - dn, low + dn, high - up, high + up)


def _check(res: dict[str, TestResiduals], unit: Unit) -> list[str]:
    """A message per test whose residual the window cannot give: none at all, or zero."""
    out = []
    for name, r in res.items():
        known = np.isfinite(r.raw)
        if known.sum() < MIN_KNOWN:
            why = max(r.unknown, key=lambda k: r.unknown[k])
            out.append(
                f"test {name}: only {int(known.sum())} known residual values in the window "
                f"(need {MIN_KNOWN}); mostly unknown because of {WHY[why]}: learn over a "
                "window where its model's tags are present and inside its trained region"
            )
        elif not np.any(r.raw[known]):
            out.append(
                f"test {name}: its residual is exactly zero over the window: the model "
                f"reproduces {unit.models[name].output} exactly (is the output among its own "
                "inputs, or constant over the window?); remove the test or give its model "
                "inputs that do not contain the output, or learn over a window where it varies"
            )
    return out


def _check_body(body: pd.DataFrame) -> list[str]:
    out = []
    for name in body.columns:
        v = body[name].to_numpy(float)
        v = v[np.isfinite(v)]
        if v.size < MIN_KNOWN:
            out.append(
                f"test {name}: only {v.size} known filtered residual values after the filter "
                f"settles (up to {SETTLE_SAMPLES} samples a run): learn over a longer window"
            )
        elif not np.ptp(v) > 0:
            out.append(
                f"test {name}: its filtered residual is constant over the window; learn over "
                "a window where its output varies"
            )
    return out


def operating_points(
    frame: pd.DataFrame, points: pd.DataFrame, place: pd.DataFrame | None = None
) -> tuple[np.ndarray, dict[str, list]] | None:
    """Each row's operating point among ``points`` (one row per point: its mean of each plant
    tag, the columns) and how a sample is placed: the nearest point, each tag's distance in its
    span over ``frame`` (the joint test's rule,
    :meth:`~diag_plugin.models.joint.JointRegressor.nearest`), over the tags known at the
    row. Tags ``frame`` lacks, without a finite mean at every point or constant over the
    window are left out (None: no tag is left). Returns the points per row and the
    :class:`~diag_plugin.diagnose.unitfile.CombinedSpec` fields ``point_tags``, ``point_at``,
    ``point_span``. ``place``: the rows whose points are returned (default ``frame``'s)."""
    from diag_plugin.diagnose.unittags import CombinedModel

    tags = [c for c in points.columns if c in frame.columns]
    at = points[tags].to_numpy(float)
    x = frame[tags].to_numpy(float)
    with np.errstate(invalid="ignore"):
        span = np.nanmax(x, axis=0) - np.nanmin(x, axis=0) if len(x) else np.zeros(len(tags))
    keep = np.isfinite(at).all(axis=0) & (np.nan_to_num(span) > 0)
    fields = {
        "point_tags": [t for t, k in zip(tags, keep, strict=True) if k],
        "point_at": at[:, keep].tolist(),
        "point_span": span[keep].tolist(),
    }
    if not fields["point_tags"]:
        return None
    model = CombinedModel(
        [], np.zeros(0), np.ones(0), np.eye(0), np.zeros((0, 0)), None,
        centers=np.zeros((len(at), 0)), point_tags=fields["point_tags"],
        point_at=at[:, keep], point_span=span[keep],
    )  # fmt: skip
    return model.point_of(frame if place is None else place), fields


def is_level_test(unit: Unit, name: str) -> bool:
    """A test of a tag against its mean (:func:`~diag_plugin.unitbuild.short.level_test`: a
    model without inputs), judged by its level."""
    t = unit.file.test(name)
    return not unit.models[name].inputs and getattr(t, "statistic", "level") == "level"


def is_line_test(unit: Unit, name: str) -> bool:
    """A linear test with inputs (:func:`~diag_plugin.models.linear.is_line`: not a joint
    test, which learns its points itself, :func:`~diag_plugin.models.joint.add_point`)
    judged by its level: one set of coefficients over every operating point."""
    from diag_plugin.models.linear import is_line

    t = unit.file.test(name)
    return is_line(unit.models[name].model) and getattr(t, "statistic", "level") == "level"


def level_points(
    unit: Unit,
    frame: pd.DataFrame,
    res: dict[str, TestResiduals],
    point: np.ndarray | None,
    keep: np.ndarray,
    block: np.ndarray,
    lines: bool = False,
) -> dict[str, tuple[list[float], list[float]]]:
    """Per level test (:func:`is_level_test`) with operating points (``point``: each
    sample's, None: one), each point's centre and relative scale of its raw residual; and
    ``res``' raw residuals of those tests replaced, in place, by the tag against its point's
    mean, scaled at the point: ``(y − m_k) · 100 / span / s_k``, the unit's own operation at
    run time (:meth:`~diag_plugin.diagnose.unit.Unit.at_points`: ``(r − c_k) / s_k`` with
    ``r`` the model's residual and ``c_k = (m_k − ŷ) · 100 / span``). ``m_k`` is the mean of
    the tag over the point's samples — cross-fitted as the tests' residuals are (``block``:
    each row's time block; a cross-fitted test's row takes its point's mean over the other
    blocks): the model's one constant, held out block by block, moved with the slow wander
    of the window that weighs most (SKAB's calibration hour) and put that wander into every
    other point's residuals. ``s_k`` is the robust scale (1.4826 MAD) of the point's residuals
    *as the thresholds judge them* (filtered by the unit's low-pass, over the settled samples
    ``keep``), relative to the quietest point's (≥ 1; the joint test's ``spread``,
    :mod:`~diag_plugin.models.joint`).

    A level test has no input that says where the plant is, so after ``diag unit accept``
    its one mean was the mean over every window and its thresholds spanned the distance
    between the points. A point without two known residuals keeps the model's mean and
    scale 1.

    With ``lines``, a linear test with inputs (:func:`is_line_test`) is centred the same
    way, at its point's mean residual ``c_k`` (cross-fitted as above: a row's point mean
    over the other blocks):
    one line fitted over every window misses an input that tells the points apart where it
    was constant over the build window (a set-point the operator moved since, which no test
    reads: it was constant when the tests were chosen), so each point keeps an offset of its
    own, and one band held both: an aeration basin's blower and valve tests doubled their
    bands when a day at a new oxygen set-point was accepted into 14 days at the old one, and
    the diffuser fouling's detection fell 52.9 → 31.1 % (acceptance pass 11). A per-point
    offset is what the set-point as an input would add to the line (a term of its own per
    value it held); a test whose inputs do tell the points apart keeps ``c_k`` near 0."""
    from diag_plugin.diagnose.residuals import LowPass
    from diag_plugin.regressors import InputSpec

    out: dict[str, tuple[list[float], list[float]]] = {}
    if point is None or not point.size:
        return out
    P = int(point.max()) + 1
    mf = unit._model_frame(frame)
    names, centred, centres = [], [], {}
    for name, r in res.items():
        if np.isfinite(r.raw).sum() < 2:
            continue
        if lines and is_line_test(unit, name):
            c, x = _line_points(r, point, P, block)
            names.append(name)
            centred.append(x)
            centres[name] = c
            continue
        if not is_level_test(unit, name):
            continue
        t, m = unit.file.test(name), unit.models[name]
        tag = InputSpec.parse(m.output).tags[0]
        if tag not in mf.columns:
            continue
        scale = t.ymax if unit.ev["scale"] == "max" and t.ymax else m.span
        y = mf[tag].to_numpy(float)
        ok = np.isfinite(r.raw) & np.isfinite(y)
        yhat = float(m.model.predict_detail(np.zeros((1, 0))).y[0])
        mean, own = _point_means(y, ok, point, P, block, "cross-fitted" in r.source, yhat)
        c = np.array([float(f"{v:.6g}") for v in (mean - yhat) * 100.0 / scale])
        x = np.where(np.isfinite(own), (y - own) * 100.0 / scale, r.raw - c[point])
        x[~np.isfinite(r.raw)] = np.nan
        names.append(name)
        centred.append(x)
        centres[name] = c
    if not names:
        return out
    X = np.column_stack(centred)
    ev = unit.ev
    if ev["lowpass"] > 0:
        X = LowPass(ev["lowpass"], ev["order"]).transform(X)
    for j, name in enumerate(names):
        sd = np.full(P, np.nan)
        for k in range(P):
            v = X[keep & (point == k), j]
            if np.isfinite(v).sum() >= 2:
                sd[k] = float(_centre_scale(v[:, None])[1][0])
        low = np.nanmin(sd) if np.isfinite(sd).any() else np.nan
        s = np.where(np.isfinite(sd) & (low > 0), sd / low, 1.0)
        s = np.array([float(f"{v:.6g}") for v in s])
        res[name].raw = centred[j] / s[point]
        out[name] = (centres[name].tolist(), s.tolist())
    return out


def _point_means(
    v: np.ndarray, ok: np.ndarray, point: np.ndarray, n_points: int, block: np.ndarray,
    crossed: bool, base: float,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Each point's mean of ``v`` over its rows ``ok`` (``base`` where it has under two) and
    each row's point mean, held out as the residuals are (``crossed``: a row's point mean
    over the other blocks; NaN where the point has under two rows)."""
    mean = np.full(n_points, base)
    own = np.full(len(v), np.nan)
    for k in range(n_points):
        at = ok & (point == k)
        if at.sum() < 2:
            continue
        mean[k] = float(np.mean(v[at]))
        own[at] = mean[k]
        if crossed:
            for b in np.unique(block[at]):
                rest = at & (block != b)
                if rest.sum() >= 2:
                    own[at & (block == b)] = float(np.mean(v[rest]))
    return mean, own


def _line_points(
    r: TestResiduals, point: np.ndarray, n_points: int, block: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """A linear test's per-point centres ``c_k`` (its mean raw residual at point ``k``, 0
    where the point has under two) and its raw residuals centred at them, a row of a
    cross-fitted test at its point's mean over the other blocks (:func:`level_points`)."""
    raw = r.raw
    ok = np.isfinite(raw)
    c, own = _point_means(raw, ok, point, n_points, block, "cross-fitted" in r.source, 0.0)
    c = np.array([float(f"{v:.6g}") for v in c])
    x = np.where(np.isfinite(own), raw - own, raw - c[point])
    x[~ok] = np.nan
    return c, x


#: the smallest residual scale the combined test takes, in % of the span: one count of a
#: 16-bit converter over the span. A test that fits a computed tag exactly (a valve command
#: from its split-range output, shut most of the window) leaves residuals of float rounding:
#: a robust scale of 2e-77 %, a variance of 8e+150 of its scaled residual, a ``T²`` of
#: 1e-199 with negative values, and a limit fitted to that (docs/explanation/acceptance-ahu.md);
#: no transmitter resolves a span finer than this
RESOLUTION_PCT = 100.0 / 2**16


def _centre_scale(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Median and robust scale (1.4826 MAD; the sd where the MAD is 0, else 1) of each
    column of ``x`` (a column never known: NaN and 1); a scale is at least
    :data:`RESOLUTION_PCT`."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a column never known: NaN
        center = np.nanmedian(x, axis=0)
        scale = 1.4826 * np.nanmedian(np.abs(x - center), axis=0)
        sd = np.nanstd(x, axis=0)
    scale = np.where(scale > 0, scale, np.where(sd > 0, sd, 1.0))
    return center, np.maximum(scale, RESOLUTION_PCT)


#: the one-sided tail probability at which :func:`predictive_widening` matches Student's t to
#: the normal distribution (a 3.1σ excursion of a test known exactly)
PREDICTIVE_TAIL = 0.001


def predictive_widening(n_eff: np.ndarray, tail: float = PREDICTIVE_TAIL) -> np.ndarray:
    """How much wider than the window's robust scale each test's residual is taken in the
    combined ``T²``, from the independent values ``n_eff`` its window holds
    (:func:`~diag_plugin.models.series.effective_samples`). A centre and a scale learned
    from ``n`` independent values leave a new value's standardised distance Student-t
    distributed with ``ν = n − 1`` degrees of freedom (the predictive distribution; the
    Gaussian budget's thresholds use the same, :mod:`~diag_plugin.learn.budget`); the factor
    is the ratio of its quantile to the normal's at ``tail``, ``t_ν⁻¹(1 − tail) / Φ⁻¹(1 −
    tail)``, at least 1 (``ν`` at least 1): 3.3 at 4 values, 1.4 at 10, 1.16 at 20, 1.03 at
    100. A test whose residual wanders slower than the window (a temperature in 400 s of a
    1 s rig: 3–10 values) then weighs in ``T²`` what its window can vouch for, not the
    ``(spread seen / spread learned)²`` of a level the window never showed, and no longer
    sets the tail of ``T²`` (nor, through the threshold's extrapolation from that tail, its
    limit) on fault-free data outside the window; a test the window knows well is
    unchanged."""
    from scipy import stats

    nu = np.maximum(np.asarray(n_eff, float) - 1.0, 1.0)
    return np.maximum(stats.t.isf(tail, nu) / stats.norm.isf(tail), 1.0)


def _combined_params(
    x: np.ndarray, point: np.ndarray | None = None, independent: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Centre (median), robust scale (1.4826 MAD; the sd where the MAD is 0) of each column of
    fault-free filtered residuals ``x`` (n × T), the covariance of the scaled residuals over
    the rows where all are known, shrunk toward its diagonal by ``λ = T / (T + n_eff)``, and
    ``λ`` (:mod:`~diag_plugin.diagnose.unittags`). The scale returned is widened to each
    test's predictive spread (:func:`predictive_widening` of its independent values), the
    covariance left that of the window's scaled residuals.

    With ``point`` (each row's operating point, :func:`operating_points`) the centre and the
    scale are one row per point (points × T: each point's own; NaN for a point without rows;
    the whole window's for a test never known at a point), and the covariance is that of the
    residuals scaled at their own point: the pooled within-point scatter, not the spread
    between the points (nor one point's noise taken for another's: SKAB's pump vibrates
    four times as much at its calibration run's flow). Each test's independent values are
    then those of its residual within each point, summed over the points (``independent``,
    per test): the windows are separate runs, and a wander over the longer one does not make
    the shorter one's values fewer."""
    from diag_plugin.models.series import effective_samples

    if point is not None:
        P = int(point.max()) + 1 if point.size else 1
        centers = np.full((P, x.shape[1]), np.nan)
        scales = np.full((P, x.shape[1]), np.nan)
        whole = _centre_scale(x)
        for p in np.unique(point):
            c, s_ = _centre_scale(x[point == p])
            unknown = ~np.isfinite(x[point == p]).any(axis=0)
            centers[p] = np.where(unknown, whole[0], c)
            scales[p] = np.where(unknown, whole[1], s_)
        with np.errstate(invalid="ignore"):
            z = (x - centers[point]) / scales[point]
        each = np.zeros(x.shape[1])
        for p in np.unique(point):
            zp = z[point == p]
            zp = zp[np.isfinite(zp).all(axis=1)]
            each += [effective_samples(zp[:, j]) for j in range(x.shape[1])]
        c0, s0, cov, lam = _combined_params(z, independent=each)
        return centers + c0 * scales, scales * s0, cov, lam

    T = x.shape[1]
    center, scale = _centre_scale(x)
    z = (x - center) / scale
    rows = np.isfinite(z).all(axis=1)
    if rows.sum() <= T + 1:
        return center, scale, np.eye(T), 1.0
    cov = np.atleast_2d(np.cov(z[rows].T))
    each = np.array([effective_samples(z[rows, j]) for j in range(T)])
    lam = T / (T + max(float(each.min()), 1.0))
    cov = (1.0 - lam) * cov + lam * np.diag(np.diag(cov))
    # the covariance is that of the window's z; each test enters T² at its predictive spread
    return (
        center,
        scale * predictive_widening(each if independent is None else independent),
        cov,
        float(lam),
    )


def _combined_part(
    b: int | None,
    x: np.ndarray,
    block: np.ndarray,
    n_blocks: int,
    point: np.ndarray | None,
    whole: tuple[np.ndarray, np.ndarray] | None,
):
    """One share of :func:`learn_combined`: ``b`` None, the whole window's parameters
    (:func:`_combined_params`); else T² of block ``b``'s rows from the parameters of the other
    blocks (``whole``: the whole window's centre and scale, for a point only block ``b``
    has)."""
    from diag_plugin.diagnose.unittags import CombinedModel

    if b is None:
        return _combined_params(x, point)
    T = x.shape[1]
    held = block == b
    fit = x[~held] if n_blocks > 1 else x
    if point is None:
        c, s, S, _ = _combined_params(fit)
        return CombinedModel([], c, s, S, np.zeros((T, 0)), None).evaluate(x[held])[0]
    center, scale = whole
    c, s, S, _ = _combined_params(fit, point[~held] if n_blocks > 1 else point)
    pad = np.full((max(0, center.shape[0] - c.shape[0]), T), np.nan)
    c = np.where(np.isfinite(np.vstack([c, pad])), np.vstack([c, pad]), center)
    s = np.where(np.isfinite(np.vstack([s, pad])), np.vstack([s, pad]), scale)
    # (a point only the held block has: its centre and scale from the whole window)
    model = CombinedModel([], c[0], s[0], S, np.zeros((T, 0)), None, centers=c, scales=s)
    return model.evaluate(x[held], point[held])[0]


def _with_outside(
    outside: np.ndarray, x_all: np.ndarray, center: np.ndarray, scale: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The combined test's parameters over the tests ``T²`` is taken over (``center`` and
    ``scale`` one row, or one row per operating point; ``cov``) written out for every test
    of the unit, in its order: a test kept out (``outside``,
    :func:`~diag_plugin.diagnose.unittags.outside_tests`) gets the whole window's centre and
    robust scale of its residuals ``x_all`` (the file's checks want them; ``T²`` never reads
    them) and the identity's row and column of the covariance."""
    inside = ~outside
    c_out, s_out = _centre_scale(x_all[:, outside])
    shape = center.shape[:-1] + (outside.size,)
    c, s = np.empty(shape), np.empty(shape)
    c[..., inside], s[..., inside] = center, scale
    c[..., outside], s[..., outside] = c_out, s_out
    full = np.eye(outside.size)
    full[np.ix_(inside, inside)] = cov
    return c, s, full


def learn_combined(
    unit: Unit,
    body: pd.DataFrame,
    block: np.ndarray,
    far: float | None,
    gains: dict[str, dict[str, float]],
    located: tuple[np.ndarray, dict[str, list]] | None = None,
    *,
    mapper: Mapper | None = None,
) -> CombinedSpec:
    """The unit-level test from the settled, filtered, cross-fitted fault-free residuals
    ``body`` (one column per test, ``block``: each row's time block): centre, scale and shrunk
    covariance (:func:`_combined_params`) over the whole window, and, with a budget ``far``
    (alarms per hour: the combined test's share), the threshold of T² calibrated on T² of each
    block computed with parameters learned without that block (out of sample, like the
    residuals), with the unit's on/off delays
    (:func:`~diag_plugin.learn.budget.calibrate_side`); where the window is too short even
    for a tail fit, Rice's Gaussian rate is fitted to √T² (Gaussian-tailed) rather than to the
    skewed T².

    ``located``: each row's operating point and how a sample is placed
    (:func:`operating_points`). Then each test's residual is centred and scaled at its row's
    point and the covariance is the pooled within-point one (:func:`_combined_params`):
    a level that differs between the points (a tag no model predicts, tested against its
    window's mean) no longer counts as fault-free scatter (SKAB: the threshold grew 49.5 →
    125,671 when the anomaly-free run's first hour was accepted into a unit built from
    valve1/1's first 400 s, and the fault went unseen). The held-out blocks' T² takes a
    point's centre from the whole window where the other blocks hold none of its rows.

    ``mapper`` (:data:`Mapper`) computes the whole window's parameters and each held-out
    block's T² (independent of each other) in any number of processes."""
    from diag_plugin.diagnose.unittags import outside_tests

    x_all = body[unit.tests].to_numpy(float)
    outside = outside_tests(unit)
    x = x_all if outside is None else x_all[:, ~outside]  # the tests T² is taken over
    point = None if located is None else located[0]
    blocks = np.unique(block)
    run = mapper or _serial
    held_t2: list[np.ndarray] = []
    if point is None:  # the blocks need nothing of the whole window's parameters
        parts = (
            run(_combined_part, [None, *blocks.tolist()], (x, block, blocks.size, None, None))
            if far is not None
            else [_combined_params(x)]
        )
        (center, scale, cov, lam), held_t2 = parts[0], parts[1:]
    else:
        center, scale, cov, lam = _combined_params(x, point)
        if far is not None:
            held_t2 = run(
                _combined_part, blocks.tolist(), (x, block, blocks.size, point, (center, scale))
            )
    if outside is not None:
        center, scale, cov = _with_outside(outside, x_all, center, scale, cov)
    spec = CombinedSpec(
        tests=list(unit.tests),
        center=(center if point is None else center[0]).tolist(),
        scale=(scale if point is None else scale[0]).tolist(),
        cov=cov.tolist(),
        shrinkage=lam,
        gains=gains,
    )
    if point is not None and located is not None:
        spec.point_center, spec.point_scale = center.tolist(), scale.tolist()
        for k, v in located[1].items():
            setattr(spec, k, v)
    if far is None:
        return spec
    t2 = np.full(len(x), np.nan)
    for b, got in zip(blocks.tolist(), held_t2, strict=True):
        t2[block == b] = got
    dt_h = pd.Timedelta(unit.period) / pd.Timedelta(hours=1)
    h = float(np.isfinite(t2).sum()) * dt_h
    high, side = combined_threshold(t2, h, far, unit.ev["on_delay"], unit.ev["off_delay"])
    spec.high = high
    spec.notes = {
        "far": float(f"{far:.3g}"),
        "method": side.method,
        "supported": bool(side.supported),
        "hours": round(h, 1),
        "hours_needed": float(f"{side.hours_needed:.3g}"),
    }
    return spec


#: the few-values rule (:func:`~diag_plugin.learn.budget.calibrate_side`'s ``few``) of the
#: combined test's T²: off (:func:`combined_threshold`)
COMBINED_FEW = 0.0


def combined_threshold(t2: np.ndarray, hours: float, far: float, on_delay: int,
                       off_delay: int):  # fmt: skip
    """The combined test's threshold on its held-out T² (``t2``, NaN unknown; ``hours`` of
    operation, the budget ``far`` per hour, the unit's delays) and the
    :class:`~diag_plugin.learn.budget.SideThreshold` it rests on
    (:func:`~diag_plugin.learn.budget.calibrate_side`): where the window holds too few
    episodes for a tail, Rice's Gaussian rate fitted to the distance √T² (a χ variable,
    Gaussian-tailed), not to the skewed T² itself.

    Without the few-values rule (:data:`COMBINED_FEW` = 0; the tests' sides have it,
    :data:`~diag_plugin.learn.budget.FEW_VALUES`): T² is a sum of squares, its tail an
    exponential one (a χ² law's), the tail fit's own model; Rice's Gaussian on T² does not
    describe it, and on T² the rule was on in no window tried (T²'s top is beyond a Gaussian
    series', :func:`~diag_plugin.learn.budget.gaussian_top`: passing ``FEW_VALUES`` here
    moves no threshold of the benchmark plants' units nor of the fan plant's and the
    pasteuriser's in the tests, docs/how-to/unit-short-windows.md, "the few-values rule
    on"). On √T² it would be, and would move thresholds (a month at 1 min of 5 slow
    residuals, 49 independent values of T²: the tail fit's 21.4 against Rice's 26.4,
    ``tests/test_learning_combined_few.py``). So it stays off until a plant shows it is
    needed."""
    from diag_plugin.learn.budget import calibrate_side

    side = calibrate_side(t2, hours, far, on_delay, off_delay, COMBINED_FEW)
    high = float(side.threshold)
    if side.method == "gaussian":
        # too few episodes for a tail: Rice's Gaussian rate fits the distance √T² (a χ
        # variable, Gaussian-tailed), not the skewed T² itself
        side = calibrate_side(np.sqrt(t2), hours, far, on_delay, off_delay, COMBINED_FEW)
        high = float(side.threshold) ** 2
    return high, side


#: a set-point's response on a test is kept where it is this many standard errors from zero
RESPONSE_T = 3.0


def setpoint_responses(
    unit: Unit,
    frame: pd.DataFrame,
    body: pd.DataFrame,
    spec: CombinedSpec,
    point: np.ndarray | None = None,
) -> dict[str, dict[str, float]]:
    """Per loop set-point tag ``SP`` (a loop test's ``set_point`` that ``frame`` holds; a fixed
    number has none), the response ``β_j`` of each test's scaled residual
    ``z_j = (r_j − c_j) / s_j`` (``body``: the settled, filtered, cross-fitted fault-free
    residuals; ``spec``: their centre and scale) to a unit move of ``SP`` over the window: the
    least-squares slope of ``z_j`` on ``SP``, kept where it is at least :data:`RESPONSE_T`
    standard errors from zero. Both series are autocorrelated (a set-point held for hours, a
    filtered residual), so the slope's variance is ``σ_e² / Σx² · (1 + 2 Σ_k ρ_x(k) ρ_e(k))``
    (Bartlett, 1935; ``ρ`` the sample autocorrelations of the set-point and of the fit's
    residual ``e``, summed up to the first lag where ``ρ_e`` is no longer positive, as
    :func:`~diag_plugin.models.series.effective_samples` sums). Neither the loop's own test
    nor a spread test is answered. With operating points (``point``: each row's; ``spec``'s
    ``point_center``, ``point_scale``, ``diag unit accept``) ``z_j`` is centred and scaled at
    the row's point and the slope is the pooled within-point one (``SP`` and ``z_j`` less
    their point's means): a set-point that differs between the points says nothing of how a
    residual answers it within one (the points' residuals are centred apart by construction).

    A set-point move ``Δ`` moves the true measurement by ``Δ``; a bias ``b`` of the loop's
    sensor, once the loop compensates it, moves the true measurement by ``−b`` with the reading
    and the set-point unchanged. So where no model reads the measurement or the set-point (or
    reads them with a gain short of the plant's), the residuals that move with the set-point
    in the window are those the compensated bias moves, by ``−β_j · b`` on top of the models'
    gains (:func:`~diag_plugin.diagnose.unittags.directions`)."""
    loops: dict[str, set[str]] = {}
    for t in unit.file.tests:
        sp = getattr(t, "set_point", None)
        if sp and sp in frame.columns:
            loops.setdefault(sp, set()).add(t.name)
    out: dict[str, dict[str, float]] = {}
    at = point if point is not None and spec.point_center else None
    for sp, own in sorted(loops.items()):
        x = frame[sp].to_numpy(float)
        row: dict[str, float] = {}
        for j, name in enumerate(spec.tests):
            test = unit.file.test(name)
            if name in own or getattr(test, "statistic", "level") == "spread":
                continue
            if at is not None:  # at each sample's own point
                c = np.asarray(spec.point_center, float)[at, j]
                s = np.asarray(spec.point_scale, float)[at, j]
                z = (body[name].to_numpy(float) - c) / s
            else:
                z = (body[name].to_numpy(float) - spec.center[j]) / spec.scale[j]
            ok = np.isfinite(x) & np.isfinite(z)
            if ok.sum() < MIN_KNOWN:
                continue
            xc, zc = (
                _centred(x[ok], None if at is None else at[ok]),
                _centred(z[ok], None if at is None else at[ok]),
            )
            sxx = float(xc @ xc)
            if not sxx > 0:
                continue
            beta = float(xc @ zc) / sxx
            e = zc - beta * xc
            rx, _ = autocorrelation(xc)
            re, k = autocorrelation(e) if np.any(e) else (rx, 1)  # an exact fit: no lag
            tau = max(1.0, 1.0 + 2.0 * float(rx[1:k] @ re[1:k]))
            se = math.sqrt(float(e @ e) / max(ok.sum() - 2, 1) / sxx * tau)
            if abs(beta) >= RESPONSE_T * se:
                row[name] = beta
        if row:
            out[sp] = row
    return out


def _centred(a: np.ndarray, group: np.ndarray | None) -> np.ndarray:
    """``a`` less its mean, or less its group's mean in each group (``group``: per value its
    operating point): the within-point deviations."""
    if group is None:
        return a - a.mean()
    out = a.astype(float, copy=True)
    for k in np.unique(group):
        sel = group == k
        out[sel] -= a[sel].mean()
    return out


def model_gains(
    unit: Unit,
    frame: pd.DataFrame,
    mapper: Mapper | None = None,
    levels: dict[str, list[float]] | None = None,
    spread: dict[str, bool] | None = None,
) -> dict[str, dict[str, float]]:
    """Per test, the mean gain ``∂ŷ/∂X`` of its model for each tag ``X`` it reads plainly (any
    lag, or its ``mean()``; a bias moves every lag and mean alike, so their gains add), over
    the samples of ``frame`` the model answers, by a forward difference of :func:`gain_step`
    (5 % of the tag's standard deviation, at least one set of a rule grid), each moved
    sample's change weighed as the unit judges it (:func:`judged_weight`: ``levels``, the
    tests' learned level scales, and ``spread``, whether a test is judged in units of its
    local spread, as
    :func:`learn_thresholds` learned them; none given, every weight 1); keyed by the plant's
    tag names. Derived inputs (a rate, a direction) get none: a bias leaves them. ``mapper``
    (:data:`Mapper`): the tests' gains in any number of processes."""
    mf = unit._model_frame(frame)
    got = (mapper or _serial)(_test_gains, list(unit.tests), (unit, mf, levels, spread))
    return dict(zip(unit.tests, got, strict=True))


#: the forward difference of :func:`model_gains`, in standard deviations of the input
GAIN_STEP_SD = 0.05


def gain_step(model, cols: list[int], sd: float) -> float:
    """The step :func:`model_gains` moves an input by: :data:`GAIN_STEP_SD` of its standard
    deviation ``sd``, and at least the spacing of a rule grid's sets on the columns ``cols``
    it is read at (``partitions_``, the model's uniform partitions: Kościelny et al., the
    31 sets of each variable). A rule grid answers by interpolating its rules' conclusions,
    and a trapezoidal set is flat over half its spacing (its core): a step shorter than the
    spacing measures where the samples sit on the sets — on a core no slope at all, on a
    flank twice the rules' — not the relation. Over one spacing the difference is that
    between neighbouring rules' conclusions, the grid's own slope, wherever the sample sits.
    An input an operator enters to one decimal sits at the same few places of its sets:
    the 7-tag line's flow set-point (sets 0.11 m³/h apart, the step 0.04) gave its valve's
    model a gain of 2.18 %/(m³/h) where the data's slope and the valve's characteristic say
    5.1 (docs/how-to/unit-loops.md, "The 7-tag line"). Measured alone over one spacing, the
    gain is the grid's wherever the step lands, also where it leaves the data: weighed by
    :func:`judged_weight`."""
    step = GAIN_STEP_SD * sd
    parts = getattr(model, "partitions_", None)
    if parts is not None and len(parts) > max(cols):
        step = max(step, *(float(parts[c].step) for c in cols))
    return step


def judged_factor(pred: Prediction, levels: list[float] | None, spread: bool) -> np.ndarray:
    """What the unit divides each sample's residual by (:meth:`~diag_plugin.diagnose.unit.
    Unit.residual`): the answering level's learned scale (:func:`~diag_plugin.diagnose.unit.
    level_factor`, NaN at a level never calibrated) times, for a test judged in units of its
    local spread, that spread (:func:`~diag_plugin.diagnose.unit.spread_factor`)."""
    f = np.broadcast_to(np.asarray(level_factor(levels, pred.level), float), np.shape(pred.y))
    return f * spread_factor(pred.spread) if spread else f.copy()


def judged_weight(
    moved: Prediction, base: Prediction, answered: np.ndarray, levels, spread: bool
) -> np.ndarray:
    """Per sample, the weight of a moved sample's change in :func:`model_gains`: the window's
    mean factor (:func:`judged_factor` of ``base``, the window as it is, over the samples
    ``answered``: those the unit judges there) over
    the factor of the moved sample's answer. A step of one input alone can leave the data
    (inputs that move together, as a fan's flow and its damper), where coarser rule levels
    answer and the unit divides their residuals by the level's scale (up to 7.7 on the AHU
    fan): the raw change there overstates what the judged residual moves (the fan speed's
    gain on the flow 8.30 %/(m³/s) over a set spacing, the judged residual 4.4–5.4 in the
    fault, and the fan's flow-meter bias named on its damper). Relative to the window's mean
    factor, not absolute: the directions put the gain in units of the judged residual's
    scale learned on the same window (:func:`~diag_plugin.diagnose.unittags.directions`),
    which holds the window's factors already; taken absolute, every test's gains shrink by
    its typical factor, and the small changes added up on the AHU filter bank (a
    neighbouring piece's tag in its fault's top three on 5.04 % of alarm samples, 1.66 %
    with the unweighed 5 % sd step; docs/how-to/unit-loops.md, branch ``i34-gain3``)."""
    if levels is None and not spread:
        return np.ones(np.shape(moved.y))
    fb = judged_factor(base, levels, spread)
    ok = np.isfinite(fb) & answered
    mean = float(fb[ok].mean()) if ok.any() else math.nan
    return mean / judged_factor(moved, levels, spread)


def _test_gains(t: str, unit: Unit, mf: pd.DataFrame, levels=None, spread=None) -> dict[str, float]:
    """One test's gains for :func:`model_gains` (``mf``: the window under the models' names;
    ``levels``, ``spread``: per test, as :func:`model_gains` takes them)."""
    from diag_plugin.regressors import DesignBuilder, parse_specs

    m = unit.models[t]
    d = DesignBuilder(m.inputs, m.output, period=m.period).transform(mf)
    specs = parse_specs(m.inputs)
    g: dict[str, float] = {}
    if not len(d.y):
        return g
    lv = None if levels is None else levels.get(t)
    in_spread = bool(spread and spread.get(t))
    at = m.model.predict_detail(d.X)
    base = supported(at, unit.ev["min_support"])
    plain = [not sp.fn or sp.fn == "mean" for sp in specs]  # a bias moves a mean alike
    for tag in dict.fromkeys(sp.tags[0] for sp, p in zip(specs, plain, strict=True) if p):
        cols = [i for i, sp in enumerate(specs) if plain[i] and sp.tags[0] == tag]
        sd = float(np.nanstd(d.X[:, cols[0]]))
        if not sd > 0:
            continue
        step = gain_step(m.model, cols, sd)
        X = d.X.copy()
        X[:, cols] += step
        pred = m.model.predict_detail(X)
        moved = supported(pred, unit.ev["min_support"])
        w = judged_weight(pred, at, np.isfinite(base), lv, in_spread)
        diff = (moved - base) / step * w
        if np.isfinite(diff).any():
            g[unit.file.tags.get(tag, tag)] = float(np.nanmean(diff))
    return g
