"""The matched-false-alarm benchmark on a plant: the built unit beside PCA and DPCA T² + Q.

:func:`run_matched_benchmark` takes a :class:`~diag_plugin.bench.publicplants.PublicPlant`
(a public plant, or the chemical plant through :func:`chemplant_plant`) and

1. **builds the unit the plain way a user would**: the training runs written as a CSV file
   with a tags CSV, ``diag import`` into a fresh SQLite historian, ``diag unit build`` over
   the window (subprocesses of this Python, so the commands are exactly a user's). Where the
   build refuses (too few rows, …) its message is reported and the unit is left out;
2. fits **PCA and DPCA** (two lags) T² + Q on the same training runs (or, for a per-run
   protocol such as SKAB's, on each run's first rows);
3. turns every method into **one alarm score per sample** (:mod:`~diag_plugin.diagnose.
   matched`): the unit's test residuals over their thresholds on the side they leave and its
   combined T² over its limit; PCA's T² and Q over their 1 % limits; each statistic after the
   same on/off delays (the unit's, from ``evaluation_for`` of the grid when no unit is built),
   then the maximum;
4. sets each method's limit so its alarm rate on the **calibration runs** equals each target
   (per sample, or episodes per hour), and scores detection, delay, episodes and naming (the
   tag at fault among the three tags most often in the per-sample top three of the
   contributions, over the samples in alarm after the onset; the tag named first; and the
   tag named first over each alarm episode's own samples) on the **scoring runs**, and the
   false alarms on the fault-free scoring runs;
5. for a labelled protocol (SKAB) also F1, FAR and MAR per sample as its README defines them.

:func:`write_page` writes the result as a markdown page (command, date, commit and the split
at the top) — the pages under ``docs/results/`` are generated, never edited by hand.
"""

from __future__ import annotations

import logging
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from diag_plugin.bench.matched import FaultRun, Scored, curve, method_score, side_ratio
from diag_plugin.bench.pages import provenance
from diag_plugin.bench.publicplants import PlantRun, PublicPlant

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_TARGETS", "chemplant_plant", "run_matched_benchmark", "write_page"]

#: the matched false-alarm rates of the curve (share of samples)
DEFAULT_TARGETS = (0.001, 0.005, 0.01, 0.02, 0.05)
#: the matched rates of the second curve, alarm episodes per hour (grids of a minute or more;
#: faster grids: HOUR_TARGETS_FAST)
HOUR_TARGETS = (0.01, 0.02, 0.05, 0.1, 0.2)
HOUR_TARGETS_FAST = (0.5, 1.0, 2.0, 5.0, 10.0)
#: previous samples in dynamic PCA
DPCA_LAGS = 2


# ---------------------------------------------------------------- the unit, as a user builds it


def _diag(args: Sequence[str], cwd: Path, timeout: float = 3600) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "diag_plugin", *args]
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)


def build_unit_as_user(plant: PublicPlant, runs: Sequence[PlantRun], work: Path) -> dict:
    """CSV → ``diag import`` → ``diag unit build``; returns ``{"unit": Unit or None,
    "note": why not, "commands": [...], "seconds": …}``."""
    from diag_plugin.diagnose.unit import Unit

    work.mkdir(parents=True, exist_ok=True)
    data = pd.concat([r.frame for r in runs]).sort_index()
    data = data[~data.index.duplicated()]
    csv = work / f"{plant.name}_train.csv"
    data.rename_axis("ts").to_csv(csv, float_format="%.8g")
    tags = work / f"{plant.name}_tags.csv"
    tags_frame(plant).to_csv(tags, index=False)
    db = f"sqlite:///{work / 'historian.db'}"
    folder = work / "units"
    folder.mkdir(exist_ok=True)
    t0, t1 = data.index[0].isoformat(), data.index[-1].isoformat()
    cmds = [
        ["--db", db, "import", str(csv), "--tags", str(tags), "--no-progress"],
        ["--db", db, "--rulebases", str(folder), "unit", "build", plant.name,
         "--from", t0, "--to", t1, "--force"]
        + (["--loops-from", str(tags)] if plant.loops else []),
    ]  # fmt: skip
    shown = [f"diag {' '.join(c)}" for c in cmds]
    t = time.perf_counter()
    for c in cmds:
        p = _diag(c, work)
        if p.returncode != 0:
            msg = (p.stderr.strip() or p.stdout.strip()).splitlines()
            note = msg[-1] if msg else f"exit {p.returncode}"
            log.warning("%s: %s", " ".join(c[:4]), note)
            return {"unit": None, "note": note, "commands": shown,
                    "seconds": time.perf_counter() - t}  # fmt: skip
    unit = Unit.load(plant.name, folder)
    return {"unit": unit, "note": "", "commands": shown, "seconds": time.perf_counter() - t,
            "tests": len(unit.tests), "rows": len(data)}  # fmt: skip


