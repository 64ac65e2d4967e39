"""``diag engine-fdi``: the seed's engine FDI experiment (Laukonen et al., §§III–IV).

Arguments only; :mod:`diag_plugin.engine_fdi` (numpy, pandas, numba) is imported when the
command runs. ``--compare`` prints, like the seed's Figs. 3–7, the validation Σe² and RMSE %
per model and method, plus the fit time (the engine-model form of ``compare-methods``).
"""

from __future__ import annotations

import argparse
import json

METHODS = ("ts-fcm", "narmax2", "wm-avg")


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``engine-fdi``."""
    p = sub.add_parser("engine-fdi", help="the seed's engine FDI experiment (Table II)")
    p.add_argument("--seed", type=int, default=0, help="simulator seed of the training run")
    p.add_argument("--method", choices=METHODS, default="ts-fcm")
    p.add_argument(
        "--faults",
        choices=("recorded", "physical"),
        default="recorded",
        help="multiply the recorded data (the seed's way, default) or fault the engine",
    )
    p.add_argument(
        "--compare",
        action="store_true",
        help="instead: validation errors per model and method (Figs. 3-7)",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=cmd_engine_fdi)


def cmd_engine_fdi(args: argparse.Namespace) -> int:
    """Run the experiment (or ``--compare``) and print per case injected / isolated / time."""
    from diag_plugin import engine_fdi

    if args.compare:
        res = engine_fdi.compare_methods(args.seed)
        if args.json:
            print(json.dumps({"seed": args.seed, "methods": res}, indent=2))
            return 0
        print(f"{'method':8} {'model':6} {'SSE':>14} {'RMSE %':>8} {'fit s':>7}")
        for method, per_model in res.items():
            for model, v in per_model.items():
                print(
                    f"{method:8} {model:6} {v['sse']:14.4g} {v['rmse_pct']:8.2f} {v['fit_s']:7.2f}"
                )
        return 0
    res = engine_fdi.run_fdi(args.seed, args.method, kind=args.faults)
    if args.json:
        doc = {
            "cases": [{k: c[k] for k in ("injected", "isolated", "time_s")} for c in res["cases"]],
            "method": res["method"],
            "seed": res["seed"],
            "detail": {k: res[k] for k in ("fault_kind", "residual_mode", "thresholds")},
        }
        print(json.dumps(doc, indent=2))
        return 0
    print(f"method {res['method']}, seed {res['seed']}, residuals {res['residual_mode']}")
    print(f"{'injected':9} {'isolated':9} {'time s':>7}")
    for c in res["cases"]:
        t = "-" if c["time_s"] is None else f"{c['time_s']:.1f}"
        mark = "" if c["exact"] else " (nearest)"
        print(f"{c['injected']:9} {c['isolated']:9} {t:>7}{mark}")
    return 0
