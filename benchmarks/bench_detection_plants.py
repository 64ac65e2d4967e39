"""Detection on two plants unlike the valve, beside PCA T² + Q at the same false-alarm budget.

Issue 24's "how to show it": for the laboratory tank rig (1 s, runs of a few hundred samples)
and the 3-input heat exchanger (60 s, weeks) of :mod:`diag_plugin.examples.rigs`:

1. the unit's models are trained on a fault-free window and its thresholds learned on the same
   window (cross-fitted, held to the budget ``far`` per hour of operation);
2. PCA T² + Q (dynamic, one lag) is fitted on the same window and its two limits are held to
   the same budget the same way: each statistic cross-fitted over the same time blocks, each
   side of the budget calibrated with the same on/off delays (:mod:`diag_plugin.learn.budget`);
3. both run on fault-free runs of seeds never used for anything else (false alarms per hour
   against the budget, and the unit's CHECK_FUNCTION share) and on faulty runs of other seeds
   (detected or not by the end of the run, and the delay of the first alarm after the onset);
4. the models' coverage of the fault-free runs with the fine rule grid alone and with the
   coarser levels behind it.

Run: ``python benchmarks/bench_detection_plants.py [--quick]`` (prints a markdown table).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from diag_plugin.bench.pca import PCADetector
from diag_plugin.diagnose.symptoms import OnOffDelay
from diag_plugin.diagnose.unit import Unit
from diag_plugin.diagnose.unitfile import UnitFile
from diag_plugin.examples.rigs import PERIODS, RigFault, build_unit, runs
from diag_plugin.learn.budget import calibrate_side
from diag_plugin.learn.thresholds import block_of, learn_thresholds
from diag_plugin.regressors import build_design
from diag_plugin.rulebase.document import RuleBase
from diag_plugin.status import NE107

PLANTS = {
    "tank": dict(
        train=range(1, 11), length=500, far=0.2, fault_free=range(1000, 1060), run=600,
        onset=200.0, fault_seeds=range(2000, 2010),
        faults=[("pump", 0.15), ("leak", 0.2), ("clog", 0.3), ("h2_bias", 2.0), ("q_bias", 8.0)],
    ),
    "hx": dict(
        train=(1,), length=60, far=0.002, fault_free=range(100, 110), run=7,
        onset=86400.0, fault_seeds=range(200, 205),
        faults=[("fouling", 0.25), ("tho_bias", 1.5), ("fc_bias", 0.1), ("bypass", 0.2)],
        run_faulty=3,
    ),
}  # fmt: skip
#: the rig again, trained and learned on three runs only: what a window too short for its
#: budget gives (unit learn says so)
PLANTS["tank3"] = {**PLANTS["tank"], "train": (1, 2, 3)}


def unit_alarms(unit: Unit, frame: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Per sample: the unit in alarm (FAILURE/OFF_SPEC/…, not CHECK_FUNCTION) and unknown."""
    d = unit.reset().evaluate(frame)
    st = d.status.to_numpy()
    alarm = (st != NE107.NORMAL) & (st != NE107.CHECK_FUNCTION)
    return alarm, st == NE107.CHECK_FUNCTION


def pca_fit(train: pd.DataFrame, period: str, far: float, on: int, off: int, blocks: int = 5):
    """PCA fitted on ``train``, its T² and Q limits held to ``far`` per hour together (each half
    of it), calibrated on cross-fitted statistics (each block scored by a PCA without it)."""
    cols = list(train.columns)
    block = block_of(train.index, blocks, train.notna().all(axis=1).to_numpy())
    stats = []
    for b in range(blocks):
        part = PCADetector(lags=1, columns=cols).fit(train[block != b])
        stats.append(part.score(train[block == b]))
    s = pd.concat(stats)
    hours = len(s) * pd.Timedelta(period) / pd.Timedelta("1h")
    t2 = calibrate_side(s["T2"].to_numpy(), hours, far / 2, on, off)
    q = calibrate_side(s["Q"].to_numpy(), hours, far / 2, on, off)
    return PCADetector(lags=1, columns=cols).fit(train).set_limits(t2.threshold, q.threshold)


def pca_alarms(pca: PCADetector, frame: pd.DataFrame, on: int, off: int) -> np.ndarray:
    raw = pca.decide(frame).to_numpy()[:, None]
    return np.nan_to_num(OnOffDelay(on, off).transform(raw)[:, 0]) > 0


def episodes_per_hour(alarm: np.ndarray, data: np.ndarray, period: str) -> float:
    """Alarm onsets per hour of operation (samples with data)."""
    starts = int(alarm[0]) + int(np.count_nonzero(alarm[1:] & ~alarm[:-1]))
    return starts / (int(data.sum()) * pd.Timedelta(period) / pd.Timedelta("1h"))


