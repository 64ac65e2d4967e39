"""An offline estimate, not a change (docs/how-to/unit-loops.md, "The settles at 1 s, off the
grid"): a settle that holds only the tests the build window's settles put on, closed as soon
as another test goes on (from there the unit's status without the guard). On a folder of
:mod:`benchmarks.settle_offgrid` (the cascade) after :mod:`benchmarks.settle_cost` ran on it:
the tests on while settling in the build window, then per cost run the first raised sample
after the onset, the raised share of the hour after it and of the hour before the onset, and
the fault-free day's raised share.

Run: ``python -m benchmarks.settle_moved_tests FOLDER``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks.settle_cost import OFFSETS, STEP_S
from benchmarks.settle_offgrid import diag

#: the cascade's build window (settle_offgrid: 2 days from 2026-03-02)
BUILD = ("2026-03-02T00:00:00Z", "2026-03-04T00:00:00Z")


def _settling(d: pd.DataFrame) -> np.ndarray:
    why = d["why"].fillna("").astype(str)
    return ((d["status"] == 2) & why.str.contains("settling")).to_numpy()


def emulate(guard: Path, none: Path, foreign_tests: list[str]) -> tuple[pd.DataFrame, np.ndarray]:
    """The statuses of ``guard``'s diagnosis with each settle closed at the first sample a
    test of ``foreign_tests`` is on (from there ``none``'s, the unit without its guard)."""
    d, n = pd.read_csv(guard, low_memory=False), pd.read_csv(none, low_memory=False)
    st, st0 = d["status"].to_numpy().copy(), n["status"].to_numpy()
    sett = _settling(d)
    foreign = (d[foreign_tests].fillna(0).to_numpy() != 0).any(axis=1)
    i = 0
    while i < len(st):
        if not sett[i]:
            i += 1
            continue
        j = i
        while j < len(st) and sett[j]:
            j += 1
        f = np.flatnonzero(foreign[i:j])
        if f.size:
            st[i + f[0] : j] = st0[i + f[0] : j]
        i = j
    return d, st


def main() -> None:
    folder = Path(sys.argv[1])
    meta = json.loads((folder / "meta.json").read_text())
    g = ["--db", f"sqlite:///{folder / 'h.db'}", "--rulebases", str(folder / "rb")]
    g0 = ["--db", g[1], "--rulebases", str(folder / "rb0")]
    csv = folder / "buildwin.csv"
    rc, text, _ = diag(g, "diagnose", "u", "--from", BUILD[0], "--to", BUILD[1], "--csv", str(csv))
    assert rc == 0, text
    b = pd.read_csv(csv, low_memory=False)
    tests = [c for c in b.columns if c.startswith("s_")]
    moved = [c for c in tests if (b.loc[_settling(b), c].fillna(0) != 0).any()]
    foreign = [c for c in tests if c not in moved]
    print("on while settling in the build window:", moved, "others:", foreign)
    for k, off in enumerate((None, *OFFSETS)):
        d, st = emulate(folder / f"cost{k}_guard.csv", folder / f"cost{k}_none.csv", foreign)
        ts = pd.to_datetime(d["ts"], utc=True)
        s = (ts - ts.iloc[0]).dt.total_seconds().to_numpy()
        onset = STEP_S + (120 if off is None else off)
        raised = (st != 0) & (st != 2)
        first = np.flatnonzero(raised & (s >= onset))
        after = raised[(s >= onset) & (s < onset + 3600)].mean()
        before = raised[(s >= STEP_S - 3600) & (s < onset)].mean()
        print(json.dumps({"offset_s": off, "first_s": float(s[first[0]] - onset) if first.size
                          else None, "raised_1h_pct": round(100 * float(after), 1),
                          "raised_before_pct": round(100 * float(before), 1)}))  # fmt: skip
    a, b_ = meta["spans"]["free"]
    none = folder / "free.none.csv"
    rc, text, _ = diag(g0, "diagnose", "u", "--from", a, "--to", b_, "--csv", str(none))
    assert rc == 0, text
    _, st = emulate(folder / "free.rb.csv", none, foreign)
    raised = (st != 0) & (st != 2)
    episodes = int((raised & ~np.r_[False, raised[:-1]]).sum())
    print(f"fault-free raised {100 * raised.mean():.2f} %, episodes {episodes}")


if __name__ == "__main__":
    main()
