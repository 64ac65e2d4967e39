"""Seed 000's Figs. 3–7 rankings (fuzzy clustering vs NARMAX, per model) over seeds and settings.

    python benchmarks/bench_engine_rankings.py [--seeds 0 1 2 3 4] [--volts] [--out r.jsonl]

The seed (§III) found NARMAX slightly better for m_a and ω, the clustering (ts-fcm) slightly
better for α, T_L and m_f. Per seed this identifies the five models of eqs. 7–11 with narmax2
and with ts-fcm under both consequent weightings (μ², eq. 24, the default; μ, eq. 23) on run
``seed`` and validates them on run ``seed + 1000`` (:func:`fdi.validation_errors`),
in free run (the regressors the seed writes) and one step ahead, and prints per model the
validation Σe² of each and whether the seed's winner wins. ``--volts`` runs everything on the
seed's sensor-voltage scale (its figures' axes). Each seed is appended to ``--out`` as a JSON
line. Not a test: about three minutes per seed on the 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from diag_plugin.engine import fdi

#: the seed's finding per model (§III): which method estimated it better
SEED_WINNER = {"m_a": "narmax2", "omega": "narmax2", "alpha": "ts", "T_L": "ts", "m_f": "ts"}
#: the identifiers compared: name -> (method, ts-fcm weight power)
IDENTIFIERS = {"narmax2": ("narmax2", 2.0), "ts-eq24": ("ts-fcm", 2.0), "ts-eq23": ("ts-fcm", 1.0)}


def one(seed: int, setup: fdi.Setup) -> dict[str, Any]:
    """Σe² and RMSE % per identifier, mode and model for one seed."""
    train = setup.simulate(fdi.N_REV, seed)
    val = setup.simulate(fdi.N_REV, seed + 1000)
    out: dict[str, Any] = {"seed": seed, "volts": setup.volts, "errors": {}}
    for name, (method, p) in IDENTIFIERS.items():
        t0 = time.perf_counter()
        em = fdi.identify(train, method, weight_power=p)
        per = {"fit_s": round(time.perf_counter() - t0, 1)}
        for mode, one_step in (("free", False), ("one-step", True)):
            em.one_step = one_step
            per[mode] = fdi.validation_errors(em, val)
        out["errors"][name] = per
    return out


def agree(r: dict[str, Any], ts: str, mode: str) -> dict[str, bool]:
    """Per model: does the seed's winner win (``ts``: which TS weighting stands for it)?"""
    e = r["errors"]
    got = {}
    for model, winner in SEED_WINNER.items():
        nar, fuz = e["narmax2"][mode][model]["sse"], e[ts][mode][model]["sse"]
        got[model] = (nar < fuz) if winner == "narmax2" else (fuz < nar)
    return got


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--volts", action="store_true", help="on the sensor-voltage scale")
    ap.add_argument("--out", type=Path, help="append each seed as a JSON line")
    args = ap.parse_args(argv)
    setup = fdi.Setup(volts=True) if args.volts else fdi.Setup()
    tally: dict[tuple[str, str], dict[str, int]] = {}
    for seed in args.seeds:
        r = one(seed, setup)
        if args.out:
            with args.out.open("a", encoding="utf-8") as fh:
                fh.write(json.dumps(r) + "\n")
        for mode in ("free", "one-step"):
            print(f"seed {seed} {mode}: Σe² narmax2 / ts eq. 24 / ts eq. 23")
            for model in SEED_WINNER:
                sse = [r["errors"][k][mode][model]["sse"] for k in IDENTIFIERS]
                print(f"  {model:6} " + " / ".join(f"{v:.4g}" for v in sse), flush=True)
            for ts in ("ts-eq24", "ts-eq23"):
                got = agree(r, ts, mode)
                t = tally.setdefault((mode, ts), {m: 0 for m in SEED_WINNER})
                for m, ok in got.items():
                    t[m] += ok
    n = len(args.seeds)
    print(f"seeds where the seed's winner wins (of {n}), per model:")
    for (mode, ts), t in tally.items():
        cells = ", ".join(f"{m} {v}" for m, v in t.items())
        print(f"  {mode:8} narmax2 vs {ts}: {cells}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
