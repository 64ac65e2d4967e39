"""Chunked training and time-ordered validation of a rule-base model.

The data arrive as consecutive, timestamp-indexed chunks of an aligned frame
(the historian's window, or a simulator frame). Memory stays flat in the length
of the range: each chunk is turned into a design matrix and folded into the
model with ``partial_fit``. Lagged inputs see across chunk boundaries because
the tail of the previous chunk is carried over as context.

Validation is a *time-ordered held-out block* (never shuffled samples): the
model trained on the first part of the range predicts the last part
(default 20 %), and the errors are reported in % of the output's nominal
span (Kościelny et al., eq. 6). The returned model is then completed with
the held-out block too (exact, by ``merge``), so the rule base uses all data
while the reported error stays out-of-sample.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor
from diag_plugin.regressors import build_design, max_lag, needed_tags
from diag_plugin.rulebase import RuleBase

#: rows of the previous chunk kept as context for lags and dir() state
CONTEXT_ROWS = 360
#: time span read and trained at once
DEFAULT_CHUNK = pd.Timedelta(days=7)
#: trains the model on a list of chunk intervals (e.g. on a Dask cluster)
ChunkFitter = Callable[[RuleBase, Iterable[tuple[pd.Timestamp, pd.Timestamp]]], WangMendelRegressor]


@dataclass
class ErrorStats:
    """Streaming residual statistics in % of span (eq. 6), mergeable."""

    span: float
    n: int = 0
    n_total: int = 0
    s1: float = 0.0
    s2: float = 0.0
    sabs: float = 0.0
    maxabs: float = 0.0

    def update(self, y: np.ndarray, yhat: np.ndarray) -> None:
        r = residual_pct(y, yhat, self.span)
        self.n_total += r.size
        r = r[np.isfinite(r)]
        self.n += r.size
        self.s1 += float(r.sum())
        self.s2 += float(r @ r)
        self.sabs += float(np.abs(r).sum())
        if r.size:
            self.maxabs = max(self.maxabs, float(np.abs(r).max()))

    def merge(self, other: ErrorStats) -> ErrorStats:
        self.n += other.n
        self.n_total += other.n_total
        self.s1 += other.s1
        self.s2 += other.s2
        self.sabs += other.sabs
        self.maxabs = max(self.maxabs, other.maxabs)
        return self

    def result(self) -> dict[str, float | int]:
        n = max(self.n, 1)
        nan = float("nan")
        return {
            "rmse_pct": float(np.sqrt(self.s2 / n)) if self.n else nan,
            "mae_pct": self.sabs / n if self.n else nan,
            "bias_pct": self.s1 / n if self.n else nan,
            "max_abs_pct": self.maxabs if self.n else nan,
            "coverage": self.n / self.n_total if self.n_total else nan,
            "samples": self.n_total,
        }


def residual_pct(y: np.ndarray, yhat: np.ndarray, span: float) -> np.ndarray:
    """Residual in % of the nominal span: ``(y − ŷ) / (y_max − y_min) · 100`` (eq. 6)."""
    return (np.asarray(y, float) - np.asarray(yhat, float)) / span * 100.0


def time_chunks(
    start: pd.Timestamp, end: pd.Timestamp, every: pd.Timedelta
) -> Iterator[tuple[pd.Timestamp, pd.Timestamp]]:
    """Consecutive half-open intervals ``[a, b)`` covering ``[start, end)``."""
    a = start
    while a < end:
        b = min(a + every, end)
        yield a, b
        a = b


def split_time(start: pd.Timestamp, end: pd.Timestamp, holdout: float) -> pd.Timestamp:
    """Start of the held-out block: the last ``holdout`` share of the range."""
    if not 0.0 < holdout < 1.0:
        raise ValueError(f"holdout must be between 0 and 1, got {holdout}")
    return start + (end - start) * (1.0 - holdout)


@dataclass
class TrainResult:
    model: WangMendelRegressor
    validation: dict[str, float | int]
    training: dict[str, float | int]
    samples: int
    rows: int
    dropped: dict[str, int]
    train_range: tuple[pd.Timestamp, pd.Timestamp]
    validation_range: tuple[pd.Timestamp, pd.Timestamp]

    def as_dict(self) -> dict:
        return {
            "validation": self.validation,
            "training": self.training,
            "samples": self.samples,
            "rows": self.rows,
            "dropped": self.dropped,
            "rules": self.model.n_rules_,
            "train_range": [t.isoformat() for t in self.train_range],
            "validation_range": [t.isoformat() for t in self.validation_range],
        }


class Designer:
    """Turns consecutive frame chunks into design matrices, carrying context."""

    def __init__(self, rb: RuleBase, spans: Mapping[str, tuple[float, float]] | None = None):
        self.inputs = [v.spec for v in rb.inputs]
        self.output = rb.output.spec
        self.tags = needed_tags([*self.inputs, self.output])
        self.spans = spans
        self.context = max(CONTEXT_ROWS, max_lag([*self.inputs, self.output]) + 1)
        self._tail: pd.DataFrame | None = None
        self.dropped: dict[str, int] = {}
        self.rows = 0

    def __call__(self, frame: pd.DataFrame):
        missing = [t for t in self.tags if t not in frame.columns]
        if missing:
            raise KeyError(f"tag(s) {', '.join(missing)} needed by the model are not in the data")
        frame = frame[self.tags]
        n_ctx = 0
        tail = trim_context(self._tail) if self._tail is not None else None
        if tail is not None and len(tail) and len(frame):
            n_ctx = len(tail)
            frame = pd.concat([tail, frame])
        d = build_design(frame, self.inputs, self.output, spans=self.spans, context=n_ctx)
        self._tail = frame.iloc[-self.context :] if len(frame) else self._tail
        for k, v in d.dropped.items():
            self.dropped[k] = self.dropped.get(k, 0) + v
        self.rows += d.n_rows
        return d.X, d.y, d.index

    def prime(self, history: pd.DataFrame) -> None:
        """Use the data just before the first chunk as context (lags, dir() state)."""
        if len(history):
            self._tail = history[self.tags].iloc[-self.context :]


def trim_context(tail: pd.DataFrame) -> pd.DataFrame:
    """Context without its leading rows where every tag is missing (before the data start)."""
    has = tail.notna().any(axis=1).to_numpy()
    first = int(np.argmax(has)) if has.any() else len(tail)
    return tail.iloc[first:]


def train(
    rb: RuleBase,
    read: Callable[[pd.Timestamp, pd.Timestamp], pd.DataFrame],
    start: pd.Timestamp,
    end: pd.Timestamp,
    *,
    holdout: float = 0.2,
    chunk: pd.Timedelta = DEFAULT_CHUNK,
    spans: Mapping[str, tuple[float, float]] | None = None,
    progress: Callable[[int, int], None] | None = None,
    fit_chunks: ChunkFitter | None = None,
) -> TrainResult:
    """Train ``rb``'s model on ``[start, end)`` read chunk by chunk by ``read(a, b)``.

    ``fit_chunks`` can replace the in-process training pass (the Dask engine
    trains the chunks on workers and merges the partial models).
    """
    start, end = pd.Timestamp(start), pd.Timestamp(end)
    if end <= start:
        raise ValueError(f"empty training range: {start} … {end}")
    cut = split_time(start, end, holdout)
    train_iv = list(time_chunks(start, cut, chunk))
    val_iv = list(time_chunks(cut, end, chunk))
    total = len(train_iv) + len(val_iv)
    span = rb.output.span[1] - rb.output.span[0]
    done = 0

    designer = Designer(rb, spans)
    period = pd.Timedelta(rb.period)
    if fit_chunks is not None:
        model = fit_chunks(rb, train_iv)
        done += len(train_iv)
        if progress:
            progress(done, total)
    else:
        model = rb.new_model()
        designer.prime(read(start - designer.context * period, start))
        for a, b in train_iv:
            X, y, _ = designer(read(a, b))
            if len(y):
                model.partial_fit(X, y)
            done += 1
            if progress:
                progress(done, total)
    if not hasattr(model, "partitions_"):
        raise ValueError(f"no usable training samples between {start} and {cut}")
    predictor = with_locks(rb, model)

    val_stats = ErrorStats(span)
    held = rb.new_model()
    vdesigner = Designer(rb, spans)
    if designer._tail is None:  # training ran elsewhere: read the context before the cut
        designer.prime(read(cut - designer.context * period, cut))
        designer.dropped = dict(getattr(model, "dropped_", {}))
        designer.rows = int(getattr(model, "rows_", 0))
    vdesigner._tail = designer._tail
    for a, b in val_iv:
        X, y, _ = vdesigner(read(a, b))
        if len(y):
            val_stats.update(y, predictor.predict(X))
            held.partial_fit(X, y)
        done += 1
        if progress:
            progress(done, total)
    dropped = dict(designer.dropped)
    for k, v in vdesigner.dropped.items():
        dropped[k] = dropped.get(k, 0) + v
    n_train = int(model.n_samples_seen_)
    model.merge(held)
    return TrainResult(
        model=model,
        validation=val_stats.result(),
        training={"samples": n_train},
        samples=int(model.n_samples_seen_),
        rows=designer.rows + vdesigner.rows,
        dropped=dropped,
        train_range=(start, cut),
        validation_range=(cut, end),
    )


def with_locks(rb: RuleBase, model: WangMendelRegressor) -> WangMendelRegressor:
    """A copy of a trained model with the experts' locked rules applied.

    The trained model itself keeps its exact statistics (for ``merge``); the
    rule base applies the locks again when it takes the training.
    """
    locked = [r for r in rb.rules if r.lock]
    if not locked:
        return model
    out = WangMendelRegressor(**model.get_params()).merge(model)
    conc = dict(zip(out.keys_.tolist(), out.conclusions_.tolist(), strict=True))
    for r in locked:
        k = int(out.cell_keys(np.array([r.premise]))[0])
        if np.isnan(r.then):
            conc.pop(k, None)
        else:
            conc[k] = r.then
    ks = sorted(conc)
    return out.set_rules(ks, [conc[k] for k in ks])
