"""How long each method's alarm outlasts a SKAB anomaly, on the **tuning** runs only (issue 34:
SKAB's own FAR counts the recovery after the anomaly, where the unit's is the highest).

Every run is built and scored as ``diag benchmark --plant skab`` does it (the unit from the
run's first 400 samples, scored by :func:`~diag_plugin.bench.publicbench.unit_score`'s parts:
each test's statistic and the combined T² after the unit's on/off delays, with the
oscillation hold's columns; PCA and DPCA with two lags, T² + Q, the same delays); each
method's limit matched at each target on the bench's calibration runs (the anomaly-free
chunks and the tuning runs' samples before their anomaly). The scoring runs are not read.

Per tuning run and target: the samples after the labelled anomaly's last sample (the
recovery) and, per method, those in alarm; for the unit what carries it there: per
statistic (test, ``T2``, ``hold:TEST``) the recovery samples it is over the limit after the
delays, and how many of them it is over the limit *before* the delays (``raw``: the statistic
itself still high; the rest is the off-delay's hold of an alarm that ended earlier); and per
method the last sample whose undelayed score is over the limit, counted from the anomaly's end
(negative: the statistic fell under the limit that many samples before the labelled end).

Per target also each method's mean detection (fault samples in alarm), its alarms before the
anomaly and SKAB's F1 and FAR on the tuning runs. ``--clear C`` is a what-if for every method
alike (:func:`released`, not the bench's rule): an alarm at limit ``λ`` also ends once its
statistic has stayed under ``C × λ`` for the on-delay's samples.

``--save FILE`` keeps every run's statistics, ``--load FILE`` reuses them. Run:
``python benchmarks/skab_recovery.py`` (SKAB's mirror or ``$DIAG_SKAB_DIR``; 21 per-run
builds, CPU time printed).
"""

from __future__ import annotations

import argparse

import numpy as np


def build_run(run, folder, cols: list[str]) -> dict[str, np.ndarray]:
    """One SKAB run as the bench builds and scores it: the unit's statistics (``unit``, with
    ``unit_names``) and its oscillation hold's delayed columns (``held``, NaN without a hold),
    PCA's and DPCA's statistics (``PCA``, ``DPCA``), and the unit's delays (``delays``)."""
    from skab_matched_tuning import baselines, build_on_grid

    from diag_plugin.bench.publicbench import _unit_parts

    _, unit, grid = build_on_grid(run, folder)
    on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
    stats, _, held = _unit_parts(unit, grid, on, off)
    names = list(unit.tests) + (["T2"] if stats.shape[1] > len(unit.tests) else [])
    out = {
        "unit": stats,
        "unit_names": np.array(names),
        "held": np.full((len(grid), 0), np.nan) if held is None else held,
        "delays": np.array([on, off]),
    }
    return out | baselines(run, cols)


def released(x: np.ndarray, on: int, off: int, clear: float) -> np.ndarray:
    """Per column the statistic after the on/off delays with a second way off (a what-if,
    not the bench's rule): an alarm at ``λ`` also ends once the statistic has stayed under
    ``clear × λ`` for ``on`` samples (back at its normal level, not hovering at the limit);
    ``d > λ`` exactly where that alarm is on. ``clear`` 0: :func:`~diag_plugin.bench.
    matched.delayed_score`."""
    a = np.where(np.isnan(x), -np.inf, np.asarray(x, float))
    a = a.reshape(len(a), -1)
    n, m = a.shape
    out = np.empty_like(a)
    for j in range(m):
        v = a[:, j]
        prev = -np.inf
        for t in range(n):
            w_on = v[max(0, t - on + 1) : t + 1]
            lo = w_on.min() if t + 1 >= on else -np.inf
            hi = v[max(0, t - off + 1) : t + 1].max()
            q = w_on.max() / clear if clear > 0 else np.inf
            prev = max(lo, min(prev, hi, q))
            out[t, j] = prev
    out[np.isneginf(out)] = np.nan
    return out


