"""``diag engine-fdi`` (the seed's engine FDI experiment, Laukonen et al., §§III–IV) and
``diag compare-methods NAME`` (every method on one model file's historian data).

Arguments only; :mod:`diag_plugin.engine.fdi` (numpy, pandas, numba) is imported when the
command runs. ``--compare`` prints, like the seed's Figs. 3–7, the validation Σe² and RMSE %
per model and method, plus the fit time (the engine-model form of ``compare-methods``).
"""

from __future__ import annotations

import argparse
import json

from diag_plugin.cliargs import add_json

METHODS = ("ts-fcm", "narmax2", "wm-avg")


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``engine-fdi`` and ``compare-methods``."""
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
    p.add_argument(
        "--one-step",
        action="store_true",
        help="residuals one step ahead on measured data (not the seed's free run)",
    )
    p.add_argument(
        "--matrix",
        choices=("printed", "derived"),
        default="printed",
        help="Table II as printed (default) or derived from eqs. 7-11 by the seed's rule",
    )
    p.add_argument(
        "--weight-power",
        type=float,
        choices=(1.0, 2.0),
        default=2.0,
        help="ts-fcm consequents weighted by mu^P: 2 as eq. 24 solves them (default), 1 as eq. 23",
    )
    p.add_argument(
        "--omega-dy",
        action="store_true",
        help="the omega case also multiplies omega_dy: the engine speed as both instruments "
        "read it (what Fig. 12's alpha residual implies, docs/explanation/engine.md)",
    )
    p.add_argument(
        "--window",
        choices=("seed", "matching"),
        default="seed",
        help="test window: the seed's revolutions 3000-5000 (default), or the 2000 where the "
        "fault-free residuals are smallest (the seed's reason for its window)",
    )
    p.add_argument(
        "--plot", metavar="DIR", help="also write the residual plots (Figs. 8-12) as SVG to DIR"
    )
    add_json(p, "print the result as JSON")
    p.set_defaults(func=cmd_engine_fdi)
    p = sub.add_parser("compare-methods", help="train every method on a model's data (Figs. 3-7)")
    p.add_argument("name", help="model name in the rule-base folder, or a file")
    p.add_argument("--from", dest="start", help="start of the range (default: all)")
    p.add_argument("--to", dest="end", help="end of the range")
    p.add_argument("--holdout", type=float, default=0.2, help="held-out share (last part)")
    add_json(p, "print the result as JSON")
    p.set_defaults(func=cmd_compare_methods)


def cmd_compare_methods(args: argparse.Namespace) -> int:
    """Validation Σe², RMSE % and fit time per registered method (seed 000 Figs. 3–7)."""
    from diag_plugin.engine.method_compare import compare_methods
    from diag_plugin.rulebase.document import resolve

    rows = compare_methods(
        resolve(args.name, args.rulebases),
        args.db,
        start=args.start,
        end=args.end,
        holdout=args.holdout,
    )
    if args.json:
        print(json.dumps({"model": args.name, "methods": rows}, indent=2))
        return 0
    print(f"{'method':8} {'SSE':>12} {'RMSE %':>8} {'coverage':>9} {'fit s':>7}")
    for r in rows:
        print(
            f"{r['method']:8} {r['sse']:12.4g} {r['rmse_pct']:8.2f} "
            f"{r['coverage']:9.1%} {r['fit_s']:7.2f}"
        )
    return 0


def cmd_engine_fdi(args: argparse.Namespace) -> int:
    """Run the experiment (or ``--compare``) and print per case injected / isolated / time."""
    from diag_plugin.engine import fdi

    if args.compare:
        res = fdi.compare_methods(args.seed, weight_power=args.weight_power, one_step=args.one_step)
        if args.json:
            doc = {"seed": args.seed, "one_step": args.one_step, "methods": res}
            print(json.dumps({**doc, "weight_power": args.weight_power}, indent=2))
            return 0
        print(f"{'method':8} {'model':6} {'SSE':>14} {'RMSE %':>8} {'fit s':>7}")
        for method, per_model in res.items():
            for model, v in per_model.items():
                print(
                    f"{method:8} {model:6} {v['sse']:14.4g} {v['rmse_pct']:8.2f} {v['fit_s']:7.2f}"
                )
        return 0
    res = fdi.run_fdi(
        args.seed,
        args.method,
        kind=args.faults,
        keep_residuals=bool(args.plot),
        one_step=args.one_step,
        matrix=args.matrix,
        weight_power=args.weight_power,
        setup=fdi.Setup(
            omega_signals=("omega", "omega_dy") if args.omega_dy else ("omega",),
            window=args.window,
        ),
    )
    plots = fdi.plot_residuals(res, args.plot) if args.plot else []
    if args.json:
        doc = {
            "cases": [
                {k: c[k] for k in ("injected", "isolated", "time_s", "isolated_by")}
                for c in res["cases"]
            ],
            "method": res["method"],
            "seed": res["seed"],
            "detail": {
                k: res[k]
                for k in (
                    "fault_kind",
                    "residual_mode",
                    "matrix",
                    "window",
                    "thresholds",
                    "weight_power",
                )
            },
            "plots": [str(p) for p in plots],
        }
        print(json.dumps(doc, indent=2))
        return 0
    print(
        f"method {res['method']}, seed {res['seed']}, residuals {res['residual_mode']}, "
        f"Table II {res['matrix']}, window {res['window'][0]}-{res['window'][1]}"
    )
    other = next(m for m in fdi.MATRICES if m != res["matrix"])
    print(f"{'injected':9} {'isolated':19} {'time s':>7}  Table II {other}")
    for c in res["cases"]:
        t = "-" if c["time_s"] is None else f"{c['time_s']:.1f}"
        # a signature that matches no Table II row exactly isolates only when one row is
        # nearer than all others (fdi.isolate); say so beside the name
        got = _named(c["isolated"], c["exact"])
        alt = c["isolated_by"][other]
        print(f"{c['injected']:9} {got:19} {t:>7}  {_named(alt['isolated'], alt['exact'])}")
    for p in plots:
        print(f"plot: {p}")
    return 0


def _named(fault: str, exact: bool) -> str:
    """The isolated fault, marked "(nearest)" when no Table II row matched exactly."""
    nearest = fault not in (None, "none", "unknown") and not exact
    return f"{fault} (nearest)" if nearest else fault
