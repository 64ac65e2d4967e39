"""Every output of a unit's replay, written to one file, to compare two versions of the code
bit for bit (issue 34, replay speed: a faster replay must give exactly what ``main`` gives).

The unit (``--unit``, e.g. the one ``bench_unit_replay.py`` builds, kept) replays the
synthetic coupled process (:mod:`diag_plugin.simulate.coupled`, seed 7, the bench's rows) and
a faulty copy of it (a bias, a drift, a stuck value and gaps on some of its tags, so the
alarm, isolation, naming and CHECK_FUNCTION paths run), each in one pass and in 7-day pieces
(``diag diagnose``'s reading). Written per run and reading: residuals, symptoms, certainties,
detected, status, quality, faults, T² and its symptom, the named tags and their shares, the
reasons (``why``), every tag's share of T² and the carried state (JSON) — as arrays in an
``.npz`` without pickles (strings as unicode arrays).

Run each version on the same unit, then compare (exit status 1 and the first differences when
any output differs, in value or in bits)::

    PYTHONPATH=/path/to/main python benchmarks/replay_digest.py --unit U --out main.npz
    python benchmarks/replay_digest.py --unit U --out branch.npz
    python benchmarks/replay_digest.py --compare main.npz branch.npz
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np
import pandas as pd


def faulty(frame: pd.DataFrame, seed: int = 3) -> pd.DataFrame:
    """A copy of ``frame`` with faults on a few varying tags: a bias, a drift, a value stuck
    at its last reading, and gaps (NaN) — each over a stretch of its own."""
    out = frame.copy()
    rng = np.random.default_rng(seed)
    tags = [c for c in out.columns if out[c].std() > 0]
    n = len(out)
    pick = rng.choice(len(tags), size=4, replace=False)
    bias, drift, stuck, gap = (tags[i] for i in pick)
    for k, tag in enumerate((bias, drift, stuck, gap)):
        a = int(n * (0.1 + 0.2 * k))
        b = min(n, a + n // 10)
        x = out[tag].to_numpy(float, copy=True)
        sd = float(np.nanstd(x))
        if tag == bias:
            x[a:b] += 4 * sd
        elif tag == drift:
            x[a:b] += np.linspace(0, 6 * sd, b - a)
        elif tag == stuck:
            x[a:b] = x[a]
        else:
            x[a:b:7] = np.nan
            x[a + n // 50 : a + n // 50 + 300] = np.nan
        out[tag] = x
    return out


def arrays(d, prefix: str) -> dict[str, np.ndarray]:
    """Every output of one diagnosis as named arrays (strings as unicode)."""
    out: dict[str, np.ndarray] = {f"{prefix}index": d.status.index.asi8}
    frames = {
        "residuals": d.residuals,
        "symptoms": d.symptoms,
        "certainties": d.certainties,
        "combined": d.combined,
        "top": d.top,
        "contributions": d.contributions,
    }
    series = {
        "detected": d.detected,
        "status": d.status,
        "quality": d.quality,
        "faults": d.faults,
        "why": d.why,
    }
    for name, f in frames.items():
        if f is None:
            continue
        out[f"{prefix}{name}.columns"] = np.array([str(c) for c in f.columns], dtype=str)
        for c in f.columns:
            out[f"{prefix}{name}.{c}"] = _plain(f[c])
    for name, s in series.items():
        if s is not None:
            out[f"{prefix}{name}"] = _plain(s)
    out[f"{prefix}message"] = np.array([d.message], dtype=str)
    return out


def _plain(s: pd.Series) -> np.ndarray:
    v = s.to_numpy()
    if v.dtype == object or pd.api.types.is_string_dtype(s.dtype):
        return np.array([str(x) for x in v], dtype=str)
    return v


def digest(unit_path: str, rows: int, period: float, tags: int) -> dict[str, np.ndarray]:
    from diag_plugin.diagnose.unit import Unit, concat
    from diag_plugin.simulate import coupled

    unit = Unit.load(unit_path)
    days = rows * period / 86400
    frame, _ = coupled.simulate(days, period_s=period, n_tags=tags, seed=7, start="2026-06-01")
    frame = frame.iloc[:rows]
    chunk = pd.Timedelta("7D") // pd.Timedelta(f"{period:g}s")
    out: dict[str, np.ndarray] = {}
    for run, data in (("clean", frame), ("faulty", faulty(frame))):
        one = unit.reset().evaluate(data)
        out.update(arrays(one, f"{run}/one/"))
        out[f"{run}/one/state"] = np.array([json.dumps(unit.to_state(), sort_keys=True)])
        unit.reset()
        parts = [unit.evaluate(data.iloc[s : s + chunk]) for s in range(0, len(data), chunk)]
        out.update(arrays(concat(parts), f"{run}/chunks/"))
        out[f"{run}/chunks/state"] = np.array([json.dumps(unit.to_state(), sort_keys=True)])
    return out


def compare(a_path: str, b_path: str) -> int:
    a, b = np.load(a_path, allow_pickle=False), np.load(b_path, allow_pickle=False)
    bad = []
    for k in sorted(set(a.files) | set(b.files)):
        if k not in a.files or k not in b.files:
            bad.append(f"{k}: only in {'b' if k not in a.files else 'a'}")
            continue
        x, y = a[k], b[k]
        if x.dtype != y.dtype or x.shape != y.shape:
            bad.append(f"{k}: {x.dtype}{x.shape} vs {y.dtype}{y.shape}")
        elif x.dtype.kind in "fc":
            if x.tobytes() != y.tobytes():  # bit for bit (NaN payloads and -0.0 too)
                nan = np.flatnonzero(np.isnan(x) != np.isnan(y))
                ne = np.flatnonzero(~((x == y) | (np.isnan(x) & np.isnan(y))))
                bad.append(f"{k}: {ne.size} values differ (first rows {ne[:5].tolist()}), "
                           f"{nan.size} in NaN-ness, or in their bits")  # fmt: skip
        elif not np.array_equal(x, y):
            ne = np.flatnonzero(x != y) if x.ndim else [0]
            bad.append(f"{k}: {len(ne)} values differ (first rows {list(ne[:5])})")
    n = len(a.files)
    if bad:
        print(f"{len(bad)} of {n} outputs differ:")
        print("\n".join(bad[:40]))
        return 1
    print(f"identical: {n} outputs (one pass and 7-day pieces, clean and faulty runs)")
    return 0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--unit", help="the unit file to replay")
    ap.add_argument("--out", help="the .npz to write")
    ap.add_argument("--rows", type=int, default=200_000)
    ap.add_argument("--period", type=float, default=180.0)
    ap.add_argument("--tags", type=int, default=50)
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"))
    a = ap.parse_args()
    if a.compare:
        sys.exit(compare(*a.compare))
    if not a.unit or not a.out:
        ap.error("--unit and --out (or --compare A B)")
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):  # as diag diagnose runs it
        out = digest(a.unit, a.rows, a.period, a.tags)
    np.savez(a.out, **out)
    print(f"{len(out)} outputs written to {a.out}")


if __name__ == "__main__":
    main()
