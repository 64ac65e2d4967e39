"""Run chunked Wang–Mendel training on a Dask distributed cluster.

Each time chunk is read and trained on a worker (the worker reads the
historian itself, so only the rule base text and the chunk bounds travel);
the partial models come back as count / sum / sum-of-squares arrays and are
merged in time order on the client. Because the accumulators are exact
integers, the result equals the in-process training bit for bit.

Point it at a real cluster with ``diag train NAME --engine dask --scheduler
tcp://scheduler:8786``; the workers need this package installed and must
reach the historian database (PostgreSQL for a multi-machine cluster).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np
import pandas as pd

from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor
from diag_plugin.regressors import build_design, max_lag, needed_tags
from diag_plugin.rulebase import RuleBase
from diag_plugin.training import CONTEXT_ROWS, trim_context

Reader = Callable[[pd.Timestamp, pd.Timestamp], pd.DataFrame]


def _context_rows(rb: RuleBase) -> int:
    return max(CONTEXT_ROWS, max_lag([*(v.spec for v in rb.inputs), rb.output.spec]) + 1)


def fit_interval(
    rb_text: str, reader: Reader, a: pd.Timestamp, b: pd.Timestamp
) -> dict[str, object]:
    """Train one chunk ``[a, b)`` with the history before it as context (runs on a worker)."""
    rb = RuleBase(rb_text)
    period = pd.Timedelta(rb.period)
    ctx = _context_rows(rb)
    frame = reader(a - ctx * period, b)
    tags = needed_tags([*(v.spec for v in rb.inputs), rb.output.spec])
    frame = frame[tags]
    context = trim_context(frame[frame.index < a].iloc[-ctx:])
    frame = pd.concat([context, frame[frame.index >= a]])
    n_ctx = len(context)
    d = build_design(frame, [v.spec for v in rb.inputs], rb.output.spec, context=n_ctx)
    if len(d.y) == 0:
        return {"empty": True, "dropped": d.dropped, "rows": d.n_rows}
    m = rb.new_model().partial_fit(d.X, d.y)
    return {k: getattr(m, k) for k in STATE} | {"dropped": d.dropped, "rows": d.n_rows}


STATE = ("keys_", "count_", "qsum_", "qsq_", "best_w_", "best_set_", "n_skipped_")


def merge_states(rb: RuleBase, parts: Iterable[dict | None]) -> WangMendelRegressor:
    """Merge partial states in time order into one model."""
    model = rb.new_model()
    model._init_partitions(np.zeros((1, len(rb.inputs))), np.zeros(1))
    model.dropped_, model.rows_ = {}, 0
    for p in parts:
        if p is None:
            continue
        model.rows_ += p["rows"]
        for k, v in p["dropped"].items():
            model.dropped_[k] = model.dropped_.get(k, 0) + v
        if p.get("empty"):
            continue
        model._merge_state(
            p["keys_"],
            p["count_"],
            p["qsum_"],
            p["qsq_"],
            p["best_w_"],
            p["best_set_"],
            p["n_skipped_"],
        )
    model._lut = None
    return model


def dask_fitter(scheduler: str | None, reader: Reader):
    """A ``fit_chunks`` callable for :func:`diag_plugin.training.train` using Dask."""
    from distributed import Client

    def fit_chunks(rb: RuleBase, intervals) -> WangMendelRegressor:
        text = rb.dumps()
        with (
            Client(scheduler, timeout="30s")
            if scheduler
            else Client(processes=False, dashboard_address=None) as client
        ):
            futures = [
                client.submit(fit_interval, text, reader, a, b, pure=False) for a, b in intervals
            ]
            parts = client.gather(futures)
        return merge_states(rb, parts)

    return fit_chunks
