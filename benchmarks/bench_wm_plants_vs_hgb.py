"""Wang–Mendel beside scikit-learn's HistGradientBoosting on several plants, held-out (issue 37).

For each plant a model of a few inputs is scored on the last 20 % of the window (time-ordered,
as ``diag train`` scores: the nearest rule where the model has no answer) with

- 31 sets per input over the nominal spans (``diag model new --sets 31``);
- 31 sets over the spans narrowed to the operating range (``explain``'s resolution suggestion);
- each of those with the sets per input searched
  (:func:`~diag_plugin.selection.setsearch.choose_sets`, what ``diag model new`` does when the
  fine grid is thin; "not searched" where the fine grid already answers 80 %);
- each of those with the paper's trapezoidal sets and with the shape ``diag model new`` chooses
  (:func:`~diag_plugin.selection.setsearch.choose_shape`; "chosen: trapezoidal" where it keeps
  the paper's);

beside HistGradientBoostingRegressor (defaults, ``random_state=0``) on the same rows. Every
choice (shape, sets) is made on the training part alone — its own last 20 % held out — never
on the scored tail. Plants: the valve (60 days at 10 s, seed 12, as bench_wm_vs_hgb.py), the
tank and the heat exchanger (smallplants, 20 days averaged to 10 s) and the chemical plant's
4-D feed blend (30 days at 1 min, as bench_explain.py).

    python benchmarks/bench_wm_plants_vs_hgb.py [valve tank heatex blend]
"""

from __future__ import annotations

import copy
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_explain import frame_and_tags  # noqa: E402

from diag_plugin.regressors import InputSpec, feature  # noqa: E402
from diag_plugin.selection.scoring import HeldOutScorer, cut_row  # noqa: E402
from diag_plugin.selection.setsearch import choose_sets, choose_shape  # noqa: E402
from diag_plugin.selection.spans import operating_span  # noqa: E402
from diag_plugin.workbench.model_edit import new_model  # noqa: E402


def plant(which: str):
    if which == "valve":
        from diag_plugin.simulate.valve import TAGS, simulate_valve

        f = simulate_valve(60, seed=12)[["CV", "P1", "P2", "F"]]
        return f, TAGS, "F[k]", ["CV[k-1]", "P1[k]", "P2[k]"], "10s"
    if which == "blend":
        cache = Path(tempfile.gettempdir()) / "bench_explain"
        cache.mkdir(exist_ok=True)
        f, info = frame_and_tags("blend", cache, 30.0)
        return f, info, "TI102[k]", ["FI101[k]", "TI101[k]", "FI102[k]", "TI109[k]"], "60s"
    from diag_plugin.simulate import smallplants as sp

    tags = sp.TANK_TAGS if which == "tank" else sp.HEATEX_TAGS
    info = {t: {"unit": u, "lo": lo, "hi": hi} for t, (u, lo, hi, _) in tags.items()}
    if which == "tank":
        f = sp.simulate_tank(20, seed=4).resample("10s").mean()
        return f, info, "FI102[k]", ["LIC101.OUT[k]", "LT101[k]"], "10s"
    f = sp.simulate_heat_exchanger(20, seed=4).resample("10s").mean()
    return f, info, "TI202[k]", ["FI201[k]", "TI201[k]", "TI203[k]", "FI202[k-3]"], "10s"


def main(argv=None) -> int:
    from sklearn.ensemble import HistGradientBoostingRegressor

    for which in argv if argv else ["valve", "tank", "heatex", "blend"]:
        f, info, out, ins, period = plant(which)
        d = Path(tempfile.mkdtemp())
        rb = new_model(d / "m.toml", "m", out, ins, frame=f, tag_info=info, period=period,
                       sets=31, shape="trapezoidal")  # fmt: skip
        cols = [feature(f, InputSpec.parse(v.spec)) for v in rb.inputs]
        y = feature(f, InputSpec.parse(out))
        cut = cut_row(f.index, 0.2)
        inner = cut_row(f.index[:cut], 0.2)  # choices are made on the training part alone
        tcols, ty = [c[:cut] for c in cols], y[:cut]
        X = np.column_stack(cols)
        ok = np.isfinite(X).all(axis=1) & np.isfinite(y)
        tr, va = ok & (np.arange(len(y)) < cut), ok & (np.arange(len(y)) >= cut)
        span = rb.output.span[1] - rb.output.span[0]
        h = HistGradientBoostingRegressor(random_state=0).fit(X[tr], y[tr])
        e_h = float(np.sqrt(np.mean(((y[va] - h.predict(X[va])) / span * 100) ** 2)))
        print(f"{which}: {out} = f({', '.join(ins)}), {len(f):,} rows; HGB {e_h:.3f} % of span")
        narrow = [
            replace(v, span=operating_span(v.span, c[:inner]) or v.span)
            for v, c in zip(rb.inputs, cols, strict=True)
        ]
        for label, vs in (("nominal spans", list(rb.inputs)), ("operating spans", narrow)):
            probe = copy.copy(rb)
            probe.inputs = list(vs)
            pick = choose_shape(probe, tcols, ty, inner)
            chosen = pick.shape if pick is not None else "trapezoidal"
            for shape in dict.fromkeys(("trapezoidal", chosen)):
                tag = f"{shape[:4]}{'' if shape == 'trapezoidal' else ' (chosen)'}"
                probe = copy.copy(rb)
                probe.inputs, probe.shape = list(vs), shape
                sc = HeldOutScorer(probe, cols, y, cut)
                rows = [("31 sets", vs)]
                c = choose_sets(probe, tcols, ty, inner, 31)
                if c is not None:
                    rows.append((f"searched {c.sets}", [replace(v, sets=s) for v, s in
                                                        zip(vs, c.sets, strict=True)]))  # fmt: skip
                for name, v2 in rows:
                    e, _, _, fine = sc.score(v2, cols)
                    print(f"  {label}, {tag:11s} {name:26s} {e:7.3f} %  {e / e_h:5.2f}x HGB  "
                          f"fine {fine:.0%}")  # fmt: skip
                if c is None:
                    print(f"  {label}, {tag:11s} sets not searched")
            if chosen == "trapezoidal":
                print(f"  {label}, shape chosen: trapezoidal")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    pd.set_option("display.width", 120)
    sys.exit(main(sys.argv[1:]))
