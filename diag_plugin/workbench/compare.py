"""Compare a model with measurements and show where it fails.

Residuals are in % of the output's nominal span (Kościelny et al., eq. 6).
*Where it fails* is answered three ways: over the input space (per rule cell:
mean, RMSE and count of the residual, and the cells the model has no rule
for), over time (the worst windows), and against every tag of the plant
(how much of the residual each tag explains) — the last points at effects the
model is missing.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from diag_plugin.metrics import error_figures, residual_pct
from diag_plugin.regressors import build_design, needed_tags
from diag_plugin.rulebase.document import RuleBase
from diag_plugin.training.baseline import json_keys
from historian.jsonable import to_jsonable


@dataclass
class Comparison:
    """Model against measurement: aligned series, metrics and failure maps."""

    name: str
    index: pd.DatetimeIndex
    y: np.ndarray
    yhat: np.ndarray
    residual: np.ndarray  # % of span, NaN where unsupported
    reason: np.ndarray
    metrics: dict[str, float]
    regions: pd.DataFrame  # per rule cell
    periods: pd.DataFrame  # per time window
    tags: pd.DataFrame  # residual against each plant tag
    dropped: dict[str, int] = field(default_factory=dict)
    inputs: list[dict] = field(default_factory=list)  # each input's span and the part used
    scope: dict = field(default_factory=dict)  # what the figures measure (:func:`scope`)
    #: HistGradientBoosting on diag train's held-out block (:func:`heldout_baseline`)
    baseline: dict | None = None

    def as_dict(self, top: int = 5) -> dict:
        worst_r = self.regions[self.regions["count"] > 0].nlargest(top, "rmse_pct")
        unsupported = self.regions[self.regions["rule"] == False]  # noqa: E712
        return {
            "model": self.name,
            **self.metrics,
            "samples": int(len(self.y)),
            "dropped": self.dropped,
            "worst_regions": _records(worst_r),
            "unsupported_regions": _records(
                unsupported.nlargest(top, "count") if len(unsupported) else unsupported
            ),
            "worst_periods": _records(self.periods.nlargest(top, "rmse_pct")),
            "tags": _records(self.tags.head(top)),
            "inputs": to_jsonable(self.inputs),
            "scope": to_jsonable(self.scope),
            **json_keys(to_jsonable(self.baseline) if self.baseline is not None else None),
        }


def _records(df: pd.DataFrame) -> list[dict]:
    return to_jsonable(df.to_dict("records"))


def compare(
    rb: RuleBase,
    frame: pd.DataFrame,
    *,
    window: pd.Timedelta | None = None,
    spans: Mapping[str, tuple[float, float]] | None = None,
    baseline: bool = False,
) -> Comparison:
    """Run ``rb``'s model over an aligned frame and locate its errors. ``baseline``: also
    HistGradientBoosting's error on the held-out block ``diag train`` scored
    (:func:`heldout_baseline`)."""
    model = rb.to_model()
    d = build_design(frame, [v.spec for v in rb.inputs], rb.output.spec, spans=spans)
    det = model.predict_detail(d.X)
    span = rb.output.span[1] - rb.output.span[0]
    res = residual_pct(d.y, det.y, span)
    return Comparison(
        name=rb.name,
        index=d.index,
        y=d.y,
        yhat=det.y,
        residual=res,
        reason=det.reason,
        metrics=error_figures(res, residual_pct(d.y, model.extrapolate(d.X), span), det.level),
        regions=error_by_cell(rb, model, d.X, res)
        if model.capabilities.rule_regions
        else _no_regions(rb),
        periods=worst_periods(d.index, res, window),
        tags=residual_vs_tags(frame, d.index, res, exclude=_model_tags(rb), y=d.y, inputs=d.X),
        dropped=d.dropped,
        inputs=span_use(rb, d.X),
        scope=scope(rb, d.index, d.X),
        baseline=heldout_baseline(rb, d.index, d.X, d.y) if baseline else None,
    )


def heldout_baseline(rb: RuleBase, index: pd.DatetimeIndex, X: np.ndarray, y: np.ndarray) -> dict:
    """HistGradientBoosting on the model's design rows, trained on the rows of the model
    file's training range before its held-out block and scored on the rows of that block
    (``[training]`` ``from``, ``validation_from``, ``to``): the figure beside
    ``diag train``'s held-out RMSE, on the rows of ``index`` inside those ranges."""
    from diag_plugin.training.baseline import hgb_baseline

    t = rb.training
    start, cut, end = _time(t.get("from")), _time(t.get("validation_from")), _time(t.get("to"))
    span = rb.output.span[1] - rb.output.span[0]
    if start is None or cut is None or end is None:
        none = np.zeros(len(index), bool)
        b = hgb_baseline(X[none], y[none], X[none], y[none], span)
        return {**b, "note": "the model file does not say which samples diag train held out"}
    tr = (index >= start) & (index < cut)
    va = (index >= cut) & (index < end)
    b = hgb_baseline(X[tr], y[tr], X[va], y[va], span)
    if b["rmse_pct"] is None and "rows" in b and not (tr.any() and va.any()):
        b["note"] = (
            "the compared range holds none of the samples diag train "
            + ("trained on" if not tr.any() else "held out")
            + " (--from/--to over its range for a baseline)"
        )
    return {**b, "heldout_from": cut, "heldout_to": end}


