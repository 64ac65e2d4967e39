"""``diag unit accept`` and ``diag unit rollback``: a new operating point an operator confirms.

When the plant moves to an operating point the unit never learned (a manual valve at a new
position), its tests there are unknown and the unit CHECK_FUNCTION, naming the input that
left what it learned (:mod:`diag_plugin.diagnose.operating`). Once an operator confirms a
period there as fault-free, :func:`accept` learns it into the unit:

1. **Backup**: the unit file and every model file are copied to
   ``.unit-backups/NAME/N/`` beside the unit file (N = 1, 2, … ; ``manifest.json`` lists
   the files and the window accepted); :func:`rollback` puts the newest back and removes it.
2. **Models, exact merge**: each test's model is retrained on the windows its file says it
   learned from (``[training] windows``, else ``from``/``to``) — the same rows give the same
   integer accumulators (:meth:`~diag_plugin.fuzzy.wang_mendel.WangMendelRegressor.merge`)
   or least-squares factor — and the model of the accepted window is merged into it: the
   result is the model of all those rows (Kościelny et al., eq. 5 over the union: every
   rule's count and sums add). Locked rules stay as the expert set them.
   A joint test (:mod:`diag_plugin.models.joint`) gets the accepted window as an operating
   point of its own (:func:`add_point`): its component is the within-point one, and each
   sample is scored against the nearest point's mean.
3. **Thresholds re-learned** over all the windows together (cross-fitted, to the unit's own
   budget), as ``diag unit learn`` learns them; the windows are set one after another on one
   time grid (a window weeks away re-timed to follow a gap), and the cross-fitting's block
   ``b`` is the ``b``-th of equal spans of every window, never a whole window (a window at a
   new operating point held out whole has no model that covers it; as equal spans of the
   joined frame a 400 s build window fell in one block, and its residuals came from models
   of the accepted point alone). Each window is an operating point of the combined
   test (its mean of every tag): each sample's residuals are centred at its nearest point's,
   the T²'s scale and covariance are the pooled within-point ones
   (:func:`~diag_plugin.learn.thresholds.learn_combined`). A level test (a tag against its
   mean, no inputs) gets a mean and a spread per point (``point_center``, ``point_scale`` in
   ``[tests]``, :func:`~diag_plugin.learn.thresholds.level_points`): its residual is taken
   at the sample's nearest point, so it still sees a fault there. The set-points' responses
   are the within-point ones and the tags' directions each point's.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import tomlkit

from diag_plugin.regressors import InputSpec, max_lag
from diag_plugin.unitbuild import short
from historian.errors import UserError

#: methods whose input spans the build widens beyond the window (``short.widened``)
LINEAR_METHODS = ("linear", "joint")

#: the folder, beside the unit file, that keeps each accept's backup
BACKUPS = ".unit-backups"

#: a test whose threshold band an accept widens more than this many times is named
WIDER = 3.0

Reader = Callable[[pd.Timestamp, pd.Timestamp], Iterable[pd.DataFrame]]


@dataclass
class AcceptResult:
    unit: str
    window: tuple[str, str]
    backup: Path
    windows: list[tuple[str, str]]
    samples: dict[str, int] = field(default_factory=dict)  # per test: rows added
    rules: dict[str, tuple[int, int]] = field(default_factory=dict)  # per test: before, after
    limits: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: per test: its thresholds before the accept (low, high; NaN where it had none)
    before: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: per test (and ``combined``): what of its band before the accept was kept, because the
    #: re-learned one was narrower (:func:`never_narrower`)
    kept: dict[str, dict] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    #: what each start's envelope re-learned rests on (``[build] envelope``)
    envelope: list[str] = field(default_factory=list)

    def widened(self) -> dict[str, float]:
        """Per test whose band (high − low) the accept widened more than :data:`WIDER`
        times: how many times. Such a test now passes what it flagged before: its inputs do
        not tell the accepted operating point from the learned ones, so both points'
        residuals share one band (SKAB: the pump's current modelled from its voltage, the
        valve1 run at a third of the anomaly-free run's flow, 13.2 → 68.3 % of span)."""
        out = {}
        for k, (lo, hi) in self.limits.items():
            lo0, hi0 = self.before.get(k, (math.nan, math.nan))
            if hi0 - lo0 > 0 and (hi - lo) / (hi0 - lo0) > WIDER:
                out[k] = (hi - lo) / (hi0 - lo0)
        return out

    def as_dict(self) -> dict:
        return {
            "unit": self.unit,
            "window": list(self.window),
            "backup": str(self.backup),
            "windows": [list(w) for w in self.windows],
            "samples": self.samples,
            "rules": {k: list(v) for k, v in self.rules.items()},
            "thresholds": _as_json(self.limits),
            "thresholds_before": _as_json(self.before),
            "widened": self.widened(),
            "kept": self.kept,
            "warnings": self.warnings,
            "envelope": self.envelope,
        }


def moved_fixed(fixed, frame: pd.DataFrame) -> list[str]:
    """The ``[fixed]`` tags (constant over the windows the unit learned: a held set-point, a
    mode) that ``frame`` (an accepted window, the models' tag names) holds beyond their margin.
    Only then are a linear test's windows merged with an intercept each
    (:func:`~diag_plugin.models.linear.within_merge`) and its residual taken at each window's
    point: the points differ by an input none of the tests reads, which one line through them
    covers by bending its coefficients (an aeration basin's oxygen set-point held at 2.0 for
    14 days, a day at 1.5 accepted: the blower's band doubled, the diffuser fouling 52.9 →
    31.1 %; with an intercept each 45.6 %, docs/explanation/acceptance-aeration2.md). Where
    the points differ in tags the tests read, one line stays: a pump's two accelerometers,
    each the other's linear test, at 4× the vibration at the accepted point kept their
    residuals' tight correlation that way, and the combined test its threshold (22; 52 with
    an intercept each, and a flow bias at the first point then missed)."""
    out = []
    for tag, s in (fixed or {}).items():
        if tag not in frame.columns:
            continue
        x = frame[tag].to_numpy(float)
        x = x[np.isfinite(x)]
        if x.size and (x.min() < s.lo or x.max() > s.hi):
            out.append(tag)
    return out


def backup_root(unit_file: Path) -> Path:
    unit_file = Path(unit_file)
    from diag_plugin.rulebase.folder import UNIT_SUFFIX

    return unit_file.parent / BACKUPS / unit_file.name.removesuffix(UNIT_SUFFIX)


def _numbered(root: Path) -> list[Path]:
    found = [p for p in root.glob("*") if p.is_dir() and p.name.isdigit()] if root.exists() else []
    return sorted(found, key=lambda p: int(p.name))


def keep_unit_backup(unit, why: dict) -> Path:
    """Copy the unit file and its model files (and matrix) to the next numbered backup."""
    uf = unit.file
    root = backup_root(uf.path)
    have = _numbered(root)
    target = root / str(int(have[-1].name) + 1 if have else 1)
    target.mkdir(parents=True)
    files = [uf.path, *(uf.resolve(t.model) for t in uf.tests)]
    if uf.matrix_path is not None:
        files.append(uf.matrix_path)
    base = uf.path.parent.resolve()
    listed = []
    for k, f in enumerate(files):
        copy = target / f"{k:03d}_{f.name}"
        shutil.copy2(f, copy)
        full = Path(f).resolve()
        to = full.relative_to(base) if full.is_relative_to(base) else full
        listed.append({"copy": copy.name, "to": str(to)})
    manifest = {"unit": unit.name, "files": listed, **why}
    (target / "manifest.json").write_text(json.dumps(manifest, indent=2), encoding="utf-8")
    return target


def rollback(unit_file: Path) -> dict:
    """Put the newest backup of the unit back (unit file, models, matrix) and remove it;
    returns its manifest, with ``replaced``: the folder the files it overwrote are kept in
    (``replaced/N`` beside the backups: a hand edit made since the accept is not lost).
    :class:`UserError` when there is none."""
    unit_file = Path(unit_file)
    root = backup_root(unit_file)
    have = _numbered(root)
    if not have:
        raise UserError(f"{unit_file}: no backup to roll back to (none under {root})")
    last = have[-1]
    manifest = json.loads((last / "manifest.json").read_text(encoding="utf-8"))
    base = unit_file.parent
    before = _numbered(root / "replaced")
    kept = root / "replaced" / str(int(before[-1].name) + 1 if before else 1)
    for f in manifest["files"]:
        dest = Path(f["to"])
        dest = dest if dest.is_absolute() else base / dest
        if dest.exists():
            kept.mkdir(parents=True, exist_ok=True)
            shutil.copy2(dest, kept / f["copy"])
        shutil.copy2(last / f["copy"], dest)
    manifest["replaced"] = str(kept) if kept.exists() else None
    shutil.rmtree(last)
    manifest["restored_from"] = str(last)
    manifest["left"] = len(have) - 1
    return manifest


def training_windows(rb) -> list[tuple[pd.Timestamp, pd.Timestamp]]:
    """The windows a model file says it was trained on: ``[training] windows``, else its
    ``from``/``to``; empty when it says neither."""
    tr = rb.training
    raw = tr.get("windows")
    pairs = [tuple(w) for w in raw] if raw else [(tr.get("from"), tr.get("to"))]
    out = []
    for a, b in pairs:
        if a is None or b is None:
            continue
        ta, tb = pd.Timestamp(str(a)), pd.Timestamp(str(b))
        out.append((_utc(ta), _utc(tb)))
    return out


def _utc(t: pd.Timestamp) -> pd.Timestamp:
    return t.tz_localize("UTC") if t.tzinfo is None else t.tz_convert("UTC")


def _joined(
    frames: list[pd.DataFrame], period: str, history: int = 0
) -> tuple[pd.DataFrame, np.ndarray]:
    """Windows one after another on one time grid, with a gap of missing rows between them,
    so the learning's filter settles in each (each is its own run) and no lag reaches into
    the window before (the gap is longer than ``history`` samples). Lags count samples, so
    the frame must be on a regular grid: a window that starts later than the gap's end is
    moved up to follow it. It stays inside the models' training range (between the first
    window's start and the last one's end), which the cross-fitting reads; the windows' own
    times are what the caller records. The cross-fitting cuts each window (run) into its
    blocks (``by_run=WITHIN_RUNS``), never holding out a whole window: a window at a new
    operating point held out whole would leave no model that covers it. Returned with each
    row's window (a gap's rows: the window before it), the runs the cross-fitting cuts: a
    window that starts within the gap's length after the one before keeps its time, so the
    gap between them is shorter than a run's gap, and found from the data the two were one
    run — the later window, the last of it, held out whole (a pressure set-point accepted 2 h
    after a 14-day build window at 2 min: its residuals all from models without it, the
    combined test centred 6.3 % off at the new point and in alarm on 98.9 % of the week
    after; docs/explanation/acceptance-boiler.md)."""
    from diag_plugin.learn.thresholds import RUN_GAP

    parts: list[pd.DataFrame] = []
    runs: list[np.ndarray] = []
    step = pd.Timedelta(period)
    rows = max(RUN_GAP, history) + 1
    for k, f in enumerate(frames):
        if k and len(parts[-1]):
            last = parts[-1].index[-1]
            gap = pd.date_range(last + step, periods=rows, freq=step)
            if len(f) and f.index[0] > gap[-1] + step:
                f = f.set_axis(f.index - (f.index[0] - (gap[-1] + step)))
            gap = gap[gap < f.index[0]] if len(f) else gap
            parts.append(pd.DataFrame(np.nan, index=gap, columns=f.columns))
            runs.append(np.full(len(gap), k - 1))
        parts.append(f)
        runs.append(np.full(len(f), k))
    out = pd.concat(parts)
    run = np.concatenate(runs) if runs else np.zeros(0, np.int64)
    keep = ~out.index.duplicated()
    out, run = out[keep], run[keep]
    order = np.argsort(out.index.asi8, kind="stable")
    return out.iloc[order], run[order].astype(np.int64)


def old_runs(frame: pd.DataFrame, window: np.ndarray, new: int) -> tuple[np.ndarray, np.ndarray]:
    """Each row's run for the cross-fitting of :func:`_joined`'s frame (``window``: each
    row's window, ``new`` the accepted one's): the old windows split into their runs at gaps
    of more than ``RUN_GAP`` rows, as their build found them, and held out whole as it held
    them (``whole``, :func:`~diag_plugin.learn.thresholds.block_of`); the accepted window one
    run, cut in spans. Before, each old window was one run cut in 5 spans: the pumping
    station's I_M2 high re-learned +2.42 where the build's way gave +10.40 on the same unit
    and rows (docs/explanation/acceptance-pumps.md)."""
    from diag_plugin.learn.thresholds import runs_of

    data = frame.notna().any(axis=1).to_numpy()
    out = np.zeros(len(window), np.int64)
    nxt = 0
    for w in np.unique(window):
        rows = np.flatnonzero(window == w)
        out[rows] = nxt + (runs_of(data[rows]) if w != new else 0)
        nxt = int(out[rows].max()) + 1
    return out, window != new


def accept(
    unit,
    read: Reader,
    start: pd.Timestamp,
    end: pd.Timestamp,
    *,
    far: float | None = None,
) -> AcceptResult:
    """Learn the fault-free window ``[start, end)`` into ``unit`` (see module doc).
    ``read(a, b)`` yields the unit's aligned frames (plant tag names) of ``[a, b)``."""
    from diag_plugin.diagnose.equipment import learnable_for, output_tag, owner
    from diag_plugin.diagnose.running import learnable
    from diag_plugin.diagnose.settle import state_tags
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.diagnose.unitfile import UnitFile
    from diag_plugin.learn.thresholds import (
        DEFAULT_FAR,
        WITHIN_RUNS,
        LearnError,
        learn_thresholds,
    )
    from diag_plugin.models.linear import is_line, within_merge
    from diag_plugin.rulebase.document import RuleBase
    from diag_plugin.training.chunked import train

    start, end = _utc(pd.Timestamp(start)), _utc(pd.Timestamp(end))
    if end <= start:
        raise UserError(f"--to {end} is not after --from {start}")
    uf = unit.file
    far = far if far is not None else float(uf.thresholds.get("far", DEFAULT_FAR))
    cache: dict[tuple, pd.DataFrame] = {}
    as_read: dict[tuple, pd.DataFrame] = {}  # the run tag's own values: its starts

    def window(a: pd.Timestamp, b: pd.Timestamp) -> pd.DataFrame:
        if (a, b) not in cache:
            parts = [f for f in read(a, b) if len(f)]
            if not parts:
                raise UserError(f"no samples of the unit's tags in {a} … {b}")
            as_read[(a, b)] = unit._model_frame(pd.concat(parts))
            # the stopped rows as an outage: only the running plant is learned (running.py)
            cache[(a, b)] = learnable(as_read[(a, b)], unit.file.running)
        return cache[(a, b)]

    def own(frame: pd.DataFrame, t) -> pd.DataFrame:
        """What test ``t`` learns from: a piece of equipment's test the rows where it runs
        (diagnose/equipment.py)."""
        out = output_tag(unit.models[t.name].output)
        return learnable_for(frame, owner(getattr(unit, "equipment", ()), out))

    new = window(start, end)
    rows = int(new.notna().any(axis=1).sum())
    if not rows:
        raise UserError(f"no samples of the unit's tags in {start} … {end}")
    if rows < short.MIN_ROWS:
        # an operating point rests on the period: its merged rules, a level test's mean and
        # spread there, the combined test's point; no fewer samples than a build's window
        raise UserError(
            f"unit {unit.name}: {start} … {end} holds {rows} samples of its {unit.period} grid; an "
            f"operating point needs at least {short.MIN_ROWS}, as a build's window does "
            "(confirm a longer period)"
        )
    # a tag constant over every window learned (a held set-point, [fixed]) moved past its
    # margin: an input that tells the points apart, which no test reads
    lines = moved_fixed(uf.fixed, new)
    plans = []
    warnings: list[str] = []
    all_windows: set[tuple[pd.Timestamp, pd.Timestamp]] = {(start, end)}
    for t in uf.tests:
        path = uf.resolve(t.model)
        rb = RuleBase.load(path)
        old = training_windows(rb)
        if not old:
            raise UserError(
                f"{path}: [training] names no window it was trained on; train it (diag train) "
                "before accepting a period into its unit"
            )
        if any(a < end and start < b for a, b in old):
            raise UserError(
                f"{start} … {end} overlaps the window {path.name} already learned "
                f"({', '.join(f'{a} … {b}' for a, b in old)})"
            )
        mine = own(new, t)
        out = output_tag(unit.models[t.name].output)
        if out in mine.columns and not mine[out].notna().any():  # its equipment stopped
            why = (
                f"{out} has no value in the period"  # the tag itself missing, not stopped
                if out not in new.columns or not new[out].notna().any()
                else "its equipment did not run in the window"
            )
            warnings.append(f"{t.name}: {why}: its model keeps what it learned")
            continue
        rb, said = widen_spans(rb, mine)
        if rb.method == short.JOINT:
            rb = add_point(rb, [window(a, b) for a, b in old], new)
        # a loop's test and its spread test share one model file: its spans said once
        if all(path != p for _, p, _, _ in plans):
            warnings.extend(f"{path.name}: {w}" for w in said)
        plans.append((t, path, rb, old))
        all_windows |= set(old)
    backup = keep_unit_backup(
        unit, {"accepted": [start.isoformat(), end.isoformat()], "at": _now()}
    )
    res = AcceptResult(unit.name, (start.isoformat(), end.isoformat()), backup, [])
    res.before = _limits(uf)
    try:
        for t, path, rb, old in plans:
            parts = [train(rb, reader(own(window(a, b), t)), a, b, holdout=0).model
                     for a, b in old]  # fmt: skip
            got = train(rb, reader(own(new, t)), start, end, holdout=0)
            if lines and is_line(parts[0]):  # one line, an intercept per window
                before = rb.codec.size(parts[0])
                model = within_merge([*parts, got.model])
            else:
                model = parts[0]
                for m in parts[1:]:
                    model.merge(m)
                before = rb.codec.size(model)
                model.merge(got.model)
            res.samples[t.name] = int(got.samples)
            res.rules[t.name] = (before, rb.codec.size(model))
            wins = sorted([*old, (start, end)])
            prov = dict(rb.training)
            prov.update({
                "source": "diag unit accept",
                "from": wins[0][0].isoformat(),
                "to": wins[-1][1].isoformat(),
                "windows": [[a.isoformat(), b.isoformat()] for a, b in wins],
                "samples": int(prov.get("samples", 0) or 0) + int(got.samples),
                "trained_at": _now(),
            })  # fmt: skip
            rb.apply_training(model, prov)
            rb.save(path)
        windows = sorted(all_windows)
        res.windows = [(a.isoformat(), b.isoformat()) for a, b in windows]
        # before the thresholds: they judge there; first among the notes, which the text
        # output cuts to four: a tag the unit now answers at (a constant tag's, a hand
        # valve's span, a state learned) outweighs a model's span note
        warnings[:0] = widen_manual(uf.path, new)
        fresh = Unit.load(uf.path, uf.path.parent)
        history = max((max_lag(m.inputs) for m in fresh.models.values()), default=0)
        frame, runs = _joined([window(a, b) for a, b in windows], fresh.period, history)
        frame = frame.rename(columns={k: v for k, v in fresh.file.tags.items()})
        # each window an operating point of the combined test: its mean of every tag
        points = pd.DataFrame([window(a, b).mean() for a, b in windows])
        points = points.rename(columns={k: v for k, v in fresh.file.tags.items()})
        k = windows.index((start, end))
        split, whole = old_runs(frame, runs, k)
        try:
            learned = learn_thresholds(
                fresh, [frame], far=far, by_run=WITHIN_RUNS, points=points, runs=split,
                whole=whole, line_points=bool(lines),
            )  # fmt: skip
        except LearnError as exc:
            raise UserError(
                f"unit {unit.name}: cannot learn thresholds:\n"
                + "\n".join("  " + p for p in exc.problems)
            ) from None
        learned.window = (windows[0][0].isoformat(), windows[-1][1].isoformat())
        res.kept = never_narrower(learned, uf, pd.Series(runs != k, index=frame.index))
        out = UnitFile.load(uf.path)
        out.set_learned(learned)
        out.save(as_read=True)
        # the starts' envelopes re-learned over all the windows, from the same held-out
        # residuals, in the thresholds just written (as the build learns them)
        # (none where nothing settles after a change)
        rc = fresh.file.running
        if state_tags(fresh) or getattr(fresh, "equipment", None):
            starts = frame.rename(columns={v: k for k, v in fresh.file.tags.items()})
            if rc is not None and rc.tag in starts.columns:  # its stopped rows as read
                run = _joined([as_read[w][[rc.tag]] for w in windows], fresh.period, history)
                got = run[0][rc.tag].reindex(starts.index).to_numpy()
                starts = starts.assign(**{rc.tag: got})
            res.envelope = relearn_envelopes(uf.path, starts, learned)
        # as the file holds them: a one-sided test (a spread's, a T²-like one) has no low
        res.limits = _limits(UnitFile.load(uf.path))
        res.warnings = warnings + list(learned.warnings)
    except BaseException:
        rollback(uf.path)  # leave the unit as it was
        raise
    return res


def relearn_envelopes(path: Path, frame: pd.DataFrame, learned) -> list[str]:
    """The unit file ``path``'s starts' envelopes (``[envelope]``, :mod:`diag_plugin.diagnose.
    envelope`) learned again from ``frame`` (every window the unit learned, models' tag names,
    the run tag as read) and the held-out residuals its thresholds were just learned from
    (``learned``), in units of those thresholds, under the settles' bounds the file keeps;
    the ``[build] envelope`` notes replaced. Before, an accept kept the build's envelope: in
    units of thresholds it had replaced, from the build's starts alone. A unit with no state
    nor piece of equipment to settle is left as it was. Returns the notes."""
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.diagnose.unitfile import UnitFile
    from diag_plugin.unitbuild.loops import HeldOut, settle_envelopes

    unit = Unit.load(path, path.parent)
    bounds = {k: float(unit.ev.get(k, 0.0) or 0.0)
              for k in ("settle_max_s", "state_settle_max_s")}  # fmt: skip
    pieces = {e.name: e.settle_max_s for e in getattr(unit, "equipment", None) or ()}
    envs = settle_envelopes(unit, frame, HeldOut(unit, frame, learned.scaled), bounds, pieces)
    if not envs:
        return []
    uf = UnitFile.load(path)
    got = {k: env.as_table() for k, env, _ in envs if env is not None}
    if got:
        uf.doc["envelope"] = got
    elif "envelope" in uf.doc:
        del uf.doc["envelope"]
    if "build" in uf.doc:
        uf.doc["build"]["envelope"] = [how for *_, how in envs]
    uf.save()
    return [how for *_, how in envs]


def never_narrower(learned, before, old: pd.Series | None = None) -> dict[str, dict]:
    """Make what ``learned`` (the thresholds re-learned over every window) holds no narrower
    than what unit file ``before`` held, side by side; returns per test what was kept.

    An operator confirms a period as fault-free: it adds evidence of normal variation and
    removes none. Yet the re-learned bands can come out narrower where the unit already
    answered (the pumping station at 4.8 bar: ``I_M2`` high +10.40 → +2.56,
    docs/explanation/acceptance-pumps.md): every threshold there rests on a tail fit
    extrapolated to 57 times the window's length, and a day more of data — and the merged
    models' cross-fitted residuals on the old window — move that extrapolation a long way.
    An unseen run at the old operating point then alarms more than before the accept. So:

    * each side of a test: ``low = min(low_before × s, low_learned)``,
      ``high = max(high_before × s, high_learned)`` (a one-sided test, its high alone), where
      ``s`` is the robust spread (1.4826 MAD) of the test's residual over the windows the
      unit had learned (``old``: True on their rows), as the re-learning scales it, over
      the same spread before (the half-width of its fuzzy ramps, :func:`~diag_plugin.learn.
      thresholds.fuzzy_sets`): a residual in units of its model's local spread changes
      units when the merged model's spread does (a quiet accepted period makes the old
      cells' relative spread larger and their residuals smaller), and the band is kept in
      the units of the old window's own residuals;
    * its level scales (a coarser rule level's, relative to the fine grid's) as re-learned:
      the larger of before and learned on top of the kept limit would widen it twice over
      (tried with the plain maximum of the stored limits: on a quiet accepted period a
      3 m³/h meter bias went from 59.8 % detected before the accept to 0 %; with ``s`` and
      the re-learned scales 30.0 %, tests/test_unit_accept_never_narrower.py);
    * its fuzzy sets' ramps moved with the threshold they are centred on (same width);
    * the combined test's ``high`` the larger of before and learned.

    Not kept where the band before rested on too little to say what normal variation is, or
    measured another residual: a test whose thresholds before were Rice's Gaussian model
    (``method`` ``gaussian`` in ``[learned]``: too few episodes for a tail, the band widened
    by the predictive Student t of few independent values — the more evidence, the
    narrower, as a build of a longer window would give: a 400 s build's level test after an
    hour accepted, tests/test_unit_accept.py; not ``rice``, Rice's model chosen where the
    window held a tail's episodes, :func:`~diag_plugin.learn.budget.calibrate_side`, kept as
    a tail's band is), and a level test that gets operating points
    in this accept (its residual now centred and scaled at each point, another unit); the
    combined test alike (Gaussian, or its first points).

    What is not kept either: a model's local spread (a spread test's residual is divided by the
    answering rules' spread, which the merged model holds), a level test's point scales,
    the combined test's covariance — each is the merged data's own."""
    from diag_plugin.learn.thresholds import robust_sd

    kept: dict[str, dict] = {}
    body = getattr(learned, "body", None)
    if body is not None and old is not None:
        body = body[old.reindex(body.index, fill_value=False).to_numpy(bool)]
    notes = before.doc.get("learned") or {}
    points = getattr(learned, "level_points", {}) or {}
    for t in before.tests:
        if t.name not in learned.limits or _thin(notes.get(t.name)):
            continue
        if t.name in points and t.point_scale is None:
            continue  # its residual is scaled at each point from now on: another unit
        lo, hi = learned.limits[t.name]
        lo0 = -math.inf if t.low is None else float(t.low)
        hi0 = -math.inf if t.high is None else float(t.high)
        one_sided = t.low is None
        note: dict = {}
        was = _ramp(t.fuzzy)
        have = body is not None and t.name in body
        now = robust_sd(body[t.name].to_numpy(float)) if have else 0.0
        if was > 0 and now > 0:
            s = now / was
            lo0, hi0 = lo0 * s, hi0 * s
            note["scale"] = float(f"{s:.4g}")
        if hi0 > hi:
            note["kept_high"] = [float(f"{hi:.6g}"), float(f"{hi0:.6g}")]
            hi = hi0
        if not one_sided and lo0 < lo:
            note["kept_low"] = [float(f"{lo:.6g}"), float(f"{lo0:.6g}")]
            lo = lo0
        if one_sided:
            lo = -hi  # as learn_thresholds writes a spread's (its low is not a test)
        kept[t.name] = note
        if set(note) <= {"scale"}:
            continue
        learned.limits[t.name] = (lo, hi)
        if t.name in learned.fuzzy:
            n1, n0, p0, p1 = learned.fuzzy[t.name]
            dn, up = (n0 - n1) / 2.0, (p1 - p0) / 2.0
            learned.fuzzy[t.name] = (lo - dn, lo + dn, hi - up, hi + up)
    learned.kept = {k: v for k, v in kept.items() if set(v) - {"scale"}}
    c0, c = before.combined, getattr(learned, "combined", None)
    fresh = c0 is not None and not c0.point_at and c is not None and bool(c.point_at)
    if (
        c0 is not None and c is not None and c0.high is not None and c.high is not None
        and not _thin(c0.notes) and not fresh
    ):  # fmt: skip
        if c0.high > c.high:
            kept["combined"] = {"kept_high": [float(f"{c.high:.6g}"), float(f"{c0.high:.6g}")]}
            c.high = float(c0.high)  # said in the summary ([combined] takes no such key)
    return kept


def _ramp(fuzzy) -> float:
    """The robust spread a test's fuzzy ramps were drawn with: their half-width (the wider
    of the two; a ramp is cut at 0.999 of its threshold only when the spread is wider)."""
    if not fuzzy:
        return 0.0
    n1, n0, p0, p1 = fuzzy
    return max((n0 - n1) / 2.0, (p1 - p0) / 2.0)


def _thin(note) -> bool:
    """A ``[learned]`` (or combined) note whose thresholds rest on Rice's Gaussian model: too
    few episodes in the window for a tail (:mod:`diag_plugin.learn.budget`)."""
    return "gaussian" in str((note or {}).get("method", ""))


def widen_manual(path: Path, frame: pd.DataFrame) -> list[str]:
    """The unit file's hand-valve spans (``[manual]``, :mod:`~diag_plugin.diagnose.manual`),
    its narrow tested tags' (``[narrow]``, the same rows) and its few-valued set-points'
    (``[chosen]``, the same rows)
    widened to hold the accepted window ``frame`` (models' tag names): ``min``/``max`` merged
    exactly, the larger margin kept; and its constant tags' (``[fixed]``,
    :mod:`~diag_plugin.diagnose.fixed`) to the values the window held them at, the margin
    kept. Saved when one changed. Returns what changed."""
    from diag_plugin.diagnose.combos import widen as more_combos
    from diag_plugin.diagnose.fixed import widen
    from diag_plugin.diagnose.manual import learned_span, merged
    from diag_plugin.diagnose.unitfile import UnitFile

    uf = UnitFile.load(path)
    said = []
    changed = [
        (table, what, tag, old, new)
        for table, what, spans in (
            ("manual", "hand valve", uf.manual),
            ("narrow", "narrow tag", uf.narrow),
            ("chosen", "set-point", uf.chosen),
        )  # fmt: skip
        for tag, old in spans.items()
        if tag in frame.columns
        and (new := merged(old, learned_span(tag, frame[tag].to_numpy(float)))) != old
    ]
    # the tags constant over the build window (diagnose/fixed.py): the values the accepted
    # window held them at are learned, margin kept
    changed += [("fixed", "constant tag", tag, uf.fixed[tag], new)
                for tag, new in widen(uf.fixed, frame).items()]  # fmt: skip
    # the combinations of the discrete states it held long enough (diagnose/combos.py)
    if added := more_combos(uf.states, frame):
        seen = uf.doc["states"]["seen"]
        for c in added:
            seen.append(c)
        said.append(f"combination(s) of {', '.join(uf.states['tags'])} learned: "
                    f"{'; '.join(added)} (held {uf.states['held_s']:g} s or longer)")  # fmt: skip
    for table, what, tag, old, new in changed:
        row = tomlkit.inline_table()
        row.update(new.as_row())
        uf.doc[table][tag] = row
        said.append(
            f"{what} {tag}: span {old.min:g} … {old.max:g} (margin {old.margin:g}) → "
            f"{new.min:g} … {new.max:g} (margin {new.margin:g})"
        )
    if said:
        uf.save()
    return said


def _as_json(limits: dict[str, tuple[float, float]]) -> dict[str, dict[str, float | None]]:
    """``{test: {"low": …, "high": …}}``, null where a test has no such threshold (NaN is
    not JSON)."""
    return {
        k: {"low": None if a != a else a, "high": None if b != b else b}
        for k, (a, b) in limits.items()
    }


def _limits(uf) -> dict[str, tuple[float, float]]:
    """Per test of unit file ``uf``: its (low, high) thresholds, NaN where it has none."""
    nan = math.nan
    return {
        t.name: (nan if t.low is None else t.low, nan if t.high is None else t.high)
        for t in uf.tests
    }


def reader(frame: pd.DataFrame):
    """``read(a, b)`` over an in-memory frame (what ``train`` reads chunk by chunk)."""
    idx = frame.index

    def read(a: pd.Timestamp, b: pd.Timestamp) -> pd.DataFrame:
        return frame.iloc[idx.searchsorted(a) : idx.searchsorted(b)]

    return read


def _grown(lo0: float, hi0: float, lo: float, hi: float, step: float) -> tuple[int, int]:
    """Whole steps to add below and above ``[lo0, hi0]`` to reach ``[lo, hi]``."""
    below = int(math.ceil((lo0 - lo) / step - 1e-9)) if lo < lo0 else 0
    above = int(math.ceil((hi - hi0) / step - 1e-9)) if hi > hi0 else 0
    return below, above


def widen_spans(rb, frame: pd.DataFrame):
    """``rb`` with every plain input's (and the output's) span grown to hold the accepted
    window's values, a grid's set step kept (sets added at the ends); the rules are cleared
    (the models are retrained from the data of every window next). Returns the rule base and
    what changed. A model with locked rules is not regrown (the expert's cells would move):
    :class:`UserError`."""
    said = []
    doc = rb.doc
    tables = [("output", doc["output"], rb.output)] + [
        (f"input {v.spec}", doc["inputs"][j], v) for j, v in enumerate(rb.inputs)
    ]
    for what, table, v in tables:
        s = InputSpec.parse(v.spec)
        if s.fn != "" or s.tags[0] not in frame.columns:
            continue
        x = frame[s.tags[0]].to_numpy(float)
        if not np.isfinite(x).any():
            continue
        lo, hi = float(np.nanmin(x)), float(np.nanmax(x))
        lo0, hi0 = v.span
        if lo >= lo0 and hi <= hi0:
            continue
        reach = (lo, hi)
        if rb.method in LINEAR_METHODS and what != "output":
            # as the build gives a linear test's inputs (short.widened): a line learned from
            # the window is trusted a quarter of its range beyond it, not to its very extremes
            # (where every excursion would flip the unit in and out of CHECK_FUNCTION)
            lo, hi = short.widened((lo, hi))
        if any(getattr(r, "lock", False) for r in rb.rules):
            raise UserError(
                f"{rb.path}: {s.tags[0]} reaches {lo:g} … {hi:g}, outside the span "
                f"{lo0:g} … {hi0:g}, and the model has locked rules: widen the span by hand "
                "(diag rules edit) before accepting"
            )
        grid = "sets" in table and what != "output" and rb.method.startswith("wm")
        step = (hi0 - lo0) / (v.sets - 1) if grid else (hi0 - lo0) / 10.0
        below, above = _grown(lo0, hi0, lo, hi, step)
        new = (lo0 - below * step, hi0 + above * step)
        table["span"] = [float(f"{new[0]:.10g}"), float(f"{new[1]:.10g}")]
        if grid:
            table["sets"] = v.sets + below + above
        said.append(
            f"{what}: span {lo0:g} … {hi0:g} → {new[0]:g} … {new[1]:g}"
            + (f", {v.sets} → {v.sets + below + above} sets (the step kept)" if grid else "")
            + f" (the window reaches {reach[0]:g} … {reach[1]:g})"
        )
    said.extend(_widen_learned_output(rb, frame))
    if not said:
        return rb, said
    rb.clear_rules("spans widened by diag unit accept")
    from diag_plugin.rulebase.document import RuleBase

    training = dict(rb.training)
    out = RuleBase(rb.dumps(), rb.path)
    out.training.update({k: v for k, v in training.items() if k != "status"})
    return out, said


def _widen_learned_output(rb, frame: pd.DataFrame) -> list[str]:
    """A linear test's ``[rules] learned_output`` (a short window's output range where its span
    is an instrument's, :data:`~diag_plugin.models.linear.LEARNED_OUTPUT`) grown to hold the
    accepted window's values: what it says, or nothing."""
    from diag_plugin.models.linear import LEARNED_OUTPUT

    have = rb.options.get(LEARNED_OUTPUT) if rb.method == "linear" else None
    tag = InputSpec.parse(rb.output.spec).tags[0]
    if have is None or tag not in frame.columns:
        return []
    x = frame[tag].to_numpy(float)
    if not np.isfinite(x).any():
        return []
    lo0, hi0 = (float(v) for v in have)
    lo, hi = min(lo0, float(np.nanmin(x))), max(hi0, float(np.nanmax(x)))
    if lo >= lo0 and hi <= hi0:
        return []
    rb.doc["rules"][LEARNED_OUTPUT] = [float(f"{lo:.10g}"), float(f"{hi:.10g}")]
    return [f"output's learned range {lo0:g} … {hi0:g} → {lo:g} … {hi:g}"]


def add_point(rb, old: list[pd.DataFrame], new: pd.DataFrame):
    """``rb`` (a joint test) with the accepted window as an operating point of its own: its
    ``[rules] points`` (the points it learned, else one: the mean of the windows it learned)
    and the mean of the group's tags over ``new``. The joint test then scores each sample
    against its nearest point's mean, along the component of fault-free variation *within*
    the points (:mod:`diag_plugin.models.joint`): the group's total covariance over two
    points far apart has as its first component the line between them, on which each point
    sits at one end (SKAB, a unit from valve1/1's first 400 s after accepting the
    anomaly-free run's first hour: the joint test alarmed on every normal sample)."""
    from diag_plugin.models.joint import POINTS, set_points

    cols = [InputSpec.parse(v.spec).tags[0] for v in [*rb.inputs, rb.output]]

    def mean(frames: list[pd.DataFrame]) -> list[float]:
        f = pd.concat([x.reindex(columns=cols) for x in frames]).dropna()
        if not len(f):
            raise UserError(f"{rb.path}: no sample with every tag of {', '.join(cols)}")
        return [float(v) for v in f.mean().to_numpy(float)]

    have = rb.options.get(POINTS)
    points = [list(p["at"]) for p in have] if have else [mean(old)]
    points.append(mean([new]))
    set_points(rb, np.asarray(points), np.zeros(len(points)))
    return rb


def _now() -> str:
    return pd.Timestamp.now(tz="UTC").floor("s").isoformat()