def tags_frame(plant: PublicPlant) -> pd.DataFrame:
    """The plant's tags CSV: name, unit, description, and the declared loops' ``loop`` and
    ``role`` columns (:mod:`~diag_plugin.unitbuild.loops`)."""
    from diag_plugin.unitbuild.loops import parse_loop

    role: dict[str, tuple[str, str]] = {}
    fixed: dict[str, str] = {}  # a loop's measurement → its fixed set-point (not a tag)
    for spec in plant.loops:
        lp = parse_loop(spec)
        role[lp.pv] = (lp.pv, "pv")
        if lp.fixed is None:
            role[lp.sp] = (lp.pv, "sp")
        else:
            fixed[lp.pv] = lp.sp
        if lp.out:
            role[lp.out] = (lp.pv, "out")
    rows = [
        {"name": t, "unit": u, "description": d, "loop": role.get(t, ("", ""))[0],
         "role": role.get(t, ("", ""))[1], "set_point": fixed.get(t, "")}
        for t, (u, d) in plant.tag_info.items()
    ]  # fmt: skip
    frame = pd.DataFrame(rows)
    if not fixed:
        frame = frame.drop(columns=["set_point"])
    return frame if plant.loops else frame.drop(columns=["loop", "role"])


def unit_statistics(unit, frame: pd.DataFrame) -> tuple[np.ndarray, pd.DataFrame | None]:
    """Per sample the unit's statistics over their limits (each test's filtered residual on
    the side it leaves; the combined T²) and its per-tag contributions, from rest."""
    stats, contrib, _ = _unit_parts(unit, frame, 0, 0)
    return stats, contrib


def unit_score(
    unit, frame: pd.DataFrame, on: int, off: int
) -> tuple[np.ndarray, pd.DataFrame | None]:
    """The unit's one alarm score per sample (:func:`~diag_plugin.bench.matched.method_score`
    of :func:`unit_statistics` after the delays ``on``/``off``, with its oscillation hold's
    columns, :func:`~diag_plugin.bench.matched.oscillation_score`) and its per-tag
    contributions, from rest: over 1 where the unit itself alarms."""
    stats, contrib, held = _unit_parts(unit, frame, on, off)
    return method_score(stats, on, off, held), contrib


def _unit_parts(unit, frame: pd.DataFrame, on: int, off: int):
    """:func:`unit_statistics`' statistics and contributions and, with delays (``on`` ≥ 1),
    the oscillation hold's delayed columns (None without a hold)."""
    from diag_plugin.bench.matched import oscillation_score
    from diag_plugin.diagnose.unitloops import oscillation_samples

    unit.reset().openings_seen = []  # the hold's settles, as the unit's replay opens them
    try:
        d = unit.evaluate(frame)
        seen = unit.openings_seen
    finally:
        unit.openings_seen = None
    lo, hi = unit._limits()
    r = d.residuals.to_numpy()
    stats = side_ratio(r, lo, hi)
    held = None
    w = oscillation_samples(unit.ev, unit.period)
    if on >= 1 and w:
        with np.errstate(invalid="ignore", divide="ignore"):
            up = np.where(hi > 0, r / hi, np.nan)
            down = np.where(lo < 0, r / lo, np.nan)
        opens = np.concatenate(seen) if seen else None
        held = oscillation_score(up, down, on, off, w, opens=opens, quiet=unit._quiet_n())
    cm = getattr(unit, "cmodel", None)
    if d.combined is not None and cm is not None and cm.high:
        stats = np.c_[stats, d.combined["T2"].to_numpy() / cm.high]
    return stats, _named_by_tests(unit, d), held