def scope(rb: RuleBase, index: pd.DatetimeIndex, X: np.ndarray | None = None) -> dict:
    """What ``compare``'s figures measure beside ``diag train``'s: the samples scored (count,
    first, last, the model's period), the share of them inside the range the saved model
    was trained on (``in_training``: 1.0 is an in-sample figure, 0.0 out-of-sample), and the
    held-out figure the training reported with the block it was measured on (from the
    file's ``[training]``; None where the file does not say), and the inputs (of ``X``, the
    inputs' values) that block sees at one operating point (:mod:`~diag_plugin.training.
    heldout`)."""
    from diag_plugin.training.heldout import narrow_inputs

    t = rb.training
    start, end = _time(t.get("from")), _time(t.get("to"))
    inside = None
    if start is not None and end is not None and len(index):
        inside = float(np.mean((index >= start) & (index < end)))
    held = t.get("validation_rmse_pct")
    held_from = _time(t.get("validation_from"))
    narrow = []
    if held_from is not None and X is not None and len(index) == len(X):
        narrow = narrow_inputs([v.spec for v in rb.inputs], X, np.asarray(index >= held_from))
    return {
        "samples": int(len(index)),
        "first": index[0] if len(index) else None,
        "last": index[-1] if len(index) else None,
        "period": rb.period,
        "training_range": [start, end] if start is not None else None,
        "in_training": inside,
        "heldout_rmse_pct": float(held) if isinstance(held, (int, float)) else None,
        "heldout_from": held_from,
        "heldout_narrow": narrow,
    }


def _time(v) -> pd.Timestamp | None:
    if v is None:
        return None
    try:
        t = pd.Timestamp(str(v))
    except ValueError:
        return None
    return t.tz_localize("UTC") if t.tzinfo is None else t.tz_convert("UTC")


def scope_note(s: Mapping) -> str:
    """One sentence: which samples the figure scores, and how it relates to the held-out
    figure ``diag train`` printed."""
    if not s.get("samples"):
        return "no samples scored"
    text = f"scored on all {s['samples']:,} samples at {s['period']}"
    inside = s.get("in_training")
    if inside is None:
        text += " (the model file does not say what it was trained on)"
    elif inside >= 0.999:
        text += ", every one used to train the saved model: an in-sample figure"
    elif inside <= 0.001:
        text += ", none of them used to train the saved model: an out-of-sample figure"
    else:
        text += f", {inside:.0%} of them used to train the saved model"
    held = s.get("heldout_rmse_pct")
    if held is not None and s.get("heldout_from") is not None:
        text += (
            f"; diag train's held-out RMSE {held:.2f} % was the model trained without the "
            f"samples from {pd.Timestamp(s['heldout_from']):%Y-%m-%d %H:%M} on, scored on them"
        )
    elif held is not None:
        text += f"; diag train's held-out RMSE was {held:.2f} % (on its last block)"
    from diag_plugin.training.heldout import narrow_note

    return text + "".join("\n" + narrow_note(n) for n in s.get("heldout_narrow", []))


