"""Rank candidate missing effects by the out-of-sample error they would leave.

For each candidate input the model is retrained with it added (or, for a
dead time, with an input's lag replaced) on the first part of the data and
scored on the last part — a time-ordered held-out block, never shuffled
samples. Candidates: every other plant tag (at its best lag), differences of
tags that share a unit (a pressure drop), dead time and more lags of the
model's inputs, direction of travel (hysteresis, backlash), rate of change,
slow drift and time of day.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace

import numpy as np
import pandas as pd

from diag_plugin.metrics import residual_pct
from diag_plugin.models.spec import Variable
from diag_plugin.regressors import (
    InputSpec,
    check_regular,
    dir_threshold,
    feature,
    needed_tags,
)
from diag_plugin.rulebase import RuleBase
from diag_plugin.training import split_time
from diag_plugin.workbench.model_edit import variable_for
from historian.taginfo import TagInfo, tag_infos

#: |correlation| with a model input above which a candidate is flagged
CORR_WARN = 0.6
#: validation samples per rule cell below which the grid is called sparse
SPARSE_PER_CELL = 5.0
#: rows used to search a tag's best lag (the best lag is then scored on all rows)
LAG_SEARCH_ROWS = 200_000


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

    def as_dict(self) -> dict:
        d = {
            "input": self.input,
            "kind": self.kind,
            "effect": self.effect,
            "rmse_pct_if_added": _num(self.rmse_pct_if_added),
            "coverage": _num(self.coverage),
            "command": self.command,
            "notes": self.notes,
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

    def as_dict(self, top: int | None = None) -> dict:
        c = self.candidates if top is None else self.candidates[:top]
        return {
            "model": self.model,
            "baseline_rmse_pct": _num(self.baseline_rmse_pct),
            "baseline_coverage": _num(self.baseline_coverage),
            "validation_from": self.validation_from.isoformat() if self.validation_from else None,
            "candidates": [x.as_dict() for x in c],
        }


class _Features:
    """Unlagged feature columns over the frame, computed once, lagged by slicing."""

    def __init__(self, frame: pd.DataFrame, spans: Mapping[str, tuple[float, float]]):
        self.frame = frame
        self.spans = spans
        self.cache: dict[str, np.ndarray] = {}

    def column(self, spec: InputSpec) -> np.ndarray:
        base = spec.base
        if base not in self.cache:
            self.cache[base] = feature(self.frame, spec, self.spans)
        v = self.cache[base]
        if spec.lag:
            v = np.r_[np.full(min(spec.lag, v.size), np.nan), v[: max(v.size - spec.lag, 0)]]
        return v


def _score(
    rb: RuleBase,
    variables: Sequence[Variable],
    cols: Sequence[np.ndarray],
    y: np.ndarray,
    cut: int,
    stride: int = 1,
) -> tuple[float, float, float]:
    """Held-out RMSE in % of span, coverage, and training samples per rule of ``rb``'s
    method with ``variables`` as inputs, trained on rows before ``cut`` (time order)."""
    X = np.column_stack(cols)
    if stride > 1:
        X, y = X[::stride], y[::stride]
        cut = -(-cut // stride)
    ok = np.isfinite(X).all(axis=1) & np.isfinite(y)
    tr = ok.copy()
    tr[cut:] = False
    va = ok.copy()
    va[:cut] = False
    if tr.sum() < 10 or va.sum() < 10:
        return math.nan, 0.0, 0.0
    spec = dc_replace(rb.spec, inputs=list(variables))
    m = rb.codec.new_estimator(spec).fit(X[tr], y[tr])
    r = residual_pct(y[va], m.predict(X[va]), rb.output.span[1] - rb.output.span[0])
    good = np.isfinite(r)
    per_cell = tr.sum() / max(rb.codec.size(m), 1)
    if not good.any():
        return math.nan, 0.0, per_cell
    return float(np.sqrt(np.mean(r[good] ** 2))), float(good.mean()), per_cell


def explain(
    rb: RuleBase,
    frame: pd.DataFrame,
    *,
    tag_info: Mapping[str, TagInfo | Mapping[str, object]] | None = None,
    holdout: float = 0.2,
    max_lag: int = 10,
    top: int | None = None,
) -> Explanation:
    """Candidate missing effects of ``rb``'s model, best first.

    ``tag_info`` maps tag → :class:`~historian.taginfo.TagInfo` (historian
    metadata); spans of new inputs come from it, else from the data.
    """
    check_regular(frame.index)
    tag_info = tag_infos(tag_info)
    known = {s.tags[0]: v.span for v in rb.inputs if (s := InputSpec.parse(v.spec)).fn == ""}
    spans = dict(known)
    spans.update({t: i.span for t, i in tag_info.items() if i.span})
    feats = _Features(frame, spans)
    out_spec = InputSpec.parse(rb.output.spec)
    y = feats.column(out_spec)
    in_specs = [InputSpec.parse(v.spec) for v in rb.inputs]
    in_cols = [feats.column(s) for s in in_specs]
    in_vars = list(rb.inputs)
    default_sets = max(v.sets for v in in_vars) if in_vars else 31
    n = len(frame)
    cut = _cut_row(frame.index, holdout)
    base_rmse, base_cov, _ = _score(rb, in_vars, in_cols, y, cut)
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

    def evaluate(spec: InputSpec, replace: int | None = None, stride: int = 1):
        var = variable(spec)
        if var is None:
            return None
        col = feats.column(spec)
        cols, vs = list(in_cols), list(in_vars)
        if replace is None:
            cols.append(col)
            vs.append(var)
        else:
            cols[replace], vs[replace] = col, var
        rmse, cov, per_cell = _score(rb, vs, cols, y, cut, stride=stride)
        return rmse, cov, per_cell, var.span, var.sets

    def best_lag(base: InputSpec, lags, replace=None):
        stride = max(1, n // LAG_SEARCH_ROWS)
        scored = []
        for lag in lags:
            r = evaluate(base.with_lag(lag), replace, stride)
            if r is not None and math.isfinite(r[0]):
                scored.append((r[0], lag))
        if not scored:
            return None
        lag = min(scored)[1]
        r = evaluate(base.with_lag(lag), replace)
        return (lag, *r) if r is not None else None

    found: list[Candidate] = []
    name = rb.name

    def add(spec: InputSpec, kind: str, res, replaces: str | None = None):
        _, rmse, cov, per_cell, span, sets = res
        col = feats.column(spec)
        notes = []
        for s, c in zip(in_specs, in_cols, strict=True):
            if replaces and str(s) == replaces:
                continue
            m = np.isfinite(col) & np.isfinite(c)
            if m.sum() > 10 and col[m].std() > 0 and c[m].std() > 0:
                r = float(np.corrcoef(col[m], c[m])[0, 1])
                if abs(r) > CORR_WARN:
                    notes.append(
                        f"strongly correlated with {s} (r = {r:.2f}): the two effects are hard "
                        "to separate in these data"
                    )
        if per_cell < SPARSE_PER_CELL or cov < 0.95 * base_cov:
            fewer = max(5, int(sets * 0.5) | 1)
            notes.append(
                f"the rule grid would be sparse ({per_cell:.0f} samples per rule, coverage "
                f"{cov:.0%}): consider fewer sets, e.g. --sets {fewer}"
            )
        quoted = f"'{spec}'"
        cmd = f"diag model add-input {name} {quoted}"
        if replaces:
            cmd += f" --replace '{replaces}'"
        if spec.fn not in ("dir", "hour") and sets != default_sets:
            cmd += f" --sets {sets}"
        found.append(
            Candidate(
                input=str(spec),
                kind=kind,
                effect=_wording(kind, spec, replaces, base_rmse, rmse, tag_info)
                + (f" (on the {cov:.0%} of samples it covers)" if cov < 0.95 * base_cov else ""),
                rmse_pct_if_added=rmse,
                coverage=cov,
                command=cmd,
                replaces=replaces,
                notes=notes,
            )
        )

    numeric = [c for c in frame.columns if np.issubdtype(frame[c].dtype, np.number)]
    # every plant tag that is not in the model, at its best lag
    tag_rmse: dict[str, float] = {}
    for tag in numeric:
        if tag in model_tags or tag in out_tags:
            continue
        r = best_lag(InputSpec("", (tag,)), range(0, max_lag + 1))
        if r is not None:
            add(InputSpec("", (tag,), r[0]), "tag", r)
            tag_rmse[tag] = r[1]
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
                r = evaluate(spec)
                alone = min(tag_rmse.get(a, base_rmse), tag_rmse.get(b, base_rmse))
                if r is not None and math.isfinite(r[0]) and r[0] < alone:
                    add(spec, "difference", (0, *r))
    # dead time / more lags, direction of travel, rate of change of each input
    for k, s in enumerate(in_specs):
        if s.fn != "":
            continue
        others = [lag for lag in range(0, max_lag + 1) if lag != s.lag]
        r = best_lag(s, others, replace=k)
        if r is not None:
            add(s.with_lag(r[0]), "dead time", r, replaces=str(s))
        have = {x.lag for x in in_specs if x.tags == s.tags and x.fn == ""}
        r = best_lag(s, [lag for lag in others if lag not in have])
        if r is not None:
            add(s.with_lag(r[0]), "dynamics", r)
        for fn, kind in (("dir", "direction"), ("rate", "rate of change")):
            th = dir_threshold(s.tags[0], spans, frame) if fn == "dir" else None
            spec = InputSpec(fn, s.tags, s.lag, th)
            r = evaluate(spec)
            if r is not None:
                add(spec, kind, (0, *r))
    for fn, kind in (("days", "drift"), ("hour", "time of day")):
        spec = InputSpec(fn, ())
        r = evaluate(spec)
        if r is not None:
            add(spec, kind, (0, *r))

    found.sort(key=lambda c: (c.coverage < 0.95 * base_cov, _sortable(c.rmse_pct_if_added)))
    return Explanation(
        model=name,
        baseline_rmse_pct=base_rmse,
        baseline_coverage=base_cov,
        candidates=found[:top] if top else found,
        validation_from=frame.index[cut] if cut < n else None,
    )


def _cut_row(index: pd.DatetimeIndex, holdout: float) -> int:
    """First row of the held-out block: the product's one time-based cut."""
    if len(index) == 0:
        return 0
    step = index[1] - index[0] if len(index) > 1 else pd.Timedelta(0)
    t = split_time(index[0], index[-1] + step, holdout)
    return int(index.searchsorted(t))


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
