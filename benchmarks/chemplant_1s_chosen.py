"""The chemical plant at 1 s on its **tuning** fault-free runs, with and without the
``[chosen]`` guard (issue 34, items 3 and 5; docs/how-to/unit-loops.md, "A set-point the
window saw at few values").

The unit is built as ``diag benchmark --plant chemplant --period 1`` builds it (training
seeds 1–3, a day each at 1 s, the tags' spans from the plant's table); each fault-free tuning
seed (150–154 by default, 3 days at 1 s; the bench scores 9151–9153 and 9101–9103, never read
here) is replayed by that unit and by the same unit without its ``[chosen]`` guard (the tests
reading a few-valued set-point judged as before it), and for each the share of samples in
alarm (a status other than NORMAL and CHECK_FUNCTION), the alarm episodes, the share
CHECK_FUNCTION and the tests whose symptoms are on most are printed. Minutes of CPU (the
build about 50 s; a 3-day run 1–2 min each way). Run: ``python
benchmarks/chemplant_1s_chosen.py [--seeds 150,151] [--cache DIR] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd


def _window() -> pd.DataFrame:
    """The bench's training window at 1 s: seeds 1–3, a day each, an hour between."""
    from diag_plugin.simulate.chemplant import sample, simulate_chemplant

    runs, start = [], pd.Timestamp("2026-01-01", tz="UTC")
    for s in (1, 2, 3):
        run = sample(simulate_chemplant(1.0, s, start=start), 1)
        runs.append(run)
        start = run.index[-1] + pd.Timedelta("1s") + pd.Timedelta("1h")
    grid = pd.date_range(runs[0].index[0], runs[-1].index[-1], freq="1s")
    return pd.concat(runs).reindex(grid)


def _run(seed: int, cache: Path | None) -> pd.DataFrame:
    from diag_plugin.simulate.chemplant import sample, simulate_chemplant

    f = cache / f"free{seed}_1s.parquet" if cache else None
    if f is not None and f.exists():
        return pd.read_parquet(f)
    x = sample(simulate_chemplant(3.0, seed, start=pd.Timestamp("2026-03-01", tz="UTC")), 1)
    if f is not None:
        f.parent.mkdir(parents=True, exist_ok=True)
        x.to_parquet(f)
    return x


def _score(unit, x: pd.DataFrame) -> dict:
    from diag_plugin.status import NE107

    d = unit.reset().evaluate(x)
    st = d.status.to_numpy()
    alarm = (st != NE107.NORMAL) & (st != NE107.CHECK_FUNCTION)
    on = {c: float(np.mean(np.abs(np.nan_to_num(d.symptoms[c].to_numpy())) > 0))
          for c in d.symptoms.columns}  # fmt: skip
    top = sorted(on.items(), key=lambda kv: -kv[1])[:4]
    return {
        "alarm": float(alarm.mean()),
        "episodes": int((alarm & ~np.r_[False, alarm[:-1]]).sum()),
        "check_function": float(np.mean(st == NE107.CHECK_FUNCTION)),
        "tests": {k: round(100 * v, 1) for k, v in top if v > 0},
    }


def main() -> None:
    from diag_plugin.diagnose.manual import ManualGuard
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.simulate.chemplant import CHEMPLANT_TAGS
    from diag_plugin.unitbuild.build import build_unit
    from historian.taginfo import TagInfo

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="150,151,152,153,154")
    ap.add_argument("--cache", type=Path, default=None, help="keep the simulated runs here")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()
    info = {t: TagInfo(t, unit=u, lo=lo, hi=hi, description=d)
            for t, (u, lo, hi, d, _) in CHEMPLANT_TAGS.items()}  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="chosen1s_") as tmp:
        t0 = time.perf_counter()
        res = build_unit("chemplant", _window(), folder=tmp, period="1s", tag_info=info,
                         force=True, source="benchmarks/chemplant_1s_chosen.py")  # fmt: skip
        print(f"built in {time.perf_counter() - t0:.0f} s")
        for n in res.notes:
            if "set-point(s) seen at" in n:
                print("note:", n)
        unit = Unit.load(res.path, tmp)
        plain = Unit.load(res.path, tmp)
        f = plain.file
        sps = [getattr(t, "set_point", None) for t in f.tests]
        plain.manual = ManualGuard.of(plain.models, plain.tests, f.manual, f.narrow, {}, sps)
    out = {"chosen": {k: [v.min, v.max] for k, v in unit.file.chosen.items()}, "seeds": {}}
    print("| seed | without the guard: alarm, episodes, CF | with it | tests on most (with) |")
    print("|---|---|---|---|")
    for s in (int(v) for v in a.seeds.split(",")):
        x = _run(s, a.cache)
        got = {"without": _score(plain, x), "with": _score(unit, x)}
        out["seeds"][s] = got
        w, g = got["without"], got["with"]
        print(f"| {s} | {w['alarm']:.1%}, {w['episodes']}, {w['check_function']:.1%} | "
              f"{g['alarm']:.1%}, {g['episodes']}, {g['check_function']:.1%} | "
              f"{g['tests']} |", flush=True)  # fmt: skip
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
