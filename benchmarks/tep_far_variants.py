"""What a Wang–Mendel answer past its span should count for (issue 34, branch i34-far): the
unit's matched false alarms and detection on the **tuning** runs of tep-studio under variants
of its inference past the spans, from one built unit.

Variants, each applied to every test's raw residual (:meth:`Unit.raw_residuals`):

* ``reach=R``: the answer moves along the model's trend for up to ``R`` of the span past its
  end (the code's :data:`~diag_plugin.fuzzy._numpy_kernels.REACH`; 0: the edge rule holds);
* ``widen=G``: the residual divided by ``1 + G·d``, ``d`` the largest distance of an input
  past its span in spans (a predictive spread that grows with the extrapolation; tried as
  ``FAR_SPREAD`` in the unit, the threshold learning and the plant, and reverted);
* ``check=D``: the residual unknown (the unit CHECK_FUNCTION) where ``d > D``.

The scores: each limit matched on the calibration runs (seeds 11–13); the share of samples in
alarm on the fault-free tuning samples (tuning seed 101 before its onsets, and the ``--more``
runs, seeds 31–34, also alone); the mean detection over seed 101's faulty samples; one
calibration or ``--more`` run in turn setting the limit, the others scored. The scoring runs
are not read. Run: ``python benchmarks/tep_far_variants.py --more DIR [--unit DIR]``
(``--unit``: keep the built unit there and reuse it).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd


def far_of(model, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Per row of ``X``: the largest distance of an input past its span (in spans), and the
    arrays to redo the trend's move (lo, hi, slopes); None for a model without a rule grid."""
    grid = getattr(model, "inference_grid", None)
    if grid is None or not hasattr(model, "trend_"):
        return None
    g = model.inference_grid()
    lo = np.asarray(g.lo, float)
    hi = lo + np.asarray(g.step, float) * (np.asarray(g.nsets, float) - 1)
    span = np.where(hi > lo, hi - lo, 1.0)
    ex = np.maximum(np.maximum(lo - X, X - hi), 0.0) / span
    return np.nan_to_num(ex).max(axis=1) if X.size else np.zeros(len(X)), lo, hi


def move(X: np.ndarray, lo: np.ndarray, hi: np.ndarray, slope: np.ndarray, reach: float):
    """The trend's move past the spans with ``reach`` (as :func:`._kernels._past`)."""
    r = reach * (hi - lo)
    far = np.clip(X, lo - r, hi + r)
    return np.nansum(slope * (far - np.clip(X, lo, hi)), axis=1)


def patch(reach: float, widen: float, check: float) -> None:
    """The variant: every Wang–Mendel prediction's move past the span redone with ``reach``
    (the model and its inputs kept for the residual), each test's residual then divided or
    made unknown (:meth:`Unit._residual_into`, which follows the prediction in
    :meth:`Unit.raw_residuals`)."""
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.fuzzy._numpy_kernels import REACH
    from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor

    predict = _ORIGINAL.setdefault("predict", WangMendelRegressor.predict_detail)
    into = _ORIGINAL.setdefault("into", Unit._residual_into)
    last: dict = {}

    def predict_detail(self, X):
        pred = predict(self, X)
        X = np.asarray(X, float)
        got = far_of(self, X)
        last.update(pred=pred, dist=None if got is None else got[0])
        if got is not None and reach != REACH:
            _, lo, hi = got
            slope = np.asarray(self.trend_, float)[1:]
            adj = (pred.reason == 3) & (pred.level >= 0)
            y = np.array(pred.y, float)
            y[adj] += (move(X, lo, hi, slope, reach) - move(X, lo, hi, slope, REACH))[adj]
            pred = dataclasses.replace(pred, y=y)
            last["pred"] = pred
        return pred

    def residual_into(self, out, j, at, test, y, pred) -> None:
        into(self, out, j, at, test, y, pred)
        dist = last.get("dist") if last.get("pred") is pred else None
        if dist is not None:
            if widen:
                out[j, at] /= 1.0 + widen * dist
            if np.isfinite(check):
                out[j, at[dist > check]] = np.nan

    WangMendelRegressor.predict_detail = predict_detail
    Unit._residual_into = residual_into


