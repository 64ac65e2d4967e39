"""Per-test thresholds of a test with few independent values (issue 34, HD), emulated on the
chemical plant's **tuning** runs: the unit built once (the bench's ``diag import`` + ``diag
unit build`` on training seeds 1–3), the held-out filtered residuals its thresholds were
learned from kept, then each rule's thresholds written into a copy of the unit file and the
bench's matched protocol run on it (limits matched on fault-free seeds 150–152, fault-free
153–154, faults on seeds 101–103; :func:`~diag_plugin.bench.publicbench.run_matched_benchmark`).
The scoring runs are never simulated.

Rules (``--rules``, comma-separated):

* ``main``: the tail fit wherever 30 episodes remain (the rule's value before i34-few,
  ``FEW_VALUES`` = 0; the build now uses 100 with ``budget.SEEN_Z``'s admission);
* ``gauss-N``: a side of fewer than N independent values whose window top a Gaussian series
  explains takes Rice's threshold (:func:`~diag_plugin.learn.budget.gaussian_top`;
  ``calibrate(few=N)``; the build's ``FEW_VALUES`` = 100 adds ``SEEN_Z``'s admission);
* ``always-N``: the same without the check of the window's top (every side under N values);
* ``pool-N``: the brief's pooled tail — every side standardised by its mean and spread above
  the mean, the episodes of all sides pooled on one ladder of standardised levels, a side's
  pooled distance where the pooled rate over the pool's episodes at the mean is its budget
  over its own, the threshold ``μ + σ (w z_own + (1 − w) z_pool)``, ``w = n / (n + N)``.

Per rule: the unit's own limits on the fault-free tuning runs 150–154 (episodes in 360 h;
budget 0.001/h), and per matched target the unit's mean detection, top 3, named first and
fault-free share, per sample and per hour. Run: ``python benchmarks/few_values_thresholds.py
--cache DIR --work DIR [--rules main,gauss-100,...]`` (the build ~2 CPU min, each rule ~20 s).
"""

from __future__ import annotations

import argparse
import re
import shutil
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))


def build_keeping_residuals(plant, work: Path):
    """The bench's build in this process; returns the unit and the held-out filtered
    residuals its tests' thresholds were calibrated on."""
    import diag_plugin.learn.thresholds as th
    from diag_plugin.bench import publicbench as pb

    kept = {}
    calibrate = th.calibrate

    def keep(body, *a, **k):
        kept["body"] = body.copy()
        return calibrate(body, *a, **k)

    th.calibrate = keep
    real = pb._diag

    def in_process(args, cwd, timeout=3600):
        """``diag`` in this process (the residuals kept), as the bench runs it."""
        import os
        import subprocess

        from diag_plugin.cli import main

        here = os.getcwd()
        os.chdir(cwd)
        try:
            rc = main(list(args))
        finally:
            os.chdir(here)
        return subprocess.CompletedProcess(args, rc or 0, "", "")

    pb._diag = in_process
    try:
        built = pb.build_unit_as_user(plant, plant.train, work)
    finally:
        pb._diag, th.calibrate = real, calibrate
    return built["unit"], kept["body"]


def pooled(budgets: dict, body: pd.DataFrame, dt_h: float, share: float, on: int, off: int,
           n0: float) -> None:  # fmt: skip
    """The pooled tail (module doc, ``pool-N``), in place of ``budgets``' thresholds."""
    from diag_plugin.learn import budget as B

    sides = {}
    for name in budgets:
        x = body[name].to_numpy(float)
        for sign in (1.0, -1.0):
            y = sign * x
            v = y[np.isfinite(y)]
            mu = float(v.mean())
            above = v[v > mu] - mu
            sd = float(np.sqrt(np.mean(above**2))) if above.size else 0.0
            if sd > 0:
                z = (y - mu) / sd
                e = max(int(B.episodes(z, np.zeros(1), on, off)[0]), 1)
                sides[(name, sign)] = (mu, sd, e, z, y)
    top = max(float(np.nanmax(s[3])) for s in sides.values())
    levels = top * np.linspace(0.0, 1.0, B.LADDER) ** 1.5
    counts = sum(B.episodes(s[3], levels, on, off) for s in sides.values())
    for (name, sign), (mu, sd, e, _, y) in sides.items():
        b = budgets[name]
        want = share * b.hours
        got = B.from_counts(levels, counts, counts[0] * want / e)
        if got is None:
            continue
        own = b.high if sign > 0 else -b.low
        w = b.independent / (b.independent + n0)
        k = mu + sd * (w * (own - mu) / sd + (1.0 - w) * got[0])
        lv = B.ladder(y[np.isfinite(y)])
        k = B._seen(k, lv, B.episodes(y, lv, on, off), want)
        if sign > 0:
            b.high = float(k)
        else:
            b.low = -float(k)