def _named_by_tests(unit, d) -> pd.DataFrame | None:
    """The unit's contributions (each tag's share of ``T²``), and where no share is known
    (``T²`` unknown: fewer than half the tests known, most of them outside what the unit
    learned) the values its tests in alarm name the tags by, as the unit itself names them
    there (:meth:`~diag_plugin.diagnose.unittags.TestNames.on_values`: a test on names the tag
    it models first, then those it reads; :meth:`~diag_plugin.diagnose.unittags.TestNames.
    fill`); NaN where no test is on either (no tag named, :func:`~diag_plugin.bench.plant.
    top_from_contributions`). Classic TEP IDV6 (tuning run d06, the A feed lost): the unit's
    ``T²`` unknown on most of its alarm, its tests on name XMEAS1 and XMV3."""
    c = d.contributions
    names = getattr(unit, "test_names", None)
    if c is None or names is None:
        return c
    x = c.to_numpy(dtype=float)
    blind = ~np.isfinite(x).any(axis=1)
    if not blind.any():
        return c
    on = names.on_values(d.residuals.to_numpy()[blind], d.symptoms.to_numpy()[blind])
    x = x.copy()
    x[blind] = np.where(on > 0, on, np.nan)
    return pd.DataFrame(x, index=c.index, columns=c.columns)


def _sample_grid(frame: pd.DataFrame, period: str) -> pd.DataFrame:
    """A run's samples one period apart from its first timestamp (SKAB's 1 s log skips a
    second now and then; PCA and DPCA count samples, and so does the unit scored here)."""
    t0 = frame.index[0]
    t0 = t0.tz_localize("UTC") if t0.tzinfo is None else t0
    out = frame.copy()
    out.index = pd.date_range(t0, periods=len(frame), freq=period)
    return out


# ---------------------------------------------------------------- PCA


def _joined(runs: Sequence[pd.DataFrame], cols: list[str], lags: int) -> pd.DataFrame:
    gap = pd.DataFrame(np.nan, index=range(lags), columns=cols)
    parts = []
    for r in runs:
        parts += [r[cols].reset_index(drop=True), gap]
    return pd.concat(parts[:-1], ignore_index=True)


def pca_fit(runs: Sequence[pd.DataFrame], cols: list[str], lags: int, share: float):
    from diag_plugin.bench.pca import PCADetector

    return PCADetector(n_components=share, lags=lags, columns=cols).fit(_joined(runs, cols, lags))


def pca_statistics(det, frame: pd.DataFrame) -> tuple[np.ndarray, pd.DataFrame]:
    s = det.score(frame)
    stats = np.c_[s["T2"].to_numpy() / det.t2_limit_, s["Q"].to_numpy() / det.q_limit_]
    return stats, det.contributions(frame)


# ---------------------------------------------------------------- the benchmark


