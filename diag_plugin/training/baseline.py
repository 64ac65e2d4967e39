"""An established baseline beside every held-out error the workbench states.

scikit-learn's :class:`~sklearn.ensemble.HistGradientBoostingRegressor` fitted on the model's
own design rows (its inputs, lags and derived inputs as the model sees them), on the same
training rows, and scored on the same held-out rows, in % of the output's span (Kościelny
et al., eq. 6), as ``benchmarks/bench_wm_vs_hgb.py`` compares them. scikit-learn (a dependency) is
imported only here, when a command asks for the baseline (``--no-baseline`` skips it).
"""

from __future__ import annotations

import logging
import time

import numpy as np

log = logging.getLogger(__name__)

METHOD = "HistGradientBoostingRegressor"
#: fixed settings: scikit-learn's defaults with early stopping off (its ``auto`` turns it on
#: past 10,000 rows and then holds out a random 10 % of the training rows) and a fixed seed
PARAMS: dict[str, object] = {"max_iter": 100, "early_stopping": False, "random_state": 0}


#: the JSON key of the baseline object in train, compare, explain and report ``--json``
KEY = "hgb_baseline"
#: its name until issue 34, beside the new one for one release (explain's JSON also had
#: ``baseline_rmse_pct``, the model's own held-out error, next to it: two "baselines")
OLD_KEY = "baseline"


def json_keys(b: dict | None) -> dict:
    """The baseline object under :data:`KEY`, and under :data:`OLD_KEY` for the scripts that
    read it there (deprecated: dropped in the release after the next); empty without one."""
    return {} if b is None else {KEY: b, OLD_KEY: b}


def describe(b: dict | None) -> str:
    """One line: the baseline's held-out error and its settings, or why there is none."""
    if not b:
        return ""
    if b.get("rmse_pct") is None:
        return f"baseline {b['method']}: {b.get('note', 'not computed')}"
    p = b["params"]
    stop = "on" if p.get("early_stopping") else "off"
    return (
        f"baseline {b['method']} on the same inputs and rows: held-out RMSE "
        f"{b['rmse_pct']:.2f} %, MAE {b['mae_pct']:.2f} % of span ({b['rows']['held_out']:,} "
        f"held-out rows, {b['rows']['train']:,} training rows; max_iter {p['max_iter']}, "
        f"early stopping {stop}, random_state {p['random_state']}, {b['seconds']:.1f} s)"
    )


def hgb_baseline(
    X_train: np.ndarray,
    y_train: np.ndarray,
    X_held: np.ndarray,
    y_held: np.ndarray,
    span: float,
) -> dict:
    """HistGradientBoosting's held-out error on the given design rows, in % of ``span``.

    Training rows with an input or the output missing are dropped (the model learns nothing
    from them either). Held-out rows without a measured output are not scored; a missing
    input there is left to HistGradientBoosting's own handling (the model's nearest rule
    stands in for it). Returns ``method``, ``params``, ``rmse_pct``, ``mae_pct``, ``rows``
    (``train``, ``held_out``) and ``seconds`` (wall time of the fit and the prediction, on
    one thread); ``rmse_pct`` None with a ``note`` where there is nothing to fit or score.
    """
    out: dict = {"method": METHOD, "params": dict(PARAMS)}
    X_train, X_held = np.asarray(X_train, float), np.asarray(X_held, float)
    y_train, y_held = np.asarray(y_train, float), np.asarray(y_held, float)
    tr = np.isfinite(y_train) & np.isfinite(X_train).all(axis=1)
    va = np.isfinite(y_held)
    out["rows"] = {"train": int(tr.sum()), "held_out": int(va.sum())}
    empty = {"rmse_pct": None, "mae_pct": None, "seconds": 0.0}
    if not tr.any() or not va.any():
        return {**out, **empty, "note": "no training or no held-out rows"}
    from sklearn.ensemble import HistGradientBoostingRegressor
    from threadpoolctl import threadpool_limits

    t = time.perf_counter()
    # one OpenMP thread: on a shared, loaded machine its thread per core spent the time
    # waiting (24,000 rows: 12 s wall, 5 s CPU on two busy cores)
    with threadpool_limits(1):
        m = HistGradientBoostingRegressor(**PARAMS).fit(X_train[tr], y_train[tr])
        r = (y_held[va] - m.predict(X_held[va])) / span * 100.0
    seconds = time.perf_counter() - t
    log.debug("baseline %s: %d + %d rows, %.2f s", METHOD, tr.sum(), va.sum(), seconds)
    return {
        **out,
        "rmse_pct": float(np.sqrt(np.mean(r**2))),
        "mae_pct": float(np.mean(np.abs(r))),
        "seconds": round(seconds, 3),
    }