def _max_known(d: np.ndarray) -> np.ndarray:
    with np.errstate(all="ignore"):
        known = (~np.isnan(d)).any(axis=1)
        out = np.full(len(d), np.nan)
        out[known] = np.nanmax(d[known], axis=1)
    return out


def scores(raw: dict, name: str, on: int, off: int, clear: float = 0.0) -> dict[str, np.ndarray]:
    """A run's score per method as the bench takes it (the whole run); ``clear`` > 0: each
    statistic through :func:`released` instead (the oscillation hold's columns as they are)."""
    from diag_plugin.bench.matched import method_score

    held = raw[f"{name}|held"]
    if clear <= 0:
        out = {"unit": method_score(raw[f"{name}|unit"], on, off, held if held.size else None)}
        for m in ("PCA", "DPCA"):
            out[m] = method_score(raw[f"{name}|{m}"], on, off)
        return out
    out = {"unit": _max_known(np.c_[released(raw[f"{name}|unit"], on, off, clear), held])}
    for m in ("PCA", "DPCA"):
        out[m] = _max_known(released(raw[f"{name}|{m}"], on, off, clear))
    return out


def undelayed(raw: dict, name: str, method: str) -> np.ndarray:
    """A run's score per method before the delays (the maximum of its statistics)."""
    x = np.asarray(raw[f"{name}|{method}"], float).reshape(len(raw[f"{name}|{method}"]), -1)
    with np.errstate(all="ignore"):
        x = np.where(np.isnan(x), -np.inf, x).max(axis=1)
    return x