def span_use(rb: RuleBase, X: np.ndarray) -> list[dict]:
    """Per input: its nominal span, the range the data use (0.1–99.9 % quantiles) and the
    used fraction of the span — a model whose inputs use a sliver of their spans is coarser
    there than its set count says."""
    out = []
    for k, v in enumerate(rb.inputs):
        x = X[:, k][np.isfinite(X[:, k])] if len(X) else np.empty(0)
        lo, hi = (float(q) for q in np.quantile(x, [0.001, 0.999])) if x.size else (np.nan,) * 2
        width = v.span[1] - v.span[0]
        used = max(0.0, min(hi, v.span[1]) - max(lo, v.span[0])) / width if x.size else np.nan
        out.append({"input": v.spec, "span": list(v.span), "used": [lo, hi], "used_fraction": used})
    return out


def _model_tags(rb: RuleBase) -> set[str]:
    return set(needed_tags([v.spec for v in rb.inputs] + [rb.output.spec]))


def _no_regions(rb: RuleBase) -> pd.DataFrame:
    """The per-cell table of a model without rule regions: empty."""
    cols = [v.spec for v in rb.inputs] + [f"{v.spec} centre" for v in rb.inputs]
    df = pd.DataFrame(columns=[*cols, "count", "mean_pct", "rmse_pct", "rule"])
    # typed, so the "worst regions" of an empty table are empty rather than an error
    return df.astype({"count": "int64", "mean_pct": float, "rmse_pct": float, "rule": bool})


def error_by_cell(rb: RuleBase, model, X: np.ndarray, res: np.ndarray) -> pd.DataFrame:
    """Residual per rule cell of the inputs (max-membership sets, eq. 3); for models that
    declare ``rule_regions``."""
    keys = model.regions(X)
    ok = np.isfinite(res)
    df = pd.DataFrame({"key": keys, "r": np.where(ok, res, 0.0), "ok": ok})
    df["r2"] = df["r"] ** 2
    g = df.groupby("key", sort=True).agg(
        count=("ok", "size"), supported=("ok", "sum"), s=("r", "sum"), s2=("r2", "sum")
    )
    n = g["supported"].clip(lower=1)
    out = pd.DataFrame(index=g.index)
    labels = model.cell_indices(g.index.to_numpy())
    for k, v in enumerate(rb.inputs):
        out[v.spec] = [v.set_label(int(i)) for i in labels[:, k]]
        out[f"{v.spec} centre"] = model.partitions_[k].centers[labels[:, k]]
    out["count"] = g["count"].to_numpy()
    out["mean_pct"] = np.where(g["supported"] > 0, g["s"] / n, np.nan)
    out["rmse_pct"] = np.where(g["supported"] > 0, np.sqrt(g["s2"] / n), np.nan)
    out["rule"] = np.isin(g.index.to_numpy(), model.keys_)
    return out.reset_index(drop=True)


def worst_periods(
    index: pd.DatetimeIndex, res: np.ndarray, window: pd.Timedelta | None = None
) -> pd.DataFrame:
    """RMSE of the residual per time window (default: :func:`default_window`)."""
    if len(index) == 0:
        return pd.DataFrame(columns=["start", "end", "rmse_pct", "mean_pct", "count"])
    if window is None:
        window = default_window(index, np.isfinite(res))
    s = pd.Series(res, index=index)
    ok = s.notna()
    g = pd.DataFrame({"r2": s.pow(2), "r": s, "ok": ok}).resample(window)
    agg = g.agg({"r2": "sum", "r": "sum", "ok": "sum"})
    n = agg["ok"].clip(lower=1)
    out = pd.DataFrame(
        {
            "start": agg.index,
            "end": agg.index + window,
            "rmse_pct": np.sqrt(agg["r2"] / n),
            "mean_pct": agg["r"] / n,
            "count": agg["ok"].astype(int),
        }
    )
    return out[out["count"] > 0].reset_index(drop=True)


