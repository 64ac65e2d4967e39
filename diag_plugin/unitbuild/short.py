"""How ``diag unit build`` fits the window it is given: a few hundred samples, or a day at 1 s.

:func:`plan_for` reads the window's length and chooses, saying why (issue 34, item 3):

* **A short window** (fewer than :data:`SHORT_ROWS` grid points, at least
  :data:`MIN_ROWS`; e.g. SKAB's protocol, the first 400 samples of a run at 1 s): at most
  :data:`SHORT_MAX_INPUTS` inputs per test, chosen with a linear model (a few hundred samples
  determine ``1 + d`` coefficients, not a grid of ``sets^d`` rules); then per test a rule grid
  of at most :data:`SHORT_MAX_SETS` sets per input only where the data fill its cells with
  :data:`SHORT_PER_CELL` samples each *and* it beats the linear test's held-out error by more
  than the build's ``MIN_GAIN``; elsewhere the test is linear (:mod:`diag_plugin.models.linear`):
  the tag against a least-squares combination of its inputs, a PCA-like parity relation.
  A tag no other tag predicts gets a **level test** (:func:`level_test`: a linear test without
  inputs, the tag against its window mean), so every tag that varies is watched. The
  residual filter's cut-off is raised (:func:`short_lowpass`) so that the window's filtered
  residuals hold about :data:`SHORT_INDEPENDENT` independent values for the thresholds.
* **A long window on a fast grid** (more than :data:`SELECT_ROWS` grid points, e.g. a day at
  1 s): the inputs and dead times are chosen on a grid :func:`coarse_factor` times coarser
  (means over consecutive samples), the dead times scaled back; the models are then trained,
  and the thresholds learned, at the data's own rate, and the unit runs at that rate.
* Otherwise the build as before (``wm-avg`` on the sets the data fill).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from diag_plugin.regressors import InputSpec
from diag_plugin.selection.sets import SETS_RANGE

#: fewest grid points a unit is built from (the thresholds need a few hundred settled residuals)
MIN_ROWS = 200
#: below this many grid points the window is short (see module doc)
SHORT_ROWS = 1000
#: inputs per test at most in a short window
SHORT_MAX_INPUTS = 2
#: sets per input at most in a short window's rule grid
SHORT_MAX_SETS = 5
#: training samples per occupied rule cell a short window's grid must hold
SHORT_PER_CELL = 40
#: independent values a short window's filtered residuals should hold (:func:`short_lowpass`)
SHORT_INDEPENDENT = 40
#: independent values of a tag a short window needs for a level test (:func:`level_test`)
SHORT_LEVEL_INDEPENDENT = SHORT_INDEPENDENT
#: under this many independent values a short window's tag no other tag predicts gets a slow
#: level test, kept out of the combined T² (:func:`level_test`); from here to
#: :data:`SHORT_LEVEL_INDEPENDENT` it stays untested: Student's t of its values no longer
#: widens the threshold much, and the wander the window did not show raises it (the heat
#: exchanger at 3 min: its outlet temperature, 33 values, in alarm on 56 % of the fault-free
#: continuation)
SHORT_SLOW_LEVEL_MAX = SHORT_LEVEL_INDEPENDENT // 2
#: independent values of a tag a short window needs for it to be a test's input
#: (:func:`slow_inputs`)
SHORT_INPUT_INDEPENDENT = SHORT_INDEPENDENT
#: the highest residual filter cut-off (/ Nyquist) a short window gets
SHORT_MAX_LOWPASS = 0.2
#: above this many grid points inputs are chosen on a coarser grid
SELECT_ROWS = 20_000
#: the linear method a short window's tests fall back to
LINEAR = "linear"


@dataclass
class Plan:
    """What the build does with this window, and why (printed and kept in ``[build]``)."""

    rows: int
    period: str
    short: bool = False
    max_inputs: int = 3
    select_method: str = "wm-avg"
    max_sets: int | None = None
    factor: int = 1
    #: a short window's residual filter (cut-off / Nyquist), None: the period's default
    lowpass: float | None = None
    #: a short window's tags too slow to be an input (:func:`slow_inputs`): their
    #: independent values in the window
    slow: dict[str, float] = field(default_factory=dict)
    reasons: list[str] = field(default_factory=list)

    @property
    def select_period(self) -> str:
        """The grid inputs are chosen on."""
        return _fmt(pd.Timedelta(self.period) * self.factor)

    def as_dict(self) -> dict:
        return {
            "rows": self.rows,
            "short": self.short,
            "max_inputs": self.max_inputs,
            "select_method": self.select_method,
            "max_sets": self.max_sets,
            "select_period": self.select_period,
            "lowpass": self.lowpass,
            "slow": dict(self.slow),
            "reasons": list(self.reasons),
        }


def _fmt(td: pd.Timedelta) -> str:
    s = td.total_seconds()
    if s >= 60 and s % 60 == 0:
        return f"{int(s // 60)}min"
    return f"{s:g}s"


def coarse_factor(rows: int) -> int:
    """Consecutive samples averaged into one for the choice of inputs: the window shrunk to
    at most :data:`SELECT_ROWS` grid points."""
    return max(1, math.ceil(rows / SELECT_ROWS))


def short_lowpass(rows: int, lowpass: float) -> float:
    """A short window's residual filter: the period's cut-off ``lowpass`` (/ Nyquist), raised
    so that the filtered residuals of ``rows`` samples hold :data:`SHORT_INDEPENDENT` values
    the thresholds can rest on (a filter remembers about ``1 / wn`` samples), at most
    :data:`SHORT_MAX_LOWPASS`."""
    return float(f"{min(SHORT_MAX_LOWPASS, max(lowpass, SHORT_INDEPENDENT / rows)):.3g}")


def plan_for(
    rows: int,
    period: str,
    max_inputs: int,
    lowpass: float | None = None,
    output_max_inputs: int | None = None,
) -> Plan:
    """The build's plan for a window of ``rows`` grid points of ``period`` (module doc);
    ``lowpass``: the period's residual filter (cut-off / Nyquist), which a short window
    raises (:func:`short_lowpass`); ``output_max_inputs``: the inputs a controller output's
    test (and a flow's balance test) may take, which a short window does not cut, said in
    its note (until 2026-11-30 the note said the per-test limit alone, acceptance-chiller.md)."""
    p = Plan(rows, period, max_inputs=max_inputs)
    if rows < SHORT_ROWS:
        p.short = True
        p.max_inputs = min(max_inputs, SHORT_MAX_INPUTS)
        p.select_method = LINEAR
        p.max_sets = SHORT_MAX_SETS
        p.reasons.append(
            f"short window ({rows} samples of {period}, under {SHORT_ROWS}): at most "
            f"{p.max_inputs} inputs per test"
            + (
                f" (a controller output's test up to {output_max_inputs}, as a flow's balance "
                "test, each input kept only where it cuts the held-out error)"
                if output_max_inputs and output_max_inputs > p.max_inputs
                else ""
            )
            + ", chosen with a linear model; a rule grid (at most "
            f"{SHORT_MAX_SETS} sets per input) only where its cells hold {SHORT_PER_CELL} "
            "samples each and it beats the linear test on held-out error, else a linear "
            "(PCA-like) test; a tag no other tag predicts: a level test (the tag against its "
            "mean over the window)"
        )
        if lowpass is not None:
            p.lowpass = short_lowpass(rows, lowpass)
            if p.lowpass != lowpass:
                p.reasons.append(
                    f"residual filter cut-off {p.lowpass:g} of Nyquist (memory about "
                    f"{1 / p.lowpass:.0f} samples), not {lowpass:g} (about {1 / lowpass:.0f}): "
                    f"the thresholds rest on the {rows} samples' filtered residuals, which "
                    f"then hold about {SHORT_INDEPENDENT} independent values, not "
                    f"{rows * lowpass:.0f}"
                )
    elif rows > SELECT_ROWS:
        p.factor = coarse_factor(rows)
        p.reasons.append(
            f"long window ({rows} samples of {period}): inputs and dead times chosen on a "
            f"{p.select_period} grid (means of {p.factor} samples), models trained and "
            f"thresholds learned at {period}"
        )
    return p


def slow_inputs(plan: Plan, tags: Sequence[str], column) -> dict[str, float]:
    """A short window's tags that wander slower than the window shows (``plan.slow``, with a
    reason in ``plan.reasons``): tags whose window holds fewer than
    :data:`SHORT_INPUT_INDEPENDENT` independent values
    (:func:`~diag_plugin.models.series.effective_samples` of ``column(tag)``). They are
    no input of a tag the window holds that many values of (:func:`inputs_for`).

    A slow input explains a fast tag's slow wander over the window by chance (Granger and
    Newbold's spurious regression: a few independent values correlate with anything): on
    SKAB's 400 s the fluid temperature (3–8 values) cut the flow's held-out error by 4 %, so
    the flow was tested against it — a relation that holds for the window only, whose
    residual wanders with the temperature (a threshold from about 4 independent values), and
    whose input leaves the span it learned as soon as the temperature drifts on by a tenth of
    a degree: the test goes unknown and the flow's fault is not seen (SKAB's cavitation: the
    flow collapses from 126 to about 20 l/min while its test reads *unknown*). Without the
    slow input the tag gets the level test its own independent values allow
    (:func:`level_test`). A slow tag stays an input of a faster one where their correlation
    is more than the pair's shared independent values give by chance (:func:`spurious`):
    its few values then carry a relation, not a common drift (classic TEP's 25 h hold slow
    tags of about 12 values that move with faster ones; a bound on the slow tag's own
    values alone cost the naming of its faults). Two slow tags (the two accelerometers of
    a pump) keep each other: neither has a level test to fall back on, and their joint
    test (:func:`joint_groups`) watches their common rise."""
    from diag_plugin.models.series import effective_samples

    if not plan.short:
        return {}
    n_eff = {t: effective_samples(column(t)) for t in tags}
    plan.slow = {t: n for t, n in n_eff.items() if n < SHORT_INPUT_INDEPENDENT}
    if plan.slow and len(plan.slow) < len(n_eff):
        each = ", ".join(f"{t} (about {n:.0f})" for t, n in plan.slow.items())
        plan.reasons.append(
            f"slow tags (under {SHORT_INPUT_INDEPENDENT} independent values in the window): "
            f"{each}; each is an input of a faster tag only where their correlation beats "
            f"chance (level {SHORT_INPUT_LEVEL:g} on the pair's independent values): a tag "
            "that wanders slower than the window correlates with a faster one by chance, and "
            "leaves the span its test learned as soon as it drifts on"
        )
    return plan.slow


def pair_samples(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """The correlation ``r`` of ``x`` and ``y`` (rows where both are known) and the
    independent values it rests on: Bartlett's ``n / (1 + 2 Σ_k ρx(k) ρy(k))`` (Bartlett 1935;
    Pyper and Peterman 1998, eq. 1), summed over the lags of the longer memory of the two
    (Sokal's window, :func:`~diag_plugin.models.series.autocorrelation`). Two series that
    wander slowly share few independent values however long the window; a white one keeps all
    ``n`` beside a slow one, and a tag whose slow part hides under fast noise keeps as few as
    its slow part allows beside a slow one."""
    from diag_plugin.models.series import autocorrelation

    ok = np.isfinite(x) & np.isfinite(y)
    a, b = x[ok] - x[ok].mean(), y[ok] - y[ok].mean()
    n = a.size
    if n < 3 or not np.any(a) or not np.any(b):
        return 0.0, float(n)
    r = float(a @ b / math.sqrt(float(a @ a) * float(b @ b)))
    (ra, ka), (rb, kb) = autocorrelation(a), autocorrelation(b)
    k = max(ka, kb)
    return r, n / max(1.0, 1.0 + 2.0 * float((ra[1:k] * rb[1:k]).sum()))


#: two-sided level at which a slow input's correlation with a tag must be significant
#: (:func:`spurious`) for it to remain an input in a short window
SHORT_INPUT_LEVEL = 0.01


def spurious(x: np.ndarray, y: np.ndarray, level: float = SHORT_INPUT_LEVEL) -> bool:
    """Whether the window's correlation of ``x`` with ``y`` is what two unrelated series
    with their autocorrelation show by chance: ``|r|`` under the two-sided ``level``
    critical value of Student's t with ``n' − 2`` degrees of freedom, ``n'`` the pair's
    independent values (:func:`pair_samples`; Pyper and Peterman 1998's modified test of
    a correlation between autocorrelated series)."""
    from scipy import stats

    r, n = pair_samples(np.asarray(x, float), np.asarray(y, float))
    dof = n - 2.0
    if dof <= 0:
        return True
    t = abs(r) * math.sqrt(dof / max(1e-12, 1.0 - r * r))
    return bool(t < stats.t.ppf(1.0 - level / 2.0, dof))


def inputs_for(plan: Plan, tag: str, candidates: Sequence[str], column=None) -> list[str]:
    """``candidates`` less the slow tags (:func:`slow_inputs`) where ``tag`` itself is not
    slow and, given the window's values ``column(tag)``, whose correlation with ``tag`` is
    :func:`spurious` — a slow tag that moves with ``tag`` beyond what the pair's independent
    values allow by chance stays an input. Without ``column`` every slow tag is left out."""
    if tag in plan.slow:
        return list(candidates)
    if column is None:
        return [c for c in candidates if c not in plan.slow]
    y = column(tag)
    return [c for c in candidates if c not in plan.slow or not spurious(column(c), y)]


def coarse_frame(frame: pd.DataFrame, factor: int) -> pd.DataFrame:
    """Means of ``factor`` consecutive rows (NaN-tolerant), indexed by each group's first
    timestamp: the grid the inputs are chosen on."""
    if factor <= 1:
        return frame
    g = np.arange(len(frame)) // factor
    out = frame.groupby(g).mean()
    out.index = frame.index[::factor][: len(out)]
    return out


def scale_lag(spec: str, factor: int) -> str:
    """An input spec chosen on the coarse grid with its dead time on the data's grid."""
    if factor <= 1:
        return spec
    s = InputSpec.parse(spec)
    return str(InputSpec(s.fn, s.tags, s.lag * factor, s.param))


def grid_cells(cols: Sequence[np.ndarray], spans: Sequence[tuple[float, float]], sets: int):
    """Rows with every input known, and the rule cells they occupy at ``sets`` per input."""
    X = np.column_stack(cols)
    X = X[np.isfinite(X).all(axis=1)]
    lo = np.array([s[0] for s in spans])
    width = np.array([s[1] - s[0] for s in spans])
    idx = np.clip(np.floor((X - lo) / width * (sets - 1) + 0.5), 0, sets - 1).astype(np.int64)
    return len(X), int(np.unique(idx @ (sets ** np.arange(idx.shape[1], dtype=np.int64))).size)


def short_sets(cols: Sequence[np.ndarray], spans: Sequence[tuple[float, float]]) -> int | None:
    """The most sets per input (at most :data:`SHORT_MAX_SETS`) whose occupied cells hold
    :data:`SHORT_PER_CELL` samples each; None where even the coarsest grid is too thin."""
    for sets in range(SHORT_MAX_SETS, SETS_RANGE[0] - 1, -1):
        n, cells = grid_cells(cols, spans, sets)
        if n >= SHORT_PER_CELL * cells:
            return sets
    return None


#: a linear test's inputs are trusted this share of their observed range beyond it
MARGIN = 0.25


def widened(span: tuple[float, float]) -> tuple[float, float]:
    """A linear test's input span from a short window's observed range, :data:`MARGIN` of
    it wider on each side: where an input leaves it the test is unknown (the unit
    CHECK_FUNCTION, naming the input; ``diag unit accept`` learns the new range)."""
    lo, hi = span
    w = (hi - lo) * MARGIN
    return (lo - w, hi + w)


def guarded(seen: tuple[float, float], instrument: tuple[float, float]) -> tuple[float, float]:
    """A short window's linear test's input span where the tag has an instrument range (a
    tags CSV's ``lo``/``hi``): the observed range ``seen`` :func:`widened`, clipped to the
    instrument's range -- what the unit learned, not all the instrument can read (issue 34,
    item 3: a pump's line learned at 80-88 % speed was judged at 57 % as in alarm). Never
    narrower than ``seen`` (a range the data already leave says nothing of the window)."""
    lo, hi = widened(seen)
    return (max(lo, min(instrument[0], seen[0])), min(hi, max(instrument[1], seen[1])))


def level_test(ch, y: np.ndarray, min_gain: float) -> bool | str:
    """A short window's test of a tag no other tag predicts: the tag against its mean over
    the window (a linear test without inputs) -- a univariate T²-like chart, so that every
    tag that varies is watched (``ch.method``, ``ch.why`` and ``ch.combined`` set). Returns
    False for a level test, True for a slow one, or the reason the tag is left untested.

    Where the window holds :data:`SHORT_LEVEL_INDEPENDENT` independent values of the tag
    ``y`` (:func:`~diag_plugin.models.series.effective_samples`) or more, a level test in
    the combined ``T²``. Under :data:`SHORT_SLOW_LEVEL_MAX` the tag wanders far slower than
    the window shows and its mean and spread rest on a handful of values: a **slow level
    test**, kept out of the combined ``T²`` (``combined = false``: a dimension of few values
    in ``T²`` takes its share of the fault-free wander and lowers ``T²`` under its limit
    through the faults the other tests see, SKAB's tuning runs, rounds 8 and 13) and judged
    on its own threshold, which Student's t of those few values widens (issue 34, H1: a slow
    tag's own excursion — SKAB's fluid temperature in the tuning run other/10 — was seen by
    no test). In between the tag is left untested, and the build drops a slow level test of
    a tag another test reads (:func:`~diag_plugin.unitbuild.build.unread_slow_levels`)."""
    from diag_plugin.models.series import effective_samples

    n = effective_samples(y)
    if SHORT_SLOW_LEVEL_MAX <= n < SHORT_LEVEL_INDEPENDENT:
        return (
            f"no other tag predicts it on held-out data (best cut of the error under "
            f"{min_gain:.0%}), and the window holds about {n:.0f} independent values of it "
            f"(a level test needs {SHORT_LEVEL_INDEPENDENT}, a slow level test under "
            f"{SHORT_SLOW_LEVEL_MAX}): it wanders slower than the window shows"
        )
    ch.method = LINEAR
    if n < SHORT_LEVEL_INDEPENDENT:
        ch.combined = False
        ch.why = (
            f"slow level test: no other tag cuts its held-out error by more than "
            f"{min_gain:.0%}, and the window holds about {n:.0f} independent values of it "
            f"(under {SHORT_SLOW_LEVEL_MAX}: it wanders far slower than the window shows); the "
            "tag against its mean over the window, on its own threshold, kept out of the "
            "combined T² (combined = false)"
        )
        return True
    ch.why = (
        f"level test: no other tag cuts its held-out error by more than {min_gain:.0%}; "
        f"the tag against its mean over the window ({n:.0f} independent values; held-out "
        f"error {ch.baseline_rmse_pct:.2f} %)"
    )
    return False


#: the method of a short window's joint test of a collinear group (:func:`joint_groups`)
JOINT = "joint"


def joint_groups(
    tests: Sequence[tuple[str, Sequence[str]]], column
) -> list[tuple[list[str], float, str]]:
    """A short window's collinear groups and whether each gets a joint test
    (:mod:`diag_plugin.models.joint`): tags whose parity tests predict each other (``A`` from
    ``B`` and ``B`` from ``A``, any dead time), joined where they share a tag. A common rise
    of such tags cancels in each one's test against the others; the joint test watches the
    group's score on its first principal component, as PCA's T² does.

    ``tests``: per linear test its tag and its inputs' tags; ``column(tag)``: the window's
    values. Returns per group its tags, the output of its joint test first — the tag with the
    largest |loading| on the component (the model divides by that loading,
    :class:`~diag_plugin.models.joint.JointRegressor`; a tag barely on the component would
    scale its residual by ~1 / 0) — then the others in ``tests``' order; the independent
    values its score holds, and why it is left out ("" where it is tested): only where the
    window holds :data:`SHORT_LEVEL_INDEPENDENT` independent values of the score, as a level
    test."""
    order = [t for t, _ in tests]
    ins = {t: set(i) for t, i in tests}
    parent = {t: t for t in order}

    def root(t: str) -> str:
        while parent[t] != t:
            t = parent[t]
        return t

    for a in order:
        for b in ins[a]:
            if b in ins and a in ins[b] and root(a) != root(b):
                parent[root(b)] = root(a)
    groups: dict[str, list[str]] = {}
    for t in order:
        groups.setdefault(root(t), []).append(t)
    out = []
    for g in groups.values():
        if len(g) < 2 or (got := group_component(g, column)) is None:
            continue
        g, n = got
        why = ""
        if n < SHORT_LEVEL_INDEPENDENT:
            why = (
                f"the window holds about {n:.0f} independent values of their common "
                f"direction (a joint test needs {SHORT_LEVEL_INDEPENDENT})"
            )
        out.append((g, n, why))
    return out


def group_component(g: Sequence[str], column) -> tuple[list[str], float] | None:
    """A group of tags ordered for its joint test, the output first — the tag with the
    largest |loading| on the first principal component of their standardised values
    (:func:`component`; the first of equal loadings in ``g``'s order), then the others in
    ``g``'s order — and the independent values of the group's score in the window; None
    where fewer than 3 rows know every tag."""
    got = component([column(t) for t in g])
    if got is None:
        return None
    v, n = got
    out_at = int(np.argmax(np.abs(v)))
    g = list(g)
    return [g[out_at]] + g[:out_at] + g[out_at + 1 :], n


def component(cols: Sequence[np.ndarray]) -> tuple[np.ndarray, float] | None:
    """The loadings ``v`` of the first principal component of the columns' standardised
    values (:func:`~diag_plugin.models.joint.first_component`, over the rows that know every
    column) and the independent values of the score on it
    (:func:`~diag_plugin.models.series.effective_samples`); None under 3 such rows."""
    from diag_plugin.models.joint import first_component
    from diag_plugin.models.series import effective_samples

    U = np.column_stack(cols)
    U = U[np.isfinite(U).all(axis=1)]
    if len(U) < 3:
        return None
    P = np.column_stack([np.ones(len(U)), U])
    m, s, v = first_component(P.T @ P)
    return v, float(effective_samples(((U - m) / s) @ v))


def blind_pairs(
    tests: Sequence[tuple[str, Sequence[str]]], untested: Sequence[str], slow: Mapping[str, float]
) -> list[tuple[str, str]]:
    """A short window's slow tags left blind, each with the slow tag whose test reads it:
    ``(A, spec)`` where ``B`` (in ``untested``: no test of its own, too slow for a level
    test, :func:`level_test`) is an input of ``A``'s parity test, ``spec`` that input as the
    test reads it (its dead time: ``B[k-25]``), and both are slow (``slow``,
    :func:`slow_inputs`). ``tests``: per linear or grid test its tag and its input specs, in
    the build's order (the first such ``A``). Their common move cancels in ``A``'s test and
    ``B`` has none: the pair's joint test is what watches it (SKAB's two accelerometers of a
    pump, docs/how-to/unit-short-windows.md, rounds 13-14). :func:`joint_groups` joins only
    tags whose tests read each other."""
    out = []
    for b in untested:
        if b not in slow:
            continue
        for a, specs in tests:
            spec = next((sp for sp in specs if InputSpec.parse(sp).tags == (b,)), None)
            if a in slow and a != b and spec is not None and not InputSpec.parse(spec).fn:
                out.append((a, spec))
                break
    return out
