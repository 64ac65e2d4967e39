"""Rank candidate missing effects by the out-of-sample error they would leave.

For each candidate input the model is retrained with it added (or, for a
dead time, with an input's lag replaced) on the first part of the data and
scored on the last part — a time-ordered held-out block, never shuffled
samples. Every candidate is scored on the *same* samples: where it has no
rule, its nearest trained rule stands in — as in the error ``diag train``
reports — so a candidate cannot look better by predicting fewer samples, and
the error it promises is the one training gives; its own coverage is shown
beside the error. A candidate whose
grid would be thin is also scored with the fewer sets the data fill, and the
better of the two is offered with its exact command.

Candidates: every other plant tag (at its best lag), differences of tags that
share a unit (a pressure drop), dead time and more lags of the model's inputs
(lags screened by correlation over a horizon of ten minutes of samples, the
best few put on the screen), direction of travel (hysteresis, backlash), rate of
change, slow drift (on windows of a week or more), time of day, and the model's
own resolution (an input's span narrowed to its operating range, more or fewer
sets).

Issue 37: not every candidate is retrained. Each goes through a quick screen first
(:class:`~diag_plugin.selection.screen.Screen`: how much of the model's out-of-fold
residual its cells explain on the held-out block) and only the :data:`REFINED` best
are retrained and scored; the others are listed as screened. A tag driven by the
output (:mod:`~diag_plugin.selection.consequence`) is flagged and ranked after the
causes that cut the error.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace

import numpy as np
import pandas as pd

from diag_plugin.models.spec import Variable
from diag_plugin.regressors import InputSpec, check_regular, dir_threshold, needed_tags
from diag_plugin.rulebase.document import RuleBase
from diag_plugin.selection.consequence import consequence
from diag_plugin.selection.features import Features
from diag_plugin.selection.lags import TOLERANCE, default_max_lag, lag_screen
from diag_plugin.selection.scoring import BlockScorer, HeldOutScorer, cut_row
from diag_plugin.selection.screen import Screen
from diag_plugin.selection.sets import sets_for_cells
from diag_plugin.selection.spans import operating_span, variable_for
from diag_plugin.training.baseline import json_keys
from diag_plugin.training.heldout import narrow_inputs
from historian.taginfo import TagInfo, tag_infos

#: |correlation| with a model input above which a candidate is flagged
CORR_WARN = 0.6
#: validation samples per rule cell below which the grid is called sparse
SPARSE_PER_CELL = 5.0
#: rows on which a thin candidate's set counts are compared (every n/QUICK_ROWS-th row)
QUICK_ROWS = 100_000
#: lags of each correlation screen that go on to the screen (:class:`Screen`)
LAGS_SCREENED = 4
#: candidates best on the screen that are retrained and scored on the held-out samples
REFINED = 8
#: share of the held-out rows the screen cannot judge a candidate on (a value seen only at
#: the edge of the training part, :meth:`Screen.unjudged`) from which it is retrained whatever
#: its screening error ...
UNJUDGED = 0.5
#: ... beyond the :data:`REFINED` best, at most this many, the least judged first
UNJUDGED_EXTRA = REFINED // 2
#: a slow drift (``days()``) is offered only when the training part spans this many days
DRIFT_MIN_DAYS = 7.0
#: a drift that cuts the error on the held-out tail is offered only when it also cuts it with
#: each of this many equal stretches of the window held out in turn (the tail's share each)
DRIFT_BLOCKS = 5
#: fewer sets than add-input writes are suggested only when they score better by more
#: than this share (the gain explain calls more than "barely")
SETS_GAIN = 0.03
#: fewer set counts in a row, tried coarse to fine, that do not beat the best coarser one by
#: :data:`SETS_GAIN` after which a thin candidate's finer (costlier) counts are not tried
SETS_PATIENCE = 2
#: fewer sets are suggested for a thin grid only when at most this share of the count
FEWER_SHARE = 2 / 3
#: a candidate covering fewer samples than the current model by more than this is thin
#: (each sample it loses is scored with its nearest rule)
COVERAGE_SLACK = 0.01


def materially_fewer(fewer: int, sets: int) -> bool:
    """Whether ``fewer`` sets are worth suggesting instead of ``sets``: at least 2 (one set
    is no input) and at most :data:`FEWER_SHARE` of ``sets`` (30 beside 31 is no change)."""
    return 2 <= fewer <= FEWER_SHARE * sets


@dataclass
class Candidate:
    input: str
    kind: str
    effect: str
    rmse_pct_if_added: float
    coverage: float
    command: str
    replaces: str | None = None
    notes: list[str] = field(default_factory=list)
    #: the candidate is likely driven by the output (:mod:`~diag_plugin.selection.consequence`)
    consequence: bool = False

    def as_dict(self) -> dict:
        d = {
            "input": self.input,
            "kind": self.kind,
            "effect": self.effect,
            "rmse_pct_if_added": _num(self.rmse_pct_if_added),
            "coverage": _num(self.coverage),
            "command": self.command,
            "notes": self.notes,
            "likely_consequence": self.consequence,
        }
        if self.replaces:
            d["replaces"] = self.replaces
        return d


def _num(v: float) -> float | None:
    return None if v is None or not math.isfinite(v) else round(float(v), 4)


@dataclass
class Explanation:
    model: str
    baseline_rmse_pct: float
    baseline_coverage: float
    candidates: list[Candidate]
    validation_from: pd.Timestamp | None = None
    #: candidates the screen ranked below the retrained ones: input, kind, screening error
    screened: list[dict] = field(default_factory=list)
    #: sets per input of the screen's coarse cells
    screen_sets: int = 0
    #: what was not offered and why (a drift on a short window)
    notes: list[str] = field(default_factory=list)
    #: wall and CPU seconds of each phase
    seconds: dict[str, float] = field(default_factory=dict)
    cpu_seconds: dict[str, float] = field(default_factory=dict)
    #: HistGradientBoosting on the model's inputs, same training and held-out rows
    #: (:func:`~diag_plugin.training.baseline.hgb_baseline`), with ``explain(baseline=True)``
    baseline: dict | None = None
    #: the inputs the held-out rows see at one operating point
    #: (:func:`~diag_plugin.training.heldout.narrow_inputs`): the held-out error judges there
    heldout_narrow: list[dict] = field(default_factory=list)

    def as_dict(self, top: int | None = None) -> dict:
        c = self.candidates if top is None else self.candidates[:top]
        return {
            "model": self.model,
            # the model as it is: trained before validation_from, scored after it
            "heldout_rmse_pct": _num(self.baseline_rmse_pct),
            "heldout_coverage": _num(self.baseline_coverage),
            "validation_from": self.validation_from.isoformat() if self.validation_from else None,
            "candidates": [x.as_dict() for x in c],
            "screened": self.screened,
            "screen_sets": self.screen_sets,
            "notes": self.notes,
            "heldout_narrow": self.heldout_narrow,
            **json_keys(self.baseline),  # HistGradientBoosting on the same rows
            # the names of heldout_rmse_pct and heldout_coverage until issue 34 (deprecated)
            "baseline_rmse_pct": _num(self.baseline_rmse_pct),
            "baseline_coverage": _num(self.baseline_coverage),
        }


def explain(
    rb: RuleBase,
    frame: pd.DataFrame,
    *,
    tag_info: Mapping[str, TagInfo | Mapping[str, object]] | None = None,
    holdout: float = 0.2,
    max_lag: int | None = None,
    top: int | None = None,
    baseline: bool = False,
) -> Explanation:
    """Candidate missing effects of ``rb``'s model, best first.

    Every candidate is scored on the same held-out samples (see :class:`HeldOutScorer`), so the
    order is the order of the errors. ``tag_info`` maps tag →
    :class:`~historian.taginfo.TagInfo` (historian metadata); spans of new inputs come
    from it, else from the data. ``max_lag`` bounds the dead times screened (default
    :func:`default_max_lag`).

    BLAS is held to one thread throughout (threadpoolctl's ``threadpool_limits(1)``): the
    coarse levels' node fits of every retrained candidate make
    thousands of vector products of some 10^4 entries, which with a BLAS thread per core
    on a loaded machine spent most of their CPU time waiting (issue 37).
    """
    from threadpoolctl import threadpool_limits

    # the compiled loops from the start (numba's import, ≈ 0.6 s CPU, pays back over the
    # dozens of models explain fits; before it, each runs numpy's slower loops: the same bits)
    from diag_plugin.fuzzy import _kernels  # noqa: F401
    from diag_plugin.fuzzy.wang_mendel import iterative_node_fit

    with threadpool_limits(1), iterative_node_fit():
        return _explain(
            rb,
            frame,
            tag_info=tag_info,
            holdout=holdout,
            max_lag=max_lag,
            top=top,
            baseline=baseline,
        )


def _explain(
    rb: RuleBase,
    frame: pd.DataFrame,
    *,
    tag_info: Mapping[str, TagInfo | Mapping[str, object]] | None,
    holdout: float,
    max_lag: int | None,
    top: int | None,
    baseline: bool = False,
) -> Explanation:
    """:func:`explain`'s work."""
    check_regular(frame.index)
    tag_info = tag_infos(tag_info)
    known = {s.tags[0]: v.span for v in rb.inputs if (s := InputSpec.parse(v.spec)).fn == ""}
    spans = dict(known)
    spans.update({t: i.span for t, i in tag_info.items() if i.span})
    feats = Features(frame, spans)
    out_spec = InputSpec.parse(rb.output.spec)
    y = feats.column(out_spec)
    in_specs = [InputSpec.parse(v.spec) for v in rb.inputs]
    in_cols = [feats.column(s) for s in in_specs]
    in_vars = list(rb.inputs)
    default_sets = max(v.sets for v in in_vars) if in_vars else 31
    n = len(frame)
    cut = cut_row(frame.index, holdout)
    horizon = default_max_lag(frame.index) if max_lag is None else max_lag
    clock = _Clock()
    scorer = HeldOutScorer(rb, in_cols, y, cut)
    # set counts are compared on every stride-th row; only the chosen one on all rows
    stride = max(1, n // QUICK_ROWS)
    quick = scorer
    if stride > 1:
        quick = HeldOutScorer(rb, [c[::stride] for c in in_cols], y[::stride], -(-cut // stride))
    base_rmse, base_cov = scorer.base_rmse, scorer.base_cov
    reference = None
    if baseline:  # on the model's inputs, its training rows and the held-out rows it scores
        from diag_plugin.training.baseline import hgb_baseline

        X = np.column_stack(in_cols) if in_cols else np.empty((n, 0))
        reference = hgb_baseline(X[:cut], y[:cut], X[scorer.va], y[scorer.va], scorer.span)
        clock.lap("baseline")
    held = np.zeros(n, bool)
    held[scorer.va] = True
    X_in = np.column_stack(in_cols) if in_cols else None
    narrow = narrow_inputs([v.spec for v in in_vars], X_in, held)
    resid = scorer.residual(in_cols)
    clock.lap("model and held-out block")
    screen = Screen(rb, in_cols, y, cut, scorer.va, scorer.base_pred)
    clock.lap("out-of-fold residual")
    var_cache: dict[str, Variable | None] = {}

    def variable(spec: InputSpec) -> Variable | None:
        """The variable add-input would write for ``spec`` (same span and sets)."""
        if spec.base not in var_cache:
            col = feats.column(spec.with_lag(0))
            v = col[np.isfinite(col)]
            if v.size == 0 or v.min() == v.max():
                var_cache[spec.base] = None  # nothing to learn from a constant
            else:
                var_cache[spec.base] = variable_for(
                    str(spec.with_lag(0)),
                    frame=frame,
                    tag_info=tag_info,
                    default_sets=default_sets,
                    known_spans=known,
                )
        base = var_cache[spec.base]
        return None if base is None else dc_replace(base, spec=str(spec))

    model_tags = set(needed_tags([v.spec for v in rb.inputs]))
    out_tags = set(out_spec.tags)

    def variant(spec: InputSpec, replace=None, sets=None, step: int = 1):
        """The variables and columns (every ``step``-th row) of the model with ``spec``."""
        var = variable(spec)
        if var is None:
            return None
        if sets is not None:
            var = dc_replace(var, sets=sets)
        cols, vs = [c[::step] for c in in_cols], list(in_vars)
        if replace is None:
            cols.append(feats.column(spec)[::step])
            vs.append(var)
        else:
            cols[replace], vs[replace] = feats.column(spec)[::step], var
        return vs, cols

    def evaluate(
        spec: InputSpec, replace=None, sets=None, sc: HeldOutScorer | None = None, fitted=None
    ):
        """``fitted``: :func:`unfilled`'s variant and fit of ``spec`` as add-input writes it
        (all rows, ``scorer``), finished instead of built and fitted again."""
        sc = sc or scorer
        if fitted is None:
            got, prefit = variant(spec, replace, sets, stride if sc is not scorer else 1), None
        else:
            got, prefit = fitted
        if got is None:
            return None
        vs, cols = got
        rmse, cov, per_cell, fine = sc.score(vs, cols, prefit=prefit)
        return _Score(rmse, cov, per_cell, vs[-1 if replace is None else replace].sets, fine=fine)

    def unfilled(spec: InputSpec, replace=None) -> tuple[float | None, tuple | None]:
        """Training samples per rule of ``spec`` as add-input writes it where that is below
        :data:`SPARSE_PER_CELL` (the data cannot fill its grid: it is thin whatever it
        scores), else None — from the fit alone, before any coarse level is fitted; with
        the variant and its fit (:func:`evaluate`'s ``fitted``; None where none fits)."""
        got = variant(spec, replace)
        if got is None:
            return None, None
        per, prefit = scorer.per_rule(*got)
        return (per if 0 < per < SPARSE_PER_CELL else None), (got, prefit)

    def drift_across_blocks(spec: InputSpec, sets: int) -> tuple[float, float] | None:
        """Where a drift's cut on the held-out tail does not hold over time-blocked folds:
        the window cut in :data:`DRIFT_BLOCKS` equal stretches, each held out in turn
        (:class:`BlockScorer`, every ``stride``-th row), the pooled errors without and with
        ``spec``; None where it cuts there too. On the tail a drift's every held-out value
        lies beyond the training part's, so it can only carry the last stretch's level
        forward: a hidden step scores as a drift there, and across the blocks it does not."""
        got = variant(spec, sets=sets, step=stride)
        if got is None:
            return None
        vs, cols = got
        rows = cols[0].size if cols else y[::stride].size
        block = np.minimum(np.arange(rows) * DRIFT_BLOCKS // max(rows, 1), DRIFT_BLOCKS - 1)
        blocked = BlockScorer(scorer.rb, cols[:-1], y[::stride], block)
        rmse, _ = blocked.score(vs, cols)
        if math.isfinite(rmse) and rmse < CUTS * blocked.base_rmse:
            return None
        return blocked.base_rmse, rmse

    def thin(r: _Score) -> bool:
        return (
            r.per_cell < SPARSE_PER_CELL
            or r.coverage < base_cov - COVERAGE_SLACK
            or r.fine < scorer.base_fine - COVERAGE_SLACK
        )

    def evaluate_best(spec: InputSpec, replace: int | None = None):
        """Scored as add-input writes it; if that grid is thin, also with fewer sets for
        the new input (a few coarse counts and what the data fill, coarse to fine until
        :data:`SETS_PATIENCE` in a row bring nothing), compared on every ``stride``-th row;
        the best is scored on all rows and kept if it scores better."""
        fewer_only, fitted = (None, None) if spec.fn in ("dir", "hour") else unfilled(spec, replace)
        if fewer_only:
            # a grid the data cannot fill is not retrained (its coarse levels' node fit is
            # the costliest of all, issue 37): only the fewer sets below are, from the start
            var = variable(spec)
            r = _Score(math.nan, 0.0, fewer_only, var.sets, fine=math.nan)
        else:
            r = evaluate(spec, replace, fitted=fitted)
            if r is None or not thin(r) or spec.fn in ("dir", "hour"):
                return r
        fit = sets_for_cells(scorer.base_rows, scorer.base_rules, r.sets - 1)
        # the bar is the count add-input writes as scored on all rows: fitted again on the
        # quick rows it costs as much (the coarse levels' nodes, not the rows, are the cost)
        best, best_sets = r, r.sets
        # coarse to fine (the finer, the costlier the fit): stop once SETS_PATIENCE counts in
        # a row do not beat the best coarser count by SETS_GAIN
        coarser, misses = math.inf, 0
        for sets in sorted({2, 3, 5, fit, max(fit, r.sets // 4), max(fit, r.sets // 2)}):
            if sets >= r.sets or misses >= SETS_PATIENCE:
                continue
            r2 = evaluate(spec, replace, sets=sets, sc=quick)
            got = math.inf if r2 is None else _sortable(r2.rmse)
            misses = 0 if got < coarser * (1 - SETS_GAIN) else misses + 1
            coarser = min(coarser, got)
            first = bool(fewer_only) and best_sets == r.sets  # nothing scored yet to beat
            if r2 is not None and (first or got < _sortable(best.rmse) * (1 - SETS_GAIN)):
                best, best_sets = r2, sets
        if best_sets == r.sets:
            return None if fewer_only else r
        # on all rows already where the quick scorer is the scorer: not fitted again
        full = best if quick is scorer else evaluate(spec, replace, sets=best_sets)
        if full is None or not _sortable(full.rmse) < _sortable(r.rmse):
            return None if fewer_only else r
        return dc_replace(full, fewer_from=r.sets, thin_before=(r.fine, r.per_cell))

    def screened(spec: InputSpec) -> float:
        """Screening error of ``spec`` (:class:`Screen`; a replaced input is paired with the
        candidate there, so adding and replacing screen alike and retraining tells them
        apart)."""
        var = variable(spec)
        if var is None:
            return math.nan
        return screen.rmse(feats.column(spec), var.sets)

    def unjudged(p: _Pending) -> float:
        """Share of the held-out rows the screen cannot judge ``p`` on (:meth:`Screen.unjudged`)."""
        return screen.unjudged(feats.column(p.spec), variable(p.spec).sets)

    def best_lag(base: InputSpec, lags: Sequence[int], target: np.ndarray, replace=None):
        """Screen ``lags`` by correlation with ``target``, the best few on the screen."""
        lags = list(lags)
        if not lags:
            return None
        col = feats.column(base.with_lag(0))[:cut]
        corr = lag_screen(target, col, max(lags))
        # the best few by correlation, and the shortest lag (no dead time) always
        order = sorted(lags, key=lambda lag: -corr[lag])[:LAGS_SCREENED]
        order = sorted({*order, min(lags)})
        scored = [(screened(base.with_lag(lag)), lag) for lag in order]
        scored = [t for t in scored if math.isfinite(t[0])]
        if not scored:
            return None
        # the shortest lag screened (no dead time, or the nearest to the input's own) where
        # it screens within TOLERANCE of the best: a dead time is suggested only where it
        # clearly matters; once it does, of the lags the screen cannot tell apart (within
        # TOLERANCE of the best) the one best correlated with the target, not the shortest
        # (at 1 s, steps held for minutes screen k-7 within 1 % of a true k-8, which
        # retrained gave 2.23 % against 0.87 % of span: the i34-qa2 pass)
        best, first = min(scored), min(scored, key=lambda t: t[1])
        near = [t[1] for t in scored if t[0] <= best[0] * (1 + TOLERANCE)]
        lag = first[1] if first[1] in near else max(near, key=lambda g: corr[g])
        return lag, dict((b, a) for a, b in scored)[lag]

    found: list[Candidate] = []
    pending: list[_Pending] = []
    name = rb.name

    def add(spec: InputSpec, kind: str, r: _Score, replaces: str | None = None):
        col = feats.column(spec)
        notes = []
        for s, c in zip(in_specs, in_cols, strict=True):
            if replaces and str(s) == replaces:
                continue
            m = np.isfinite(col) & np.isfinite(c)
            if m.sum() > 10 and col[m].std() > 0 and c[m].std() > 0:
                rr = float(np.corrcoef(col[m], c[m])[0, 1])
                if abs(rr) > CORR_WARN:
                    notes.append(
                        f"strongly correlated with {s} (r = {rr:.2f}): the two effects are hard "
                        "to separate in these data"
                    )
        if r.fewer_from:
            cov0, per0 = r.thin_before
            if math.isfinite(cov0):
                notes.append(
                    f"with {r.fewer_from} sets the rule grid would be thin ({per0:.0f} samples "
                    f"per rule, the fine grid answering {cov0:.0%}): {r.sets} sets score better"
                )
            else:
                notes.append(
                    f"with {r.fewer_from} sets the data cannot fill the rule grid ({per0:.1f} "
                    f"samples per rule; not retrained): {r.sets} sets scored best"
                )
        elif thin(r):
            fewer = sets_for_cells(scorer.base_rows, scorer.base_rules, r.sets - 1)
            notes.append(
                f"the rule grid would be thin ({r.per_cell:.0f} samples per rule, the fine grid "
                f"answering {r.fine:.0%} of the samples; coarser rules answer the rest)"
                # never fewer than 2 (one set is no input: the audit saw '--sets 1')
                # and only when materially fewer (at most FEWER_SHARE of the count: the
                # valve's '--sets 30' beside 31 was noise, the i34-qa2 pass)
                + (
                    f": consider fewer sets, e.g. --sets {fewer}"
                    if materially_fewer(fewer, r.sets)
                    else ""
                )
            )
        effect_of_y = False
        if kind == "tag":
            ev = consequence(feats.column(spec.with_lag(0)), y, in_cols, cut, horizon)
            if ev.likely:
                effect_of_y = True
                notes.insert(0, ev.note(spec.tags[0], str(out_spec)))
            elif ev.unjudged:
                notes.insert(0, ev.unjudged_note(spec.tags[0], str(out_spec)))
        cmd = f"diag model add-input {name} '{spec}'"
        if replaces:
            cmd += f" --replace '{replaces}'"
        written = variable(spec)
        if spec.fn not in ("dir", "hour") and written is not None and r.sets != written.sets:
            cmd += f" --sets {r.sets}"
        found.append(
            Candidate(
                input=str(spec),
                kind=kind,
                effect=_wording(kind, spec, replaces, base_rmse, r.rmse, tag_info),
                rmse_pct_if_added=r.rmse,
                coverage=r.coverage,
                command=cmd,
                replaces=replaces,
                notes=notes,
                consequence=effect_of_y,
            )
        )

    def offer(spec: InputSpec, kind: str, rmse: float, replace: int | None = None):
        if math.isfinite(rmse):
            pending.append(_Pending(spec, kind, rmse, replace))

    numeric = [c for c in frame.columns if np.issubdtype(frame[c].dtype, np.number)]
    # every plant tag that is not in the model, at its best lag
    tag_rmse: dict[str, float] = {}
    for tag in numeric:
        if tag in model_tags or tag in out_tags:
            continue
        got = best_lag(InputSpec("", (tag,)), range(0, horizon + 1), resid)
        if got is not None:
            offer(InputSpec("", (tag,), got[0]), "tag", got[1])
            tag_rmse[tag] = got[1]
    # differences of tags with the same unit (a pressure drop), kept only when the
    # difference explains more than either tag alone
    units: dict[str, list[str]] = {}
    for t in numeric:
        u = tag_info[t].unit if t in tag_info else ""
        if u and t not in out_tags:
            units.setdefault(u, []).append(t)
    have = {(s.fn, frozenset(s.tags)) for s in in_specs}
    for group in units.values():
        for i, a in enumerate(group):
            for b in group[i + 1 :]:
                spec = InputSpec("diff", (a, b))
                if ("diff", frozenset((a, b))) in have:
                    continue
                r = screened(spec)
                alone = min(tag_rmse.get(a, base_rmse), tag_rmse.get(b, base_rmse))
                if math.isfinite(r) and r < alone:
                    offer(spec, "difference", r)
    # dead time / more lags, direction of travel, rate of change of each input
    for k, s in enumerate(in_specs):
        if s.fn != "":
            continue
        others = [lag for lag in range(0, horizon + 1) if lag != s.lag]
        got = best_lag(s, others, y[:cut], replace=k)
        if got is not None:
            offer(s.with_lag(got[0]), "dead time", got[1], replace=k)
        have_lags = {x.lag for x in in_specs if x.tags == s.tags and x.fn == ""}
        got = best_lag(s, [lag for lag in others if lag not in have_lags], resid)
        if got is not None:
            offer(s.with_lag(got[0]), "dynamics", got[1])
        for fn, kind in (("dir", "direction"), ("rate", "rate of change")):
            th = dir_threshold(s.tags[0], spans, frame) if fn == "dir" else None
            spec = InputSpec(fn, s.tags, s.lag, th)
            offer(spec, kind, screened(spec))
    notes: list[str] = []
    days = (frame.index[cut - 1] - frame.index[0]) / pd.Timedelta(days=1) if cut > 0 else 0.0
    for fn, kind in (("days", "drift"), ("hour", "time of day")):
        if fn == "days" and days < DRIFT_MIN_DAYS:
            notes.append(
                f"slow drift not offered: the training part of the window spans {days:.1f} "
                f"days; a drift (slower than a day) needs {DRIFT_MIN_DAYS:g} days or more, or "
                "a short window fits any slow wander as one"
            )
            continue
        spec = InputSpec(fn, ())
        offer(spec, kind, screened(spec))
    clock.lap("screen")
    # the best on the screen are retrained and scored as training would score them, and
    # those the screen cannot judge (their held-out values seen only at the edge of the
    # training part) beside them
    pending.sort(key=lambda p: p.screen_rmse)
    refined = _refined(pending, unjudged)
    retrained = {id(p) for p in refined}
    for p in refined:
        r = evaluate_best(p.spec, p.replace)
        if r is not None:
            if p.kind == "drift" and r.rmse < CUTS * base_rmse:
                held = drift_across_blocks(p.spec, r.sets)
                if held is not None:
                    notes.append(
                        f"slow drift not offered: {p.spec} cuts the error on the held-out "
                        f"last part ({base_rmse:.2f} → {r.rmse:.2f} % of span) but not with "
                        f"each of {DRIFT_BLOCKS} stretches of the window held out in turn "
                        f"({held[0]:.2f} → {held[1]:.2f} %): the slow wander of one stretch "
                        "carried forward, not a drift"
                    )
                    continue
            add(p.spec, p.kind, r, replaces=None if p.replace is None else str(in_specs[p.replace]))
    screened_out = [
        {
            "input": str(p.spec),
            "kind": p.kind,
            "replaces": None if p.replace is None else str(in_specs[p.replace]),
            "screen_rmse_pct": _num(p.screen_rmse),
        }
        for p in pending
        if id(p) not in retrained
    ]
    clock.lap("retrain the best")
    # the model's own resolution: spans narrowed to the operating range, more or fewer sets
    # (sets only for methods with rule cells: ts-fcm and narmax2 do not use them)
    uses_sets = rb.new_model().capabilities.rule_regions
    for k, (s, v) in enumerate(zip(in_specs, in_vars, strict=True)):
        for change, var in _resolution_variants(v, in_cols[k][:cut]):
            if var.sets != v.sets and not uses_sets:
                continue
            vs = list(in_vars)
            vs[k] = var
            rmse, cov, _, _ = scorer.score(vs, in_cols)
            if not math.isfinite(rmse):
                continue
            opt = (
                f"--span {var.span[0]:g} {var.span[1]:g}"
                if var.span != v.span
                else f"--sets {var.sets}"
            )
            found.append(
                Candidate(
                    input=str(s),
                    kind="resolution",
                    effect=_resolution_wording(change, base_rmse, rmse),
                    rmse_pct_if_added=rmse,
                    coverage=cov,
                    command=f"diag model set-input {name} '{s}' {opt}",
                )
            )

    clock.lap("resolution")
    # causes that cut the error first, by error; then the rest by error, candidates driven
    # by the output among them (their error is real, but a model using them hides the faults
    # it is built to show: a cause that helps is preferred; where none does, they lead)
    found.sort(key=lambda c: (_tier(c, base_rmse), _sortable(c.rmse_pct_if_added)))
    return Explanation(
        model=name,
        baseline_rmse_pct=base_rmse,
        baseline_coverage=base_cov,
        candidates=found[:top] if top else found,
        validation_from=frame.index[cut] if cut < n else None,
        screened=screened_out,
        screen_sets=screen.pair_sets,
        notes=notes,
        seconds=clock.laps,
        cpu_seconds=clock.cpu,
        baseline=reference,
        heldout_narrow=narrow,
    )


class _Clock:
    """Wall and CPU seconds of each phase of :func:`explain` (what the benchmark prints; on
    a shared machine the CPU seconds are the steadier figure)."""

    def __init__(self) -> None:
        self.laps: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self.t, self.c = time.perf_counter(), time.process_time()

    def lap(self, name: str) -> None:
        now, cpu = time.perf_counter(), time.process_time()
        self.laps[name], self.cpu[name] = now - self.t, cpu - self.c
        self.t, self.c = now, cpu


@dataclass(frozen=True)
class _Pending:
    """A candidate on the screen: its spec, kind, screening error and the input it replaces."""

    spec: InputSpec
    kind: str
    screen_rmse: float
    replace: int | None = None


def _refined(pending: Sequence[_Pending], unjudged: Callable[[_Pending], float]) -> list[_Pending]:
    """The candidates to retrain, from ``pending`` sorted by screening error: the
    :data:`REFINED` best, then at most :data:`UNJUDGED_EXTRA` of the others the screen could
    not judge on :data:`UNJUDGED` of the held-out rows or more (``unjudged``: that share), the
    least judged first (their screening error says nothing)."""
    share = [(unjudged(p), i) for i, p in enumerate(pending[REFINED:], REFINED)]
    rest = sorted((-u, i) for u, i in share if u >= UNJUDGED)  # equal shares: screen's order
    return list(pending[:REFINED]) + [pending[i] for _, i in rest[:UNJUDGED_EXTRA]]


@dataclass(frozen=True)
class _Score:
    rmse: float
    coverage: float
    per_cell: float
    sets: int
    fewer_from: int | None = None
    thin_before: tuple[float, float] | None = None
    fine: float = 1.0  # share of the held-out samples the fine rule grid answered


def _resolution_variants(v: Variable, col: np.ndarray):
    """The model's own resolution for one input: the span narrowed to the operating range
    seen in training (:func:`operating_span`) when that is under 70 % of the span, more sets
    (×1.5) and fewer sets (÷2)."""
    narrow = operating_span(v.span, col)
    if narrow is not None:
        lo, hi = narrow
        yield (
            f"{v.spec} uses only {lo:g} … {hi:g} of its span {v.span[0]:g} … {v.span[1]:g}",
            dc_replace(v, span=(lo, hi)),
        )
    more = int(v.sets * 1.5) | 1
    if more > v.sets:
        yield f"more sets for {v.spec} ({v.sets} → {more})", dc_replace(v, sets=more)
    fewer = max(2, v.sets // 2)
    if fewer < v.sets:
        yield f"fewer sets for {v.spec} ({v.sets} → {fewer})", dc_replace(v, sets=fewer)


def _resolution_wording(change: str, base: float, rmse: float) -> str:
    if rmse < 0.97 * base:
        gain = f"would cut the error from {base:.1f} % to {rmse:.1f} % of span"
    elif rmse < base:
        gain = f"would barely change the error ({base:.1f} % → {rmse:.1f} %)"
    else:
        gain = f"would not cut the error ({base:.1f} % → {rmse:.1f} %)"
    return f"model resolution: {change}: {gain}"


#: a candidate "cuts the error" when it promises less than this share of the baseline
CUTS = 0.97


def _tier(c: Candidate, base: float) -> int:
    """0: not driven by the output and cuts the error (below :data:`CUTS` × baseline);
    1: everything else (consequences, candidates that do not help)."""
    return 0 if not c.consequence and _sortable(c.rmse_pct_if_added) < CUTS * base else 1


def _sortable(v: float) -> float:
    return v if math.isfinite(v) else math.inf


KIND_WORDS = {
    "tag": "{what} not in the model",
    "difference": "{what} not in the model",
    "dead time": "{tag} acts with a different dead time than {old} assumes",
    "dynamics": "another sample of {tag} matters (dynamics)",
    "direction": "the direction of travel of {tag} matters (hysteresis, backlash)",
    "rate of change": "the rate of change of {tag} matters",
    "drift": "a slow drift over time",
    "time of day": "a daily pattern (time of day)",
}
KIND_LABELS = {
    "tag": "{what}",
    "difference": "{what}",
    "dead time": "dead time of {tag}",
    "dynamics": "dynamics of {tag}",
    "direction": "direction of travel of {tag}",
    "rate of change": "rate of change of {tag}",
    "drift": "slow drift",
    "time of day": "time of day",
}


def _wording(kind, spec: InputSpec, replaces, base, rmse, tag_info) -> str:
    """One sentence a plant engineer reads: the physical effect and the gain."""
    tag = spec.tags[0] if spec.tags else ""
    desc = tag_info[tag].description.strip() if tag in tag_info else ""
    what = f"{desc} {tag}".strip() if desc else tag
    if kind == "difference":
        what = f"the difference {spec.tags[0]} − {spec.tags[1]}"
        descs = [tag_info[t].description if t in tag_info else "" for t in spec.tags]
        if all("pressure" in d.lower() for d in descs):
            what = f"the pressure drop {spec.tags[0]} − {spec.tags[1]}"
    verb = "using" if replaces else "adding"
    tail = f" instead of {replaces}" if replaces else ""
    if math.isfinite(rmse) and rmse < 0.97 * base:
        head = KIND_WORDS[kind].format(what=what, tag=tag, old=replaces)
        return (
            f"{head}: {verb} {spec}{tail} would cut the error "
            f"from {base:.1f} % to {rmse:.1f} % of span"
        )
    label = KIND_LABELS[kind].format(what=what, tag=tag)
    if not math.isfinite(rmse):
        return f"{label}: {verb} {spec}{tail} could not be scored"
    if rmse < base:
        return (
            f"{label}: {verb} {spec}{tail} would barely change the error "
            f"({base:.1f} % → {rmse:.1f} %)"
        )
    return f"{label}: {verb} {spec}{tail} would not cut the error ({base:.1f} % → {rmse:.1f} %)"
