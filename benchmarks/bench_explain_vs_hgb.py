"""Follow ``explain``'s top suggestions on the 60-day valve and put the result beside
scikit-learn's HistGradientBoosting on the same split (issue 8, "resolution").

Model ``F = f(CV[k-1], P1[k], P2[k])`` with nominal spans (P1, P2 over 0–4,000 kPa) and 31
sets; each step applies ``explain``'s best candidate exactly as its command says and retrains.
Prints, per step, the promised and the trained held-out RMSE (% of the 0–40 t/h span) and
coverage. scikit-learn is not a dependency: without it only our figures are printed
(``pip install scikit-learn`` for the comparison).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from diag_plugin.simulate.valve import TAGS, simulate_valve
from diag_plugin.training.chunked import train
from diag_plugin.workbench.explain import explain
from diag_plugin.workbench.model_edit import add_input, new_model, set_input

STEPS = 5


def follow(best, rb, frame):
    w = best.command.split()
    sets = int(w[w.index("--sets") + 1]) if "--sets" in w else None
    if best.kind == "resolution":
        i = w.index("--span") if "--span" in w else None
        span = (float(w[i + 1]), float(w[i + 2])) if i else None
        return set_input(rb, best.input, span=span, sets=sets)
    return add_input(rb, best.input, frame=frame, tag_info=TAGS, replace=best.replaces, sets=sets)


def hgb(frame: pd.DataFrame, columns: dict[str, pd.Series], cut) -> float | None:
    try:
        from sklearn.ensemble import HistGradientBoostingRegressor
    except ImportError:
        return None
    X = pd.DataFrame(columns)
    y = frame["F"]
    ok = X.notna().all(axis=1) & y.notna()
    tr, va = ok & (frame.index < cut), ok & (frame.index >= cut)
    m = HistGradientBoostingRegressor(max_iter=500, random_state=0).fit(X[tr], y[tr])
    r = (y[va] - m.predict(X[va])) / 40 * 100
    return float(np.sqrt(np.mean(r**2)))


def main(seed: int = 12) -> int:
    f = simulate_valve(60, seed=seed)[["CV", "P1", "P2", "T1", "X", "F"]]
    a, b = f.index[0], f.index[-1] + pd.Timedelta("10s")
    read = lambda s, t: f[(f.index >= s) & (f.index < t)]  # noqa: E731
    with tempfile.TemporaryDirectory() as d:
        rb = new_model(
            Path(d) / "v.toml",
            "v",
            "F[k]",
            ["CV[k-1]", "P1[k]", "P2[k]"],
            frame=f,
            tag_info=TAGS,
            sets=31,
        )
        res = train(rb, read, a, b)
        v = res.validation
        print(f"start: held-out RMSE {v['rmse_pct']:.3f} % of span, coverage {v['coverage']:.1%}")
        for step in range(1, STEPS + 1):
            t = time.perf_counter()
            e = explain(rb, f, tag_info=TAGS, top=1)
            best = e.candidates[0]
            if not best.rmse_pct_if_added < 0.99 * e.baseline_rmse_pct:
                print("nothing left that cuts the error")
                break
            rb = follow(best, rb, f)
            v = train(rb, read, a, b).validation
            print(
                f"step {step}: {best.command}\n   promised {best.rmse_pct_if_added:.3f} %, "
                f"trained {v['rmse_pct']:.3f} %, coverage {v['coverage']:.1%} "
                f"({time.perf_counter() - t:.0f} s)"
            )
        final = [x.spec for x in rb.inputs]
    cut = res.validation_range[0]
    base = {"CV1": f["CV"].shift(1), "P1": f["P1"], "P2": f["P2"]}
    h3 = hgb(f, base, cut)
    if h3 is None:
        print("scikit-learn not installed: no HistGradientBoosting comparison")
        return 0
    print(f"HistGradientBoosting, inputs CV[k-1], P1, P2: {h3:.3f} %")
    extra = {"dP": f["P1"] - f["P2"], "X": f["X"]}
    h5 = hgb(f, base | extra, cut)
    print(
        f"HistGradientBoosting, inputs + P1-P2, X: {h5:.3f} %   (final model: {', '.join(final)})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(*(int(a) for a in sys.argv[1:])))