def main(argv: list[str] | None = None) -> int:
    from _common import scratch

    from diag_plugin.bench.matched import Scored, calibrate, delayed_score
    from diag_plugin.bench.publicbench import before_onset, fault_free_mask, skab_metrics
    from diag_plugin.bench.publicplants import load_skab

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", default="0.001,0.01,0.05,0.1,0.25", help="shares of samples")
    ap.add_argument("--save", default=None, help="keep the runs' statistics in this .npz")
    ap.add_argument("--load", default=None, help="statistics saved by --save (same code)")
    ap.add_argument("--dir", default=None, help="scratch folder (default: system temp)")
    ap.add_argument("--carriers", type=int, default=3, help="the unit's carriers shown per run")
    ap.add_argument(
        "--clear",
        type=float,
        default=0.0,
        metavar="C",
        help="what-if for every method alike: an alarm also ends after the on-delay's samples "
        "under C times its limit (released); 0: the bench's delays",
    )
    args = ap.parse_args(argv)
    targets = [float(t) for t in args.targets.split(",")]
    from skab_matched_tuning import cpu_seconds

    plant = load_skab()
    cols = list(plant.tags)
    raw: dict[str, np.ndarray] = dict(np.load(args.load)) if args.load else {}
    cpu = cpu_seconds()
    with scratch("skab_recovery_", args.dir) as work:
        for k, run in enumerate(plant.calibration):  # the tuning runs are among them
            if f"{run.name}|unit" in raw:
                continue
            one = build_run(run, work / f"run{k}", cols)
            raw["delays"] = one.pop("delays")
            raw.update({f"{run.name}|{key}": v for key, v in one.items()})
            print(f"{run.name}: built and scored ({len(one['unit_names'])} statistics)",
                  flush=True)  # fmt: skip
    cpu = cpu_seconds() - cpu
    if args.save:
        np.savez_compressed(args.save, **raw)
    on, off = (int(v) for v in raw["delays"])
    methods = ("unit", "PCA", "DPCA")
    sc = {r.name: scores(raw, r.name, on, off, args.clear) for r in plant.calibration}
    print(f"\nSKAB tuning runs ({len(plant.tuning)}): the recovery after each anomaly; "
          f"delays {on}/{off}; CPU {cpu:.0f} s")  # fmt: skip
    for target in targets:
        lims = {}
        for m in methods:
            xs = [before_onset(sc[r.name][m][r.learn :], r.labels[r.learn :])
                  if r.labels is not None else sc[r.name][m][r.learn :]
                  for r in plant.calibration]  # fmt: skip
            lims[m] = calibrate(xs, target, 1.0).limit
        print(f"\ntarget {target:g}: limits " + ", ".join(f"{m} {v:.3g}" for m, v in lims.items()))
        print(
            "run | fault | recovery | in alarm (of them the score under the limit before the "
            "delays: the off-delay's hold): unit / PCA / DPCA | raw over the limit until "
            "(samples from the end): unit / PCA / DPCA | the unit's carriers (recovery "
            "samples over the limit, of them raw)"
        )
        tot = {m: 0 for m in methods}
        held_tot = {m: 0 for m in methods}
        n_rec = 0
        for run in plant.tuning:
            lab = run.labels
            end = int(np.flatnonzero(lab > 0)[-1])
            rec = np.arange(end + 1, len(lab))
            rec = rec[lab[rec] == 0]
            n_rec += rec.size
            cells, last = [], []
            for m in methods:
                s = np.nan_to_num(sc[run.name][m], nan=-np.inf)
                u = undelayed(raw, run.name, m)
                a = s[rec] > lims[m]
                n, h = int(a.sum()), int((a & ~(u[rec] > lims[m])).sum())
                tot[m] += n
                held_tot[m] += h
                cells.append(f"{n} ({h})")
                over = np.flatnonzero(u[run.learn :] > lims[m]) + run.learn
                last.append(str(int(over[-1]) - end) if over.size else "—")
            # the unit's carriers: per statistic its recovery samples over the limit after the
            # delays, and of them those over it before the delays
            x = np.asarray(raw[f"{run.name}|unit"], float)
            d = delayed_score(x, on, off)
            names = [str(v) for v in raw[f"{run.name}|unit_names"]]
            held = raw[f"{run.name}|held"]
            carry = []
            for j, nm in enumerate(names):
                a = np.nan_to_num(d[rec, j], nan=-np.inf) > lims["unit"]
                if a.any():
                    r_ = np.nan_to_num(x[rec, j], nan=-np.inf) > lims["unit"]
                    carry.append((int(a.sum()), int((a & r_).sum()), nm))
            for j in range(held.shape[1]):
                a = np.nan_to_num(held[rec, j], nan=-np.inf) > lims["unit"]
                if a.any():
                    carry.append((int(a.sum()), -1, f"hold:{names[j]}"))
            carry.sort(reverse=True)
            shown = "; ".join(
                f"{nm} {a}" + ("" if r_ < 0 else f" ({r_} raw)")
                for a, r_, nm in carry[: args.carriers]
            )
            print(f"{run.name} | {run.fault} | {rec.size} | " + " / ".join(cells) + " | "
                  + " / ".join(last) + f" | {shown or '—'}")  # fmt: skip
        summary = []
        for m in methods:
            det, pre, pre_n = [], 0, 0
            for run in plant.tuning:
                x = np.nan_to_num(sc[run.name][m][run.learn :], nan=-np.inf) > lims[m]
                lab = run.labels[run.learn :]
                det.append(x[lab > 0].mean())
                b = fault_free_mask(lab)
                pre += int(x[b].sum())
                pre_n += int(b.sum())
            sk = skab_metrics([Scored(sc[r.name][m][r.learn :]) for r in plant.tuning],
                              [r.labels[r.learn :] for r in plant.tuning], lims[m])  # fmt: skip
            summary.append(f"{m} {np.mean(det):.0%} / {pre / pre_n:.2%} / {sk['F1']:.2f} / "
                           f"{sk['FAR']:.1%}")  # fmt: skip
        print("detection / alarms before the anomaly / SKAB F1 / SKAB FAR: " + "; ".join(summary))
        print(f"all | | {n_rec} | "
              + " / ".join(f"{tot[m]} ({held_tot[m]}; {tot[m] / max(n_rec, 1):.0%})"
                           for m in methods))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
