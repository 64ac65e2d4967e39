"""Chunked training and time-ordered validation of a model file's model.

The data arrive as consecutive, timestamp-indexed chunks of an aligned frame
(the historian's window, or a simulator frame). Memory stays flat in the length
of the range: each chunk is turned into a design matrix by one
:class:`~diag_plugin.regressors.DesignBuilder`, which carries every derived
input's state (direction, rate, lag history) from chunk to chunk and on into
the validation block, and is folded into the model with ``partial_fit``. The
rule base does not depend on the chunking.

Validation is a *time-ordered held-out block* (never shuffled samples): the
model trained on the first part of the range predicts the last part
(default 20 %), and the errors are reported in % of the output's nominal
span (Kościelny et al., eq. 6), counting every held-out sample: where the
model has no rule, its nearest trained rule stands in (``extrapolate``), so a
model cannot look better by predicting less (coverage is reported beside it). The returned model
is then completed with the held-out block too (exact, by ``merge``), so the rule base uses all data
while the reported error stays out-of-sample.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field

import pandas as pd

from diag_plugin.metrics import ErrorStats, residual_pct
from diag_plugin.models.protocol import Model
from diag_plugin.regressors import Design, DesignBuilder
from diag_plugin.rulebase.document import RuleBase
from historian.sampling import snap_near, snap_up
from historian.times import from_us, period_us, to_us

#: samples before the range read to start the state of unbounded-memory inputs (dir())
WARMUP_ROWS = 360
#: model periods read and trained at once (30 days of 10 s data, 3 days of 1 s data): few
#: enough reads that their fixed costs vanish, memory still flat in the length of the range
CHUNK_ROWS = 1 << 18
#: time span read and trained at once; None: :data:`CHUNK_ROWS` periods of the model
DEFAULT_CHUNK: pd.Timedelta | None = None
Reader = Callable[[pd.Timestamp, pd.Timestamp], pd.DataFrame]
Interval = tuple[pd.Timestamp, pd.Timestamp]


@dataclass
class Tally:
    """Rows read and rows dropped per reason, summed over chunks."""

    rows: int = 0
    dropped: dict[str, int] = field(default_factory=dict)

    def add(self, rows: int, dropped: Mapping[str, int]) -> Tally:
        self.rows += rows
        for k, v in dropped.items():
            self.dropped[k] = self.dropped.get(k, 0) + v
        return self

    def add_design(self, d: Design) -> Tally:
        return self.add(d.n_rows, d.dropped)


#: trains a model on chunk intervals elsewhere (e.g. a Dask cluster): gets the file, the
#: intervals, the design builder at the start of the first one and the reader; returns the
#: trained model and the tally, leaving the builder at the end of the last interval
ChunkFitter = Callable[[RuleBase, list[Interval], DesignBuilder, Reader], tuple[Model, Tally]]


def on_grid(t: pd.Timestamp, period: pd.Timedelta | str, how: str = "up") -> pd.Timestamp:
    """``t`` on the model's grid (``k · period`` from the Unix epoch, UTC, the historian's
    grid): the first grid point at or after it (``"up"``) or the nearest one (``"near"``).
    Every boundary the product makes (range ends, hold-out cut, chunk edges) lies on it."""
    p = period_us(pd.Timedelta(period))
    t_us = to_us(t)
    return from_us(snap_up(t_us, p) if how == "up" else snap_near(t_us, p))


def time_chunks(
    start: pd.Timestamp,
    end: pd.Timestamp,
    every: pd.Timedelta,
    period: pd.Timedelta | None = None,
) -> Iterator[tuple[pd.Timestamp, pd.Timestamp]]:
    """Consecutive half-open intervals ``[a, b)`` covering ``[start, end)``; with ``period``
    each is a whole number of periods long (at least one), so grid-aligned ends give
    grid-aligned chunks."""
    if period is not None:
        every = max(1, int(pd.Timedelta(every) // period)) * period
    a = start
    while a < end:
        b = min(a + every, end)
        yield a, b
        a = b


def split_time(
    start: pd.Timestamp,
    end: pd.Timestamp,
    holdout: float,
    period: pd.Timedelta | None = None,
) -> pd.Timestamp:
    """Start of the held-out block: the last ``holdout`` share of the range (the one hold-out
    cut of the product: training, compare and explain all cut by time); with ``period`` the
    nearest grid point. ``holdout = 0``: no held-out block (the cut is ``end``)."""
    if not 0.0 <= holdout < 1.0:
        raise ValueError(f"holdout must be at least 0 and below 1, got {holdout}")
    if holdout == 0.0:
        return end
    cut = start + (end - start) * (1.0 - holdout)
    if period is not None:
        cut = on_grid(cut, period, "near")
    return cut


@dataclass
class TrainResult:
    model: Model
    size: int
    validation: dict[str, float | int]
    training: dict[str, float | int]
    samples: int
    rows: int
    dropped: dict[str, int]
    train_range: tuple[pd.Timestamp, pd.Timestamp]
    validation_range: tuple[pd.Timestamp, pd.Timestamp]
    #: with ``train(keep_rows=True)``: the design rows trained on and held out, as
    #: ``(X_train, y_train, X_held, y_held)`` (for a baseline on exactly those rows)
    design: tuple | None = None
    #: inputs the held-out block sees at one operating point (:mod:`.heldout`)
    heldout_narrow: list[dict] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {
            "heldout_narrow": self.heldout_narrow,
            "validation": self.validation,
            "training": self.training,
            "samples": self.samples,
            "rows": self.rows,
            "dropped": self.dropped,
            "rules": self.size,
            "train_range": [t.isoformat() for t in self.train_range],
            "validation_range": [t.isoformat() for t in self.validation_range],
        }


def design_builder(rb: RuleBase, spans: Mapping[str, tuple[float, float]] | None = None):
    """The design builder of a model file's inputs and output."""
    return DesignBuilder([v.spec for v in rb.inputs], rb.output.spec, spans, period=rb.period)