#: the methods :func:`patch` wraps, as they were
_ORIGINAL: dict = {}


def main(argv: list[str] | None = None) -> int:
    from tep_matched_tuning import QUIET, TUNING_ONLY, _more_runs

    from diag_plugin.bench.matched import calibrate, rates
    from diag_plugin.bench.publicbench import build_unit_as_user, unit_score
    from diag_plugin.bench.publicplants import load_braatz, load_tep_studio
    from diag_plugin.diagnose.unit import Unit

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plant", choices=("tep", "tep-studio"), default="tep-studio")
    ap.add_argument("--more", default=None, help="folder of the tunefree runs (seeds 31–34)")
    ap.add_argument("--unit", default="/tmp/i34far_unit", help="the built unit's folder")
    ap.add_argument("--targets", default="0.001,0.005,0.01")
    ap.add_argument("--variants", default="reach=0.25",
                    help="';'-separated, each 'reach=R,widen=G,check=D' (any part)")  # fmt: skip
    args = ap.parse_args(argv)
    plant = load_braatz() if args.plant == "tep" else load_tep_studio(need=TUNING_ONLY)
    folder = Path(args.unit)
    if not (folder / "units").exists():
        built = build_unit_as_user(plant, plant.train, folder)
        print(f"built in {built['seconds']:.0f} s: {built['note']}")
    unit = Unit.load(plant.name, folder / "units")
    on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
    more = _more_runs(args.more) if args.more else {}
    cal = [r.frame for r in plant.calibration]
    if args.plant == "tep":  # the quiet tuning runs take the place of the --more runs
        more = {r.name: r.frame for r in plant.tuning if r.name in QUIET}
        pre = []
        faulty = [(r.frame, 0) for r in plant.tuning if r.name not in QUIET]
    else:
        pre = [r.frame.iloc[: r.onset] for r in plant.tuning]
        faulty = [(r.frame, int(r.onset or 0)) for r in plant.tuning]
    period = plant.period_s
    targets = [float(t) for t in args.targets.split(",")]
    print(f"unit: {len(unit.tests)} tests; calibration {len(cal)} runs; tuning pre-onset "
          f"{sum(map(len, pre))} samples; more {len(more)} runs; {len(faulty)} faulty")  # fmt: skip
    print("| variant | target | pre-onset + more | more alone | detection | one run's limit "
          "(cal + more, each) |")  # fmt: skip
    print("|---" * 6 + "|")
    for spec in args.variants.split(";"):
        kv = dict(p.split("=") for p in spec.split(",") if p)
        patch(float(kv.get("reach", 0.25)), float(kv.get("widen", 0)),
              float(kv.get("check", "inf")))  # fmt: skip

        def score(f: pd.DataFrame) -> np.ndarray:
            return unit_score(unit, f, on, off)[0]

        s_cal = [score(f) for f in cal]
        s_more = [score(f) for f in more.values()]
        s_fault = [(score(f), k) for f, k in faulty]
        # tep-studio: the samples before each onset, from the whole run's score (causal: the
        # same as the piece's alone)
        s_pre = [s[:k] for s, k in s_fault] if pre else []
        for t in targets:
            lim = calibrate(s_cal, t, period).limit
            free = rates(s_pre + s_more, lim, period)[0]
            alone = rates(s_more, lim, period)[0]
            det = np.mean([np.mean(np.nan_to_num(s[k:], nan=-np.inf) > lim) for s, k in s_fault])
            pool = s_cal + s_more
            each = []
            for i in range(len(pool)):
                li = calibrate([pool[i]], t, period).limit
                each.append(rates(pool[:i] + pool[i + 1 :], li, period)[0])
            shown = " ".join(f"{100 * x:.1f}" for x in each)
            row = f"{100 * det:.1f} % | {100 * np.mean(each):.2f} % ({shown}) |"
            print(f"| {spec} | {100 * t:g} % | {100 * free:.2f} % | {100 * alone:.2f} % | {row}",
                  flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