def run_matched_benchmark(
    plant: PublicPlant,
    *,
    targets: Sequence[float] = DEFAULT_TARGETS,
    per: str = "sample",
    work: str | Path | None = None,
    pca_share: float | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict:
    """Score the built unit, PCA and DPCA on ``plant`` at matched false-alarm ``targets``
    (see module doc). Returns a JSON-able dict (also what :func:`write_page` writes)."""
    from diag_plugin.unitbuild.build import evaluation_for

    tick = progress or (lambda stage, done, total: None)
    seconds: dict[str, float] = {}
    share = pca_share or (0.85 if plant.name == "skab" else 0.9)
    period = f"{int(plant.period_s)}s"
    tmp = None
    if work is None:
        tmp = tempfile.TemporaryDirectory(prefix=f"matched_{plant.name}_")
        work = tmp.name
    work = Path(work)
    try:
        t = time.perf_counter()
        tick("build the unit", 0, 1)
        if plant.per_run:
            # the protocol's own way: the first run's head through the user's commands, then
            # a unit per run from that run's head (build_unit in this process)
            n = plant.faults[0].learn if plant.faults else 0
            one = PlantRun(plant.faults[0].name, plant.faults[0].frame.iloc[:n])
            built = build_unit_as_user(plant, [one], work)
            if built["unit"] is not None:
                built["note"] = (
                    "a unit per run, built from the run's first rows (the protocol's training rows)"
                )
        else:
            built = build_unit_as_user(plant, plant.train, work)
        seconds["unit build"] = time.perf_counter() - t
    finally:
        if tmp is not None:
            tmp.cleanup()
    unit = built["unit"]
    if unit is not None:
        on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
    else:
        ev = evaluation_for(period)
        on, off = int(ev["on_delay"]), int(ev["off_delay"])
    cols = list(plant.tags)

    t = time.perf_counter()
    fitted: dict[str, object] = {}
    if not plant.per_run:
        frames = [r.frame for r in plant.train]
        fitted = {
            "PCA": pca_fit(frames, cols, 0, share),
            "DPCA": pca_fit(frames, cols, DPCA_LAGS, share),
        }
    seconds["PCA fit"] = time.perf_counter() - t
    methods = (["unit"] if unit is not None else []) + ["PCA", "DPCA"]

    per_run_units: dict[str, object] = {}
    run_work = Path(tempfile.mkdtemp(prefix=f"units_{plant.name}_")) if plant.per_run else None

    def run_unit(run: PlantRun):
        """The unit of a per-run protocol: built from ``run``'s first rows."""
        from diag_plugin.diagnose.unit import Unit
        from diag_plugin.unitbuild.build import build_unit

        if run.name not in per_run_units:
            folder = run_work / f"run{len(per_run_units)}"
            t0 = time.perf_counter()
            res = build_unit(plant.name, _sample_grid(run.frame, period).iloc[: run.learn],
                             folder=folder,
                             period=period, tag_info=plant.tag_info and {
                                 t: {"unit": u, "description": d}
                                 for t, (u, d) in plant.tag_info.items()}, force=True)  # fmt: skip
            per_run_units[run.name] = Unit.load(res.path, folder)
            seconds["per-run unit builds"] = seconds.get("per-run unit builds", 0.0) + (
                time.perf_counter() - t0
            )
        return per_run_units[run.name]

    def scored(run: PlantRun) -> dict[str, Scored]:
        """Every method's score on ``run`` (for a per-run protocol: fitted on its first rows,
        scored on the rest)."""
        out = {}
        frame = run.frame
        dets = fitted
        if plant.per_run:
            head = frame.iloc[: run.learn]
            dets = {"PCA": pca_fit([head], cols, 0, share),
                    "DPCA": pca_fit([head], cols, DPCA_LAGS, share)}  # fmt: skip
        for m in methods:
            if m == "unit":
                u = run_unit(run) if plant.per_run else unit
                grid = _sample_grid(frame, period) if plant.per_run else frame
                s, contrib = unit_score(u, grid, on, off)
            else:
                stats, contrib = pca_statistics(dets[m], frame)
                s = method_score(stats, on, off)
            cut = run.learn if plant.per_run else 0
            c = None if contrib is None else contrib.iloc[cut:]
            out[m] = Scored(s[cut:], c)
        return out

    t = time.perf_counter()
    per_method: dict[str, dict] = {
        m: {"calibration": [], "free": [], "faults": []} for m in methods
    }
    total = len(plant.calibration) + len(plant.free) + len(plant.faults)
    done = 0
    for role, runs in (("calibration", plant.calibration), ("free", plant.free)):
        for r in runs:
            for m, s in scored(r).items():
                x = s.score
                if r.labels is not None:  # a labelled run: its fault-free samples only
                    x = before_onset(x, r.labels[(r.learn if plant.per_run else 0) :])
                per_method[m][role].append(x)
            done += 1
            tick("score fault-free runs", done, total)
    fault_runs = []
    labels = []
    for r in plant.faults:
        cut = r.learn if plant.per_run else 0
        lab = None if r.labels is None else r.labels[cut:]
        active = None if lab is None else lab > 0
        fault_runs.append(
            FaultRun(r.fault or r.name, r.name, int(r.onset) - cut, tuple(r.tags), active)
        )
        labels.append(lab)
        for m, s in scored(r).items():
            per_method[m]["faults"].append(s)
        done += 1
        tick("score fault runs", done, total)
    seconds["score"] = time.perf_counter() - t

    if plant.per_run and not plant.free:
        # SKAB: the fault-free scoring samples are the scoring runs' samples before their
        # first labelled anomaly (SKAB's own FAR, every label-0 sample, is its table's)
        for m in methods:
            per_method[m]["free"] = [
                before_onset(s.score, lab)
                for s, lab in zip(per_method[m]["faults"], labels, strict=True)
            ]
    res = curve(per_method, targets, plant.period_s, per, fault_runs)
    hourly = None
    if per == "sample":  # the same scores, limits matched in alarm episodes per hour
        ht = HOUR_TARGETS if plant.period_s >= 60 else HOUR_TARGETS_FAST
        hourly = curve(per_method, ht, plant.period_s, "hour", fault_runs)
    if any(lab is not None for lab in labels):
        for p in res["points"]:
            for m in methods:
                lim = p["methods"][m]["limit"]["limit"]
                lim = np.inf if lim is None else lim
                p["methods"][m]["skab"] = skab_metrics(per_method[m]["faults"], labels, lim)
    for p in res["points"] + (hourly["points"] if hourly else []):
        for m in methods:  # the per-run detail stays in the JSON, not the alarm rows
            for f in p["methods"][m]["faults"].values():
                for r in f["per_run"]:
                    r.pop("alarm_rows", None)
    return {
        "plant": plant.name,
        "title": plant.title,
        "period_s": plant.period_s,
        "source": plant.source,
        "split": plant.split,
        "per": per,
        "targets": list(targets),
        "delays": [on, off],
        "pca_share": share,
        "methods": methods,
        "unit": {k: v for k, v in built.items() if k != "unit"},
        "fault_info": {f.fault: plant.fault_info.get(f.fault or "", "") for f in fault_runs},
        "fault_tags": {f.fault: list(f.tags) for f in fault_runs},
        "runs": {
            "train": [r.name for r in plant.train],
            "calibration": [r.name for r in plant.calibration],
            "free": [r.name for r in plant.free],
            "faults": [r.name for r in plant.faults],
            "tuning": [r.name for r in plant.tuning],
        },
        "curve": res,
        "curve_hour": hourly,
        "seconds": {k: round(v, 1) for k, v in seconds.items()},
    }


def before_onset(x: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """The samples of a labelled run before its first labelled anomaly: its fault-free
    operation. The label-0 samples *after* a fault are not: the process is recovering, and
    every method's alarm that saw the fault is still held there by its off-delay (on SKAB's
    tuning runs each such tail is one plateau at the fault's own level, 171–173 samples of a
    run that ends within the off-delay), so counting them as fault-free would set a low
    target's limit at the level of the largest fault seen to its end rather than of the
    fault-free scores."""
    return x[: fault_free_mask(labels).sum()]


def fault_free_mask(labels: np.ndarray, recovery: bool = False) -> np.ndarray:
    """Which samples of a labelled run are its fault-free operation (:func:`before_onset`):
    those before its first labelled anomaly; with ``recovery`` every label-0 sample, the
    recovery after the anomaly included (the SKAB bench's calibration until 2026-12-02)."""
    lab = np.asarray(labels)
    if recovery:
        return lab == 0
    hit = np.flatnonzero(lab > 0)
    return np.arange(lab.size) < (hit[0] if hit.size else lab.size)


def skab_metrics(
    scores: Sequence[Scored], labels: Sequence[np.ndarray], limit: float | Sequence[float]
) -> dict:
    """F1, FAR and MAR per sample over all runs, as the SKAB README's binary metric:
    ``F1 = TP / (TP + (FN + FP) / 2)``, ``FAR = FP / (FP + TN)``, ``MAR = FN / (FN + TP)``
    (unknown samples are not in alarm); ``limit`` one for all runs or one per run."""
    tp = tn = fp = fn = 0
    limits = np.broadcast_to(np.asarray(limit, float), (len(scores),))
    for s, lab, limit in zip(scores, labels, limits, strict=True):
        pred = np.where(np.isnan(s.score), -np.inf, s.score) > limit
        true = lab > 0
        tp += int(np.sum(pred & true))
        tn += int(np.sum(~pred & ~true))
        fp += int(np.sum(pred & ~true))
        fn += int(np.sum(~pred & true))
    return {
        "F1": tp / (tp + (fn + fp) / 2) if tp + fn + fp else float("nan"),
        "FAR": fp / (fp + tn) if fp + tn else float("nan"),
        "MAR": fn / (fn + tp) if fn + tp else float("nan"),
    }


# ---------------------------------------------------------------- the chemical plant


def chemplant_plant(quick: bool = False, faults: Sequence[str] | None = None) -> PublicPlant:
    """The project's own chemical plant (3-min means) in the same shape: train seeds 1–3 × 10
    days, calibration 9161–9163 × 3 days, fault-free scoring 9151–9153 × 3 days, faults
    9101–9103 × 3 days from day 1 (``quick``: 2 × 6 days, one seed each, three faults).
    Tuning seeds 101–103 (faults) and 150–154 (fault-free) are not run here."""
    from diag_plugin.simulate.chemplant import FAULTS, sample, simulate_chemplant

    train_seeds, days = ((1, 2), 6.0) if quick else ((1, 2, 3), 10.0)
    cal_seeds = (9161,) if quick else (9161, 9162, 9163)
    free_seeds = (9151,) if quick else (9151, 9152, 9153)
    fault_seeds = (9101,) if quick else (9101, 9102, 9103)
    names = ("fi109_bias", "tv103_stuck", "feed_comp_step") if quick else tuple(FAULTS)
    if faults:
        unknown = [f for f in faults if f not in FAULTS]
        if unknown:
            raise ValueError(f"unknown fault(s) {', '.join(unknown)}; known: {', '.join(FAULTS)}")
        names = tuple(faults)
    run_days, onset_days = (2.0, 0.5) if quick else (3.0, 1.0)
    start = pd.Timestamp("2026-01-01", tz="UTC")
    train = []
    for s in train_seeds:
        f = sample(simulate_chemplant(days, s, start=start), 180)
        train.append(PlantRun(f"seed {s}", f))
        start = f.index[-1] + pd.Timedelta("1h")
    cal = [PlantRun(f"seed {s}", sample(simulate_chemplant(run_days, s), 180)) for s in cal_seeds]
    free = [PlantRun(f"seed {s}", sample(simulate_chemplant(run_days, s), 180)) for s in free_seeds]
    faults = [
        chemplant_fault_run(name, s, run_days, onset_days, f"{name} seed {s}")
        for name in names
        for s in fault_seeds
    ]
    loops = chemplant_loops()
    return chemplant_public(
        train,
        cal,
        free,
        faults,
        "the project's chemical plant simulator (3-min means)",
        [
            f"train: fault-free seeds {', '.join(map(str, train_seeds))} × {days:g} days",
            f"calibration (the matched limits): fault-free seeds "
            f"{', '.join(map(str, cal_seeds))} × {run_days:g} days",
            f"fault-free scoring: seeds {', '.join(map(str, free_seeds))} × {run_days:g} days",
            f"fault scoring: seeds {', '.join(map(str, fault_seeds))}, {run_days:g}-day runs, "
            f"the fault from day {onset_days:g}",
            "tuning (not run here): fault seeds 101–103, fault-free 150–154",
            "loops declared to the unit build (issue 34, docs/how-to/unit-loops.md): "
            + ", ".join(loops),
        ],
    )


def chemplant_fault_run(
    name: str, seed: int, days: float, onset_days: float, label: str
) -> PlantRun:
    """One fault run of the chemical plant (3-min means): ``name`` from ``onset_days`` on,
    with the row of its onset and its tags at fault."""
    from diag_plugin.simulate.chemplant import FAULTS, sample, simulate_chemplant

    raw = simulate_chemplant(days, seed, fault=name, onset_s=onset_days * 86400)
    x = sample(raw, 180)
    onset = pd.Timestamp(raw.attrs["fault"]["onset"])
    if x.index.tz is not None and onset.tz is None:
        onset = onset.tz_localize(x.index.tz)
    k = int(np.searchsorted(x.index, onset))
    return PlantRun(label, x, name, k, tuple(FAULTS[name].tags))


def chemplant_loops() -> list[str]:
    """The chemical plant's loops as a user declares them in the tags CSV (each controller:
    the tag it holds, its set-point, its output)."""
    return [f"{pv}={c}.SP:{c}.OUT" for c, pv in CHEMPLANT_LOOPS.items()]


def chemplant_public(
    train: list[PlantRun],
    calibration: list[PlantRun],
    free: list[PlantRun],
    faults: list[PlantRun],
    title: str,
    split: list[str],
) -> PublicPlant:
    """The chemical plant's runs as a :class:`PublicPlant` (:func:`chemplant_plant`; the
    tuning check, ``benchmarks/matched_tuning_top3.py``): PCA's columns the measurements and
    outputs (the unit's historian holds the set-points too), the loops declared."""
    from diag_plugin.simulate.chemplant import CHEMPLANT_TAGS, FAULTS

    return PublicPlant(
        name="chemplant",
        title=title,
        period_s=180.0,
        tags=[c for c, v in CHEMPLANT_TAGS.items() if v[4] != "set-point"],
        tag_info={t: (v[0], v[3]) for t, v in CHEMPLANT_TAGS.items()},
        train=train,
        calibration=calibration,
        free=free,
        faults=faults,
        fault_info={n: FAULTS[n].kind for n in dict.fromkeys(f.fault for f in faults) if n},
        source="diag_plugin.simulate.chemplant",
        loops=chemplant_loops(),
        split=split,
    )


#: the chemical plant's controllers and the measured tag each one holds
CHEMPLANT_LOOPS = {
    "FIC101": "FI101",
    "FIC102": "FI102",
    "TIC103": "TI103",
    "TIC104": "TI104",
    "LIC101": "LI101",
    "TIC107": "TI107",
    "PIC101": "PI101",
    "LIC102": "LI102",
    "LIC103": "LI103",
}


# ---------------------------------------------------------------- the page


def _pct(x: float | None, digits: int = 0) -> str:
    return "—" if x is None or not np.isfinite(x) else f"{100 * x:.{digits}f} %"


def _dur(s: float | None) -> str:
    if s is None:
        return "—"
    return f"{s / 3600:.1f} h" if s >= 3600 else f"{s / 60:.0f} min" if s >= 60 else f"{s:.0f} s"


def _episodes_right(x: dict) -> str:
    """A fault's or a method's alarm episodes named right (:func:`~diag_plugin.bench.matched.
    naming`) of those named, and the runs whose name changed between episodes."""
    if not x["named_runs"]:
        return "—"
    return f"{x['episodes_right']}/{x['episodes_named']}; {x['name_changed_runs']} changed"


def _summary(pts: list[dict], methods: list[str], per: str) -> list[str]:
    """The curve as a table: per target and method the mean detection, the runs named, the
    false alarms on the fault-free scoring runs and the calibration rate reached."""
    head = "| target | " + " | ".join(
        f"{m} detection | {m} top 3 | {m} first | {m} episodes right | "
        f"{m} false alarms (share, /h: episodes, 95 %) | {m} calibration"
        for m in methods
    )
    lines = [head + " |", "|" + "---|" * (1 + 6 * len(methods))]
    for p in pts:
        cells = [f"{p['target']:g}" + ("" if per == "sample" else "/h")]
        for m in methods:
            x = p["methods"][m]
            lim = x["limit"]
            fa = (
                "—"
                if x["free_share"] is None
                else f"{_pct(x['free_share'], 2)}, {x['free_per_hour']:.3g}"
            )
            if x.get("free_per_hour_95"):
                lo, hi = x["free_per_hour_95"]
                fa += f": {x['free_episodes']}, {lo:.3g}–{hi:.3g}"
            cal = f"{_pct(lim['share'], 2)}, {lim['per_hour']:.3g}/h" + (
                "" if lim["supported"] else " †"
            )
            n = x["named_runs"]
            cells += [_pct(x["mean_detection"]), f"{x['in_top']}/{n}",
                      f"{x['named_first']}/{n}", _episodes_right(x), fa, cal]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return [*lines, ""]


def render_page(out: dict, command: str) -> str:
    """The result as markdown: provenance, the split, the curve, a table per target."""
    methods = out["methods"]
    per = out["per"]
    unit_of = "share of samples" if per == "sample" else "alarm episodes per hour"
    lines = [
        f"# Matched false alarms: {out['title']}",
        "",
        *provenance(command),
        f"- data: {out['source']}",
        f"- sample period {out['period_s']:g} s; every method's statistics after on/off "
        f"delays of {out['delays'][0]}/{out['delays'][1]} samples, then their maximum; the "
        f"limit on it set so the {unit_of} in alarm on the calibration runs is the target",
        f"- PCA and DPCA ({DPCA_LAGS} lags): T² + Q, components to {out['pca_share']:.0%} "
        "of the variance, each statistic over its 1 % limit",
        "",
        "Runs and what each is for (fixed before any result was looked at):",
        "",
        *[f"- {s}" for s in out["split"]],
        "",
    ]
    u = out["unit"]
    if "unit" in methods:
        lines.append(
            f"The unit: built by the plain commands below from {u.get('rows', '?')} rows, "
            f"{u.get('tests', '?')} tests, in {u['seconds']:.0f} s:"
        )
    else:
        lines.append(f"**The unit could not be built**: `{u['note']}`. Commands tried:")
    lines += ["", "```", *u["commands"], "```", ""]
    pts = out["curve"]["points"]
    lines += [
        "## Detection against false alarms",
        "",
        "Mean detection rate over the faults (share of samples in alarm from the onset on, "
        "or where a labelled data set marks the fault; unknown samples count as not in "
        "alarm), the tag at fault in the top three (runs where one is defined), the runs "
        "whose tag named first is the tag at fault (*first*), the alarm episodes after the "
        "onset whose tag named first over the episode's own samples is the tag at fault, of "
        "the episodes, and the runs whose name changed between episodes (*episodes right*), "
        "and the false alarms on the fault-free scoring runs, per "
        "target: the share of samples and the alarm episodes per hour, with the episodes "
        "counted and the exact 95 % interval of their rate (an episode's samples are one "
        "event: a rate from a handful of episodes is known to a factor of two or three). "
        "*Calibration* is the rate reached on the calibration runs; a target the "
        "calibration runs cannot resolve (under 5 alarm samples or episodes expected) is "
        "marked †.",
        "",
    ]
    lines += _summary(pts, methods, per)
    if out.get("curve_hour"):
        lines += [
            "The same scores with each limit matched in **alarm episodes per hour** on the "
            "calibration runs:",
            "",
            *_summary(out["curve_hour"]["points"], methods, "hour"),
        ]
    if "skab" in pts[0]["methods"][methods[0]]:
        lines += [
            "SKAB's own binary metrics on the scoring runs (per sample after each run's first "
            "400; F1 = TP/(TP + (FN+FP)/2), FAR = FP/(FP+TN), MAR = FN/(FN+TP)):",
            "",
            "| target | " + " | ".join(f"{m} F1 | {m} FAR | {m} MAR" for m in methods) + " |",
            "|" + "---|" * (1 + 3 * len(methods)),
        ]
        for p in pts:
            cells = [f"{p['target']:g}"]
            for m in methods:
                s = p["methods"][m]["skab"]
                cells += [f"{s['F1']:.2f}", _pct(s["FAR"], 1), _pct(s["MAR"], 1)]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    faults = list(pts[0]["methods"][methods[0]]["faults"])
    for p in pts:
        lines += [
            f"## At {p['target']:g}" + (" of samples" if per == "sample" else " per hour"),
            "",
            "Per fault: detection rate, median delay of the first alarm after the onset, "
            "alarm episodes after the onset (mean per run), the tag at fault in the top three "
            "(runs), named first (runs), the episodes named right (of the episodes; runs "
            "whose name changed between episodes), and the three tags named (first run).",
            "",
            "| fault | tag at fault | "
            + " | ".join(
                f"{m} detected | delay | episodes | top 3 | first | episodes right | named"
                for m in methods
            )
            + " |",
            "|" + "---|" * (2 + 7 * len(methods)),
        ]
        for f in faults:
            tags = out["fault_tags"].get(f) or []
            cells = [f, ", ".join(tags) or "—"]
            for m in methods:
                x = p["methods"][m]["faults"][f]
                named = x["per_run"][0]["top"] if x["per_run"] else []
                cells += [
                    _pct(x["detection_rate"]),
                    _dur(x["delay_s"]),
                    f"{x['episodes']:.1f}",
                    f"{x['in_top']}/{x['named_runs']}" if x["named_runs"] else "—",
                    f"{x['named_first']}/{x['named_runs']}" if x["named_runs"] else "—",
                    _episodes_right(x),
                    ", ".join(named) or "—",
                ]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    if out.get("fault_info"):
        lines += ["## The faults", ""]
        for f, d in out["fault_info"].items():
            lines.append(f"- {f}: {d or '—'}")
        lines.append("")
    sec = ", ".join(f"{k} {v:g} s" for k, v in out["seconds"].items())
    lines += [f"Times on this machine: {sec}.", ""]
    return "\n".join(lines)


def write_page(out: dict, path: str | Path, command: str) -> Path:
    """Write :func:`render_page` to ``path`` (folders made)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(render_page(out, command), encoding="utf-8")
    return p