def warmup_rows(builder: DesignBuilder) -> int:
    """Samples before a range that start the builder's state: the lags, and for inputs with
    unbounded memory (dir()) a longer stretch."""
    return max(builder.history, WARMUP_ROWS if builder.unbounded else 0)


def prime(builder: DesignBuilder, read: Reader, at: pd.Timestamp, period: pd.Timedelta) -> None:
    """Start the builder's state from the data just before ``at`` (nothing to read for a
    model without lags or derived state)."""
    rows = warmup_rows(builder)
    if rows:
        builder.prime(read(at - rows * period, at))


def train(
    rb: RuleBase,
    read: Reader,
    start: pd.Timestamp,
    end: pd.Timestamp,
    *,
    holdout: float = 0.2,
    chunk: pd.Timedelta | None = DEFAULT_CHUNK,
    spans: Mapping[str, tuple[float, float]] | None = None,
    progress: Callable[[int, int], None] | None = None,
    fit_chunks: ChunkFitter | None = None,
    keep_rows: bool = False,
) -> TrainResult:
    """Train ``rb``'s model on ``[start, end)`` read chunk by chunk by ``read(a, b)``.

    ``fit_chunks`` can replace the in-process training pass (the Dask engine
    trains the chunks on workers and merges the partial models). ``keep_rows``: keep the
    design rows of both parts in :attr:`TrainResult.design` (memory grows with the range;
    with ``fit_chunks`` the training part is read a second time here).
    """
    period = pd.Timedelta(rb.period)
    given = pd.Timestamp(start), pd.Timestamp(end)
    start, end = on_grid(given[0], period), on_grid(given[1], period)
    if end <= start:
        raise ValueError(
            f"no sample of the model's {rb.period} grid between {given[0]} and {given[1]}"
        )
    cut = split_time(start, end, holdout, period)
    if chunk is None:
        chunk = CHUNK_ROWS * period
    if holdout > 0 and not start < cut < end:
        raise ValueError(
            f"{(end - start) // period} samples of {rb.period} from {start} to {end} are too "
            f"few to hold out {holdout:.0%}: give a longer range, or --holdout 0 to train on "
            "all of it without a validation figure"
        )
    train_iv = list(time_chunks(start, cut, chunk, period))
    val_iv = list(time_chunks(cut, end, chunk, period))
    total = len(train_iv) + len(val_iv)
    span = rb.output.span[1] - rb.output.span[0]
    done = 0
    model = rb.new_model()
    caps = model.capabilities
    # a method that is not incremental and mergeable (ts-fcm) keeps the design rows of the
    # range in memory and is fitted once: on the training part, then on all of it
    whole = not (caps.incremental and caps.mergeable)
    if whole and fit_chunks is not None:
        raise ValueError(f"method {rb.method} cannot be trained chunk by chunk on workers")
    rows: list[tuple] = []
    kept: dict[str, list[tuple]] = {"train": [], "held": []}

    builder = design_builder(rb, spans)
    prime(builder, read, start, period)
    train_range = _Ranges()  # (not seen with fit_chunks: no held-out check then)
    if fit_chunks is not None:
        if keep_rows:
            local = design_builder(rb, spans)
            prime(local, read, start, period)
            for a, b in train_iv:
                d = local.transform(read(a, b))
                kept["train"].append((d.X, d.y))
        model, tally = fit_chunks(rb, train_iv, builder, read)
        done += len(train_iv)
        if progress:
            progress(done, total)
    else:
        tally = Tally()
        for a, b in train_iv:
            d = builder.transform(read(a, b))
            tally.add_design(d)
            train_range.add(d.X)
            if keep_rows:
                kept["train"].append((d.X, d.y))
            if len(d.y) and whole:
                rows.append((d.X, d.y))
            elif len(d.y):
                model.partial_fit(d.X, d.y)
            done += 1
            if progress:
                progress(done, total)
    if whole and rows:
        model.fit(*_stack(rows))
    n_train = int(getattr(model, "n_samples_seen_", 0))
    if n_train == 0:
        raise ValueError(f"no usable training samples between {start} and {cut}")
    predictor = rb.predictor(model)

    val_stats = ErrorStats()
    held = rb.new_model()
    held_range = _Ranges()
    for a, b in val_iv:
        d = builder.transform(read(a, b))
        tally.add_design(d)
        if keep_rows:
            kept["held"].append((d.X, d.y))
        if len(d.y):
            held_range.add(d.X)
            det = predictor.predict_detail(d.X)
            val_stats.update(
                residual_pct(d.y, det.y, span),
                residual_pct(d.y, _stand_in(predictor, d.X, det.y), span),
                det.level,
            )
            if whole:
                rows.append((d.X, d.y))
            else:
                held.partial_fit(d.X, d.y)
        done += 1
        if progress:
            progress(done, total)
    if whole:
        model = rb.new_model().fit(*_stack(rows))
    else:
        model.merge(held)
    return TrainResult(
        model=model,
        size=rb.codec.size(model),
        validation=val_stats.result(),
        training={"samples": n_train},
        samples=int(model.n_samples_seen_),
        rows=tally.rows,
        dropped=tally.dropped,
        train_range=(start, cut),
        validation_range=(cut, end),
        heldout_narrow=held_range.narrow([v.spec for v in rb.inputs], train_range),
        design=(*_stack(kept["train"]), *_stack(kept["held"])) if keep_rows else None,
    )