def coverage(frame: pd.DataFrame, unit: Unit) -> dict[str, tuple]:
    """Per test: share of the fault-free runs answered by the fine grid alone and with levels,
    and the same inside the training data's range."""
    out = {}
    for name, m in unit.models.items():
        rb = RuleBase.load(m.path)
        d = build_design(frame, m.inputs, m.output)
        lv = m.model.predict_detail(d.X)
        fine = np.isfinite(lv.y) & (lv.level == 0)
        inner = rb.to_model().inference_grid().inner
        cells = np.column_stack([p.nearest(d.X[:, k]) for k, p in enumerate(m.model.partitions_)])
        inside = ((cells >= inner[:, 0]) & (cells <= inner[:, 1])).all(axis=1)
        out[name] = (fine.mean(), np.isfinite(lv.y).mean(), fine[inside].mean(),
                     np.isfinite(lv.y)[inside].mean())  # fmt: skip
    return out


def run_plant(name: str, cfg: dict, quick: bool) -> list[str]:
    plant = name.rstrip("0123456789")
    period = PERIODS[plant]
    step = pd.Timedelta(period)
    t0 = time.perf_counter()
    train = runs(plant, cfg["train"], length=cfg["length"])
    clean = train.dropna()
    folder = Path(tempfile.mkdtemp(prefix=f"bench24_{plant}_"))
    path = build_unit(folder, plant, train)
    unit = Unit.load(path)
    got = learn_thresholds(unit, [train], far=cfg["far"])
    uf = UnitFile.load(path)
    uf.set_learned(got)
    uf.save()
    unit = Unit.load(path)
    on, off = unit.ev["on_delay"], unit.ev["off_delay"]
    pca = pca_fit(train, period, cfg["far"], on, off)
    ff_seeds = list(cfg["fault_free"])[: (10 if quick else None)]
    ff = runs(plant, ff_seeds, length=cfg["run"])
    data = ff.notna().all(axis=1).to_numpy()
    ours, unknown = unit_alarms(unit, ff)
    theirs = pca_alarms(pca, ff, on, off)
    hours = data.sum() * step / pd.Timedelta("1h")
    cov = coverage(ff, unit)
    lines = [
        f"### {name}: trained and learned on {len(clean):,} samples "
        f"({len(clean) * step / pd.Timedelta('1h'):.2g} h), budget {cfg['far']:g} per hour",
        "",
        f"fault-free runs of {len(ff_seeds)} unseen seeds, {hours:,.1f} h: false alarms per "
        f"hour unit {episodes_per_hour(ours, data, period):.3g}, PCA "
        f"{episodes_per_hour(theirs, data, period):.3g} (budget {cfg['far']:g}); unit "
        f"CHECK_FUNCTION {unknown[data].mean():.2%}; budget method "
        + ", ".join(
            f"{k} {b.method}" + ("" if b.supported else " (extrapolated)")
            for k, b in got.budgets.items()
        ),  # fmt: skip
        "",
        "| test | fine grid answers | with levels | inside training range: fine | with levels |",
        "|---|---|---|---|---|",
    ]
    for k, (a, b, c, d) in cov.items():
        lines.append(f"| {k} | {a:.1%} | {b:.1%} | {c:.1%} | {d:.1%} |")
    if plant == "hx":  # the goal: 3 inputs, 31 sets on every input
        fine31 = Unit.load(build_unit(folder / "s31", plant, train, sets=31))
        for k, (a, b, c, d) in coverage(ff, fine31).items():
            lines.append(f"| {k}, 31 sets | {a:.1%} | {b:.1%} | {c:.1%} | {d:.1%} |")
    lines += ["", "| fault | strength | unit detected | unit delay s (median) | PCA detected | "
              "PCA delay s (median) |", "|---|---|---|---|---|---|"]  # fmt: skip
    seeds = list(cfg["fault_seeds"])[: (3 if quick else None)]
    onset = cfg["onset"]
    for kind, strength in cfg["faults"]:
        res = {"unit": [], "pca": []}
        for s in seeds:
            length = cfg["run"] if plant == "tank" else cfg.get("run_faulty", cfg["run"])
            f = runs(plant, [s], faults=[RigFault(kind, strength, onset)], length=length)
            at = int(onset / step.total_seconds())
            a_u, _ = unit_alarms(unit, f)
            a_p = pca_alarms(pca, f, on, off)
            for key, a in (("unit", a_u), ("pca", a_p)):
                hit = np.flatnonzero(a[at:])
                res[key].append(hit[0] * step.total_seconds() if hit.size else None)
        cells = []
        for key in ("unit", "pca"):
            delays = [d for d in res[key] if d is not None]
            cells += [f"{len(delays)}/{len(seeds)}",
                      f"{np.median(delays):.0f}" if delays else "—"]  # fmt: skip
        lines.append(f"| {kind} | {strength:g} | " + " | ".join(cells) + " |")
    lines.append(f"\n({time.perf_counter() - t0:.0f} s)")
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="fewer seeds")
    p.add_argument("--plant", choices=sorted(PLANTS), action="append")
    args = p.parse_args(argv)
    for plant in args.plant or ["tank", "tank3", "hx"]:
        print("\n".join(run_plant(plant, PLANTS[plant], args.quick)), flush=True)
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
