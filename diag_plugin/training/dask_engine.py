"""Run chunked training on a Dask distributed cluster.

Each time chunk is read and trained on a worker (the worker reads the
historian itself, so only the model file's text, the chunk bounds and the
chunk's starting design state travel); the partial models come back as their
public state (:meth:`to_state`) and are merged in time order on the client.
Only methods that declare ``mergeable`` run here; for the Wang–Mendel models
the accumulators are exact integers, so the result equals the in-process
training bit for bit. Inputs with unbounded memory (``dir()``) get their
state at every chunk start from a pass over the data on the client
(:func:`diag_plugin.training.chunked.chunk_starts`).

Point it at a real cluster with ``diag train NAME --dask tcp://scheduler:8786``
(:mod:`diag_plugin.training.dask_connect`, as ``diag unit build --dask``); the workers need this
package installed and must reach the historian database (PostgreSQL for a multi-machine
cluster).
"""

from __future__ import annotations

from contextlib import nullcontext
from typing import Any

import pandas as pd

from diag_plugin.models.protocol import Model
from diag_plugin.regressors import DesignBuilder
from diag_plugin.rulebase.document import RuleBase
from diag_plugin.training.chunked import Interval, Reader, Tally, chunk_starts, fit_interval
from diag_plugin.training.dask_connect import connect

#: seconds one training's chunks may take on the cluster (as a build's stage, unitbuild)
DASK_MAP_TIMEOUT = 3600.0


def _fit_on_worker(rb_text: str, read: Reader, a, b, state, history_from):
    return fit_interval(RuleBase(rb_text), read, a, b, state, history_from)


def merge_states(rb: RuleBase, parts) -> tuple[Model, Tally]:
    """Merge partial model states (in time order) into one model, and sum their tallies."""
    model = rb.new_model()
    tally = Tally()
    for state, t in parts:
        tally.add(t.rows, t.dropped)
        if state is not None:
            model.merge(type(model).from_state(state))
    return model, tally


def dask_fitter(cluster: Any, worker_read: Reader, map_timeout: float = DASK_MAP_TIMEOUT):
    """A ``fit_chunks`` callable for :func:`diag_plugin.training.chunked.train` using Dask.

    ``cluster``: a connected ``distributed.Client`` (from
    :func:`diag_plugin.training.dask_connect.connect`; left open), a scheduler address (connected
    and checked as ``--dask`` is, for each training), or None for a cluster in this process.
    ``worker_read`` is the picklable reader the workers call (each opens its own
    connection); the client reads through the reader ``train`` gives it. A training whose
    chunks are not all back within ``map_timeout`` s is a
    :class:`~historian.errors.UserError` naming the address.
    """
    from distributed import Client, as_completed

    from historian.errors import UserError

    def session():
        if cluster is None:
            return Client(processes=False, dashboard_address=None)
        if isinstance(cluster, str):
            return connect(cluster)
        return nullcontext(cluster)

    def fit_chunks(rb: RuleBase, intervals: list[Interval], builder: DesignBuilder, read):
        if not rb.new_model().capabilities.mergeable:
            raise ValueError(f"method {rb.method} cannot merge partial models: train locally")
        starts = chunk_starts(builder, read, intervals, pd.Timedelta(rb.period))
        text = rb.dumps()
        with session() as client:
            futures = [
                client.submit(_fit_on_worker, text, worker_read, a, b, st, h0, pure=False)
                for (a, b), (st, h0) in zip(intervals, starts, strict=True)
            ]
            try:  # the client's own loop: a checked client is not the default one
                for _ in as_completed(futures, loop=client.loop, timeout=map_timeout):
                    pass
            except TimeoutError:
                client.cancel(futures)
                where = client.scheduler.address if cluster is not None else "in-process"
                raise UserError(
                    f"--dask {where}: {len(futures)} chunks of {rb.name} not trained within "
                    f"{map_timeout:g} s"
                ) from None
            parts = client.gather(futures)
        return merge_states(rb, parts)

    return fit_chunks