class _Ranges:
    """The least and greatest value of each design column over the chunks added."""

    def __init__(self):
        self.lo = self.hi = None

    def add(self, X) -> None:
        import numpy as np

        if X is None or not len(X):
            return
        lo, hi = np.fmin.reduce(X, axis=0), np.fmax.reduce(X, axis=0)  # NaN: no value
        self.lo = lo if self.lo is None else np.fmin(self.lo, lo)
        self.hi = hi if self.hi is None else np.fmax(self.hi, hi)

    def narrow(self, specs, other: _Ranges) -> list[dict]:
        """:func:`~.heldout.narrow_ranges` of these (held-out) ranges within these and
        ``other``'s (training) together; empty where either saw nothing."""
        import numpy as np

        from diag_plugin.training.heldout import narrow_ranges

        if self.lo is None or other.lo is None:
            return []
        lo, hi = np.fmin(self.lo, other.lo), np.fmax(self.hi, other.hi)
        return narrow_ranges(specs, lo, hi, self.lo, self.hi)


def _stand_in(predictor, X, y_hat):
    """The prediction with the model's stand-in (``extrapolate``) where it has none, asking
    the model only about those rows (rows are scored one by one; ``extrapolate`` of all of
    them would infer the whole block a second time)."""
    import numpy as np

    miss = ~np.isfinite(y_hat)
    if not miss.any():
        return y_hat
    out = y_hat.copy()
    out[miss] = predictor.extrapolate(X[miss])
    return out


def _stack(rows: list[tuple]) -> tuple:
    """The design rows of several chunks as one ``X``, ``y``."""
    import numpy as np

    if not rows:
        return np.empty((0, 0)), np.empty(0)
    return np.vstack([x for x, _ in rows]), np.concatenate([y for _, y in rows])


def chunk_starts(
    builder: DesignBuilder, read: Reader, intervals: Iterable[Interval], period: pd.Timedelta
) -> list[tuple[dict | None, pd.Timestamp]]:
    """Where each chunk's design starts, for training the chunks independently (workers).

    Per interval ``[a, b)``: a builder state to load (or None for a fresh one)
    and the time from which to read history up to ``a``. Inputs with bounded
    memory (lags, rate) are exact from the last ``history`` samples, read by
    the worker; with an unbounded one (dir()) the states are carried here by a
    pass over the data, so every chunk starts exactly where one pass would be.
    ``builder`` is left at the end of the last interval.
    """
    out: list[tuple[dict | None, pd.Timestamp]] = []
    intervals = list(intervals)
    if builder.unbounded:
        for a, b in intervals:
            out.append((builder.to_state(), a))
            builder.advance(read(a, b))
        return out
    for i, (a, _) in enumerate(intervals):
        out.append((builder.to_state(), a) if i == 0 else (None, a - builder.history * period))
    if intervals and builder.history:
        b = intervals[-1][1]
        builder.advance(read(b - builder.history * period, b))
    return out


def fit_interval(
    rb: RuleBase,
    read: Reader,
    a: pd.Timestamp,
    b: pd.Timestamp,
    state: dict | None,
    history_from: pd.Timestamp,
) -> tuple[dict | None, Tally]:
    """Train one chunk ``[a, b)`` from where :func:`chunk_starts` says it starts; returns the
    model's state (None if no usable rows) and the tally."""
    builder = design_builder(rb)
    if state is not None:
        builder.load_state(state)
    if history_from < a:
        builder.advance(read(history_from, a))
    d = builder.transform(read(a, b))
    tally = Tally().add_design(d)
    if not len(d.y):
        return None, tally
    return rb.new_model().partial_fit(d.X, d.y).to_state(), tally