def default_window(index: pd.DatetimeIndex, ok: np.ndarray) -> pd.Timedelta:
    """``compare``'s time window: 1/60 of the time the data cover, in whole hours from an
    hour up; under that in whole minutes (whole seconds under a minute), at least ten
    samples. The time covered is the range, unless the samples fill less than half of it
    (short runs spread over weeks, as SKAB's): then the samples' count times their period —
    a 12-h window on runs of 20 minutes showed nothing."""
    rng = index[-1] - index[0]
    period = (index[1:] - index[:-1]).median() if len(index) > 1 else pd.Timedelta(0)
    covered = int(ok.sum()) * period
    basis = rng if covered >= rng / 2 else covered
    raw = basis / 60
    if raw >= pd.Timedelta(hours=1) or period <= pd.Timedelta(0):
        return max(pd.Timedelta(hours=1), raw.ceil("h"))
    raw = max(raw, 10 * period)
    return raw.ceil("min") if raw >= pd.Timedelta(minutes=1) else raw.ceil("s")


def residual_vs_tags(
    frame: pd.DataFrame,
    index: pd.DatetimeIndex,
    res: np.ndarray,
    exclude: set[str],
    y: np.ndarray | None = None,
    inputs: np.ndarray | None = None,
) -> pd.DataFrame:
    """How much of the residual each other plant tag explains.

    ``explained_pct`` is the share of the residual's variance explained by a
    piecewise-constant fit on deciles of the tag (a model-free, non-linear
    measure, in-sample, the tag alone); ``corr`` is the plain correlation.
    ``diag explain`` ranks differently: by the held-out error of the model retrained
    with the tag (where the tag acts together with the model's inputs, that counts), causes
    before consequences. With the output ``y`` and the model's input rows ``inputs``,
    ``likely_consequence`` flags a tag driven by the output
    (:func:`~diag_plugin.selection.consequence.consequence`, the same test ``explain`` uses);
    ``consequence_unjudged`` marks a tag the output seems to drive where the data cannot tell
    (:attr:`~diag_plugin.selection.consequence.Consequence.unjudged`: not flagged).
    """
    from diag_plugin.selection.consequence import consequence
    from diag_plugin.selection.lags import default_max_lag
    from diag_plugin.selection.scoring import cut_row

    cut = cut_row(index, 0.2) if len(index) > 1 else 0
    horizon = default_max_lag(index)
    rows = []
    r = pd.Series(res, index=index)
    ok = r.notna()
    for tag in frame.columns:
        if tag in exclude or not np.issubdtype(frame[tag].dtype, np.number):
            continue
        x = frame[tag].reindex(index)
        m = ok & x.notna()
        if m.sum() < 20 or x[m].nunique() < 2:
            continue
        xv, rv = x[m].to_numpy(float), r[m].to_numpy(float)
        bins = np.unique(np.quantile(xv, np.linspace(0, 1, 11)))
        which = np.clip(np.searchsorted(bins, xv, side="right") - 1, 0, max(len(bins) - 2, 0))
        means = np.bincount(which, rv) / np.maximum(np.bincount(which), 1)
        resid = rv - means[which]
        var = rv.var()
        explained = 1 - resid.var() / var if var > 0 else 0.0
        corr = float(np.corrcoef(xv, rv)[0, 1]) if xv.std() > 0 and rv.std() > 0 else 0.0
        effect = unjudged = False
        if y is not None and inputs is not None and len(y) == len(index):
            cols = [inputs[:, k] for k in range(inputs.shape[1])]
            ev = consequence(x.to_numpy(float), y, cols, cut, horizon)
            effect, unjudged = ev.likely, ev.unjudged and not ev.likely
        rows.append(
            {
                "tag": tag,
                "explained_pct": 100 * explained,
                "corr": corr,
                "likely_consequence": effect,
                "consequence_unjudged": unjudged,
            }
        )
    columns = ["tag", "explained_pct", "corr", "likely_consequence", "consequence_unjudged"]
    df = pd.DataFrame(rows, columns=columns)
    return df.sort_values("explained_pct", ascending=False).reset_index(drop=True)