def rule_limits(rule: str, unit, body: pd.DataFrame, far: float) -> dict:
    """Each test's ``(low, high)`` under ``rule``, as ``learn_thresholds`` writes them."""
    from diag_plugin.diagnose.unittags import COMBINED_SHARE
    from diag_plugin.learn import budget as B
    from diag_plugin.learn.thresholds import FLOOR

    far_t = far * (1.0 - COMBINED_SHARE) if unit.ev["combined"] else far
    on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
    kind, _, n = rule.partition("-")
    few = float(n) if kind in ("gauss", "always") else 0.0
    saved = B.gaussian_top
    try:
        if kind == "always":
            B.gaussian_top = lambda v, g, p=B.GAUSS_P: True
        got = B.calibrate(body, unit.period, far_t, on_delay=on, off_delay=off, few=few)
    finally:
        B.gaussian_top = saved
    if kind == "pool":
        dt_h = pd.Timedelta(unit.period) / pd.Timedelta(hours=1)
        pooled(got, body, dt_h, far_t / (2 * body.shape[1]), on, off, float(n))
    lim = {k: (min(b.low, -FLOOR), max(b.high, FLOOR)) for k, b in got.items()}
    for t in unit.file.tests:
        if getattr(t, "statistic", "level") == "spread":
            lim[t.name] = (-lim[t.name][1], lim[t.name][1])
    return lim


def unit_with(limits: dict, folder: Path, into: Path, name: str):
    """A copy of the unit in ``folder`` with ``limits`` written into its file."""
    from diag_plugin.diagnose.unit import Unit

    shutil.rmtree(into, ignore_errors=True)
    shutil.copytree(folder, into)
    f = into / f"{name}.unit.toml"
    lines = f.read_text(encoding="utf-8").splitlines()
    for i, line in enumerate(lines):
        m = re.match(r"^([A-Za-z0-9_.]+) = \{model = ", line)
        if m and m.group(1) in limits:
            lo, hi = limits[m.group(1)]
            line = re.sub(r"\bhigh = [-0-9.e+]+", f"high = {hi:.6g}", line)
            lines[i] = re.sub(r"\blow = [-0-9.e+]+", f"low = {lo:.6g}", line)
    f.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return Unit.load(name, into)


def named_first(point: dict, fault_tags: dict) -> int:
    return sum(
        bool(r["top"]) and r["top"][0] in fault_tags.get(f, [])
        for f, x in point["faults"].items()
        for r in x["per_run"]
        if r["named_counted"]
    )


def main(argv: list[str] | None = None) -> int:
    from matched_tuning_top3 import chemplant_tuning

    from diag_plugin.bench import publicbench as pb

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default=None, help="folder for the simulated chemplant runs")
    ap.add_argument("--work", required=True, help="folder for the unit and its copies")
    ap.add_argument("--rules", default="main,gauss-100,gauss-300,always-100,pool-100")
    args = ap.parse_args(argv)
    work = Path(args.work)
    plant = chemplant_tuning(Path(args.cache) if args.cache else None)
    unit, body = build_keeping_residuals(plant, work / "build")
    folder = work / "build" / "units"
    far = float(re.search(r"^far = (\S+)", (folder / f"{plant.name}.unit.toml").read_text(),
                          re.M).group(1))  # fmt: skip
    scores: dict[int, np.ndarray] = {}
    score = pb.unit_score

    def kept(u, frame, on, off):
        s, c = score(u, frame, on, off)
        scores[id(frame)] = s
        return s, c

    pb.unit_score = kept
    base = rule_limits("main", unit, body, far)
    for rule in args.rules.split(","):
        lim = rule_limits(rule, unit, body, far)
        u = unit_with(lim, folder, work / f"rule_{rule}", plant.name)
        done = {"unit": u, "note": "", "commands": [], "seconds": 0.0, "tests": len(u.tests)}
        pb.build_unit_as_user = lambda plant, runs, work, done=done: done
        scores.clear()
        out = pb.run_matched_benchmark(plant, targets=[0.001, 0.005, 0.01, 0.02, 0.05],
                                       per="sample", work=str(work / "scratch"))  # fmt: skip
        eps = 0
        hours = 0.0
        for r in plant.calibration + plant.free:
            on = scores[id(r.frame)] > 1
            eps += int(np.count_nonzero(on[1:] & ~on[:-1]) + on[0])
            hours += len(on) * plant.period_s / 3600.0
        width = {k: (lim[k][1] - lim[k][0]) / (base[k][1] - base[k][0]) for k in lim}
        moved = sorted((w, k) for k, w in width.items() if abs(w - 1) > 1e-3)
        print(f"## {rule}: {len(moved)} of {len(lim)} bands moved "
              f"({', '.join(f'{k} ×{w:.2f}' for w, k in moved[:8])}"
              f"{' …' if len(moved) > 8 else ''}); own limits on fault-free 150–154: {eps} "
              f"episodes in {hours:.0f} h (budget {far:g}/h)")  # fmt: skip
        ft = out["fault_tags"]
        for key in ("curve", "curve_hour"):
            cells = []
            for p in out[key]["points"]:
                x = p["methods"]["unit"]
                cells.append(f"{p['target']:g}: {100 * x['mean_detection']:.1f} % top 3 "
                             f"{x['in_top']}/{x['named_runs']} first {named_first(x, ft)} "
                             f"ff {x.get('free_share') or 0:.4f}")  # fmt: skip
            print(f"  {'per sample' if key == 'curve' else 'per hour'}: " + " | ".join(cells))
        pts = out["curve"]["points"]
        for f in pts[0]["methods"]["unit"]["faults"]:
            print(f"    {f:22s} " + " ".join(
                f"{100 * p['methods']['unit']['faults'][f]['detection_rate']:.0f}/"
                f"{p['methods']['unit']['faults'][f]['in_top']}" for p in pts))  # fmt: skip
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
