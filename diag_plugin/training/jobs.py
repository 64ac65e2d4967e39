"""Training jobs: ``diag train NAME|--all`` and ``diag experiments NAME``.

A training job reads the model's rule-base file, streams the historian
window in chunks (memory flat in the length of the range), trains with
``partial_fit`` (or on a Dask cluster), validates on a time-ordered held-out
block, writes the rule base keeping the experts' locked rules, and records
an experiment so the user can watch the error fall version by version.
The commands' arguments are in :mod:`diag_plugin.training.cli` (a light module: ``diag``
builds its parser without importing this one).
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import sys
import time
from collections.abc import Mapping
from contextlib import nullcontext
from pathlib import Path

import pandas as pd
from sqlalchemy.engine import make_url

from diag_plugin.cliargs import table_console
from diag_plugin.metrics import coverage_note, levels_note
from diag_plugin.regressors import needed_tags
from diag_plugin.rulebase.backups import backups
from diag_plugin.rulebase.document import RuleBase, RuleBaseError, resolve
from diag_plugin.rulebase.folder import is_model_file
from diag_plugin.training.baseline import KEY, describe, json_keys
from diag_plugin.training.chunked import DEFAULT_CHUNK, on_grid, train
from diag_plugin.training.dask_connect import check_timeout, connect, dask_address
from historian.access import WindowReader, experiments
from historian.errors import UserError
from historian.jsonable import to_jsonable
from historian.store import Historian

log = logging.getLogger(__name__)


def safe_url(url: str) -> str:
    """The database URL without its password, for provenance and messages."""
    try:
        return make_url(url).render_as_string(hide_password=True)
    except Exception:  # noqa: BLE001 - not a URL SQLAlchemy knows; keep as given
        return url


def data_window(
    rb: RuleBase,
    url: str,
    start: str | None = None,
    end: str | None = None,
    *,
    historian: Historian | None = None,
) -> tuple[list[str], pd.Timestamp, pd.Timestamp]:
    """The tags a model file reads and the range to train it on, on the model's grid:
    ``start``/``end`` where given (any time; naive means UTC), else from the first to one
    period past the last stored sample of those tags. ``historian``: the open historian of
    ``url`` to ask (the caller closes it); else one is opened for the question."""
    tags = needed_tags([*(v.spec for v in rb.inputs), rb.output.spec])
    with nullcontext(historian) if historian is not None else Historian.open(url) as h:
        known = set(h.tags()["name"])
        missing = [t for t in tags if t not in known]
        if missing:
            raise KeyError(f"tag(s) {', '.join(missing)} of model {rb.name} not in {safe_url(url)}")
        a, b = h.time_range(tags)
    if a is None:
        raise ValueError(f"no samples of {', '.join(tags)} in {safe_url(url)}")
    period = pd.Timedelta(rb.period)
    t0 = on_grid(_utc(start) if start else a, period)
    t1 = on_grid(_utc(end), period) if end else on_grid(b, period, "near") + period
    if t1 <= t0:
        raise ValueError(
            f"no sample of {rb.name}'s {rb.period} grid from {t0} to {t1} "
            f"(its data run from {a} to {b})"
        )
    return tags, t0, t1


def _utc(t: str) -> pd.Timestamp:
    """A time given by the user: naive means UTC."""
    ts = pd.Timestamp(t)
    return ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")


def train_one(
    path: Path,
    url: str,
    *,
    start: str | None = None,
    end: str | None = None,
    holdout: float = 0.2,
    chunk: pd.Timedelta | None = DEFAULT_CHUNK,
    engine: str = "local",
    scheduler: str | None = None,
    progress=None,
    baseline: bool = True,
    client=None,
) -> dict:
    """Train the model in ``path`` and record the experiment; returns the result dict.
    ``baseline``: put HistGradientBoosting's held-out error on the same design rows beside
    the model's (``hgb_baseline`` in the dict, and ``baseline`` for one release:
    :func:`~diag_plugin.training.baseline.hgb_baseline`; none where nothing is held out).
    ``client``: a checked Dask client (:func:`diag_plugin.training.dask_connect.connect`) to train
    the chunks on; ``engine="dask"`` with ``scheduler`` (an address, connected here) or
    without (a cluster in this process) says the same the old way.
    One historian connection serves the data range, the reads and the record (each
    ``Historian.open`` costs its engine, schema check and connections)."""
    rb = RuleBase.load(path)
    with Historian.open(url) as h:
        tags, t0, t1 = data_window(rb, url, start, end, historian=h)
        reader = WindowReader(url, tuple(tags), rb.period, historian=h)
        fit_chunks = None
        if client is not None or engine == "dask":
            from diag_plugin.training.dask_engine import dask_fitter

            fit_chunks = dask_fitter(client if client is not None else scheduler, reader)
        started = time.perf_counter()
        try:
            res = train(
                rb,
                reader,
                t0,
                t1,
                holdout=holdout,
                chunk=chunk,
                progress=progress,
                fit_chunks=fit_chunks,
                keep_rows=baseline and holdout > 0,
            )
        finally:
            reader.close()
        seconds = time.perf_counter() - started  # the training's (the baseline has its own)
        rb.apply_training(
            res.model,
            {
                "source": safe_url(url),
                "from": t0.isoformat(),
                "to": t1.isoformat(),
                "samples": res.samples,
                "dropped": sum(res.dropped.values()),
                "validation_rmse_pct": round(res.validation["rmse_pct"], 4)
                if math.isfinite(res.validation["rmse_pct"])
                else "n/a",
                # the held-out block: from here to "to" (diag compare names it)
                "validation_from": res.validation_range[0].isoformat(),
                "trained_at": pd.Timestamp.now(tz="UTC").floor("s").isoformat(),
            },
        )
        rb.save()
        metrics = {k: v for k, v in res.validation.items() if not _is_nan(v)}
        hgb = None
        if res.design is not None and res.validation.get("samples"):
            from diag_plugin.training.baseline import hgb_baseline

            span = rb.output.span[1] - rb.output.span[0]
            hgb = hgb_baseline(*res.design, span)
            metrics.update(baseline_metrics(hgb))
        version = len(h.experiments(rb.name)) + 1
        h.record_model_version(rb.name, str(version), rb.dumps())
        h.record_experiment(
            rb.name,
            str(version),
            [v.spec for v in rb.inputs],
            t0,
            t1,
            {**metrics, "rules": res.size, "trained_samples": res.samples},
        )
    out = {"model": rb.name, "version": version, **res.as_dict()}
    out["seconds"] = round(seconds, 3)
    out["rulebase"] = str(path)
    out.update(json_keys(hgb))
    return out


def baseline_metrics(b: Mapping | None) -> dict:
    """The HistGradientBoosting baseline's held-out figures as an experiment records them
    (``hgb_baseline_rmse_pct``, ``hgb_baseline_mae_pct``, on the same held-out rows as the
    model's ``rmse_pct``); empty where none was computed."""
    if not b or b.get("rmse_pct") is None:
        return {}
    return {"hgb_baseline_rmse_pct": b["rmse_pct"], "hgb_baseline_mae_pct": b["mae_pct"]}


def heldout_note(r: Mapping) -> str:
    """What the held-out figure of a training result measures, in one sentence, so it is
    never mistaken for ``diag compare``'s in-sample figure; a warning line more per input the
    held-out block sees at one operating point (:mod:`.heldout`)."""
    from diag_plugin.training.heldout import narrow_note

    a, b = (pd.Timestamp(t) for t in r["validation_range"])
    t0 = pd.Timestamp(r["train_range"][0])
    share = (b - a) / (b - t0) if b > t0 else float("nan")
    return (
        f"held out: the last {share:.0%} of the range, {a:%Y-%m-%d %H:%M} … "
        f"{b:%Y-%m-%d %H:%M} ({r['validation']['samples']:,} samples), predicted by the "
        "model trained on the rest; the saved model then learned them too, so diag compare "
        "(which scores it on the samples it was trained on) gives an in-sample figure"
    ) + "".join("\n" + narrow_note(n) for n in r.get("heldout_narrow", []))


def _is_nan(v) -> bool:
    return isinstance(v, float) and not math.isfinite(v)


def cmd_train(args) -> int:
    if args.all == bool(args.name):
        raise UserError("give a model NAME or --all")
    paths = (
        sorted(p for p in Path(args.rulebases).glob("*.toml") if is_model_file(p))
        if args.all
        else [resolve(args.name, args.rulebases)]
    )
    if not paths:
        raise UserError(f"no rule-base files in {args.rulebases}")
    try:
        chunk = pd.Timedelta(args.chunk) if args.chunk else None
    except ValueError:
        raise UserError(f"--chunk {args.chunk!r} is not a duration like 7D or 12h") from None
    address = dask_address(args)
    check_timeout(args.dask_timeout)
    with contextlib.ExitStack() as stack:
        client = None
        if address not in (None, "local"):  # reached and checked before any work
            client = stack.enter_context(connect(address, args.dask_timeout))
        return _train_all(args, paths, chunk, address, client)


def _train_all(args, paths: list[Path], chunk, address: str | None, client) -> int:
    """:func:`cmd_train`'s models, one after the other (``client``: a checked Dask client;
    ``address`` ``local``: a cluster in this process, the deprecated ``--engine dask``)."""
    results, failures = [], []
    con = _stderr_console()
    for path in paths:
        if not path.exists():
            failures.append(
                {
                    "rulebase": str(path),
                    "error": "no such model file (diag model new …)",
                    "bad_input": True,
                }
            )
            continue
        try:
            with _progress(con, path.stem) as cb:
                results.append(
                    train_one(
                        path,
                        args.db,
                        start=args.start,
                        end=args.end,
                        holdout=args.holdout,
                        chunk=chunk,
                        engine="dask" if address else "local",
                        client=client,
                        progress=cb,
                        baseline=not args.no_baseline,
                    )
                )
        except RuleBaseError as exc:
            failures.append(
                {"rulebase": str(path), "error": "\n".join(exc.problems), "bad_input": True}
            )
        except (KeyError, ValueError, UserError, FileNotFoundError) as exc:
            failures.append(
                {"rulebase": str(path), "error": str(exc).strip("'\""), "bad_input": True}
            )
        except Exception as exc:  # noqa: BLE001 - one model's failure must not stop the others
            if type(exc).__module__.startswith(("sqlalchemy", "psycopg", "adbc", "sqlite3")):
                raise  # the database, not this model: diag reports it (exit 3)
            log.debug("training %s failed", path, exc_info=exc)
            failures.append({"rulebase": str(path), "error": f"{type(exc).__name__}: {exc}"})
    if args.json:
        doc = results[0] if (len(paths) == 1 and results) else {"results": results}
        if failures:
            doc = {**doc, "failures": failures} if results else {"failures": failures}
        print(json.dumps(doc, indent=2, default=str))
    else:
        for r in results:
            v = r["validation"]
            tail = f"{r['samples']:,} samples, {r['rules']} rules, {r['seconds']:.1f} s"
            if not v.get("samples"):
                print(
                    f"{r['model']} v{r['version']}: trained on all of the range, no held-out "
                    f"validation (--holdout 0), so no validation error; {tail}"
                )
                continue
            print(
                f"{r['model']} v{r['version']}: held-out RMSE {v['rmse_pct']:.2f} % of span, "
                f"MAE {v['mae_pct']:.2f} %, coverage {v['coverage']:.1%}; {tail}"
            )
            print(f"  {heldout_note(r)}")
            if line := describe(r.get(KEY)):
                print(f"  {line}")
            if note := levels_note(v):
                print(f"  {note}")
            if note := coverage_note(v):
                print(f"  {note}")
        for f in failures:
            print(f"{f['rulebase']}: training failed: {f['error']}", file=sys.stderr)
    if not failures:
        return 0
    # bad input (a missing or broken file, unknown tags, a range without data) is 2, like
    # every command's; a model that failed for another reason is the job failing (1)
    return 2 if any(f.get("bad_input") for f in failures) else 1


def _stderr_console():
    """rich's console on stderr where it may be a terminal, else None (no progress bar).
    rich says "terminal" only for a tty or when ``TTY_COMPATIBLE`` or ``FORCE_COLOR`` ask
    for it, so elsewhere (a cron job, a pipe, a benchmark) rich is not imported: its import
    was 0.07 s of a ``diag train`` process's CPU time (issue 37)."""
    try:
        tty = sys.stderr.isatty()
    except (AttributeError, ValueError):
        tty = False
    if not (tty or os.environ.get("TTY_COMPATIBLE") or os.environ.get("FORCE_COLOR")):
        return None
    from rich.console import Console

    return Console(stderr=True)


class _progress:
    """A rich progress bar on a terminal, nothing otherwise."""

    def __init__(self, console, name: str):
        self.console, self.name = console, name
        self.bar = None

    def __enter__(self):
        if self.console is None or not self.console.is_terminal:
            return None
        from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

        self.bar = Progress(
            TextColumn(f"training {self.name}"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total} chunks"),
            TimeRemainingColumn(),
            console=self.console,
            transient=True,
        )
        self.bar.start()
        task = self.bar.add_task(self.name, total=None)

        def cb(done: int, total: int) -> None:
            self.bar.update(task, completed=done, total=total)

        return cb

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.stop()
        return False


def cmd_experiments(args) -> int:
    from rich.markup import escape
    from rich.table import Table

    path = resolve(args.name, args.rulebases)
    name = RuleBase.load(path).name if path.exists() else args.name
    df = experiments(args.db, name)
    if not path.exists() and not len(df):
        raise UserError(f"no model {args.name!r}: {path} does not exist and no experiments")
    cols = [
        c
        for c in (
            "version",
            "created_at",
            "inputs",
            "rmse_pct",
            "hgb_baseline_rmse_pct",
            "mae_pct",
            "hgb_baseline_mae_pct",
            "coverage",
            "samples",
            "data_from",
            "data_to",
        )
        if c in df.columns
    ]
    if args.json:
        rows = []
        for rec in df[cols].to_dict("records"):
            rows.append({k: to_jsonable(v) for k, v in rec.items()})
        kept = [str(p) for p in backups(path)]
        print(json.dumps({"model": name, "experiments": rows, "backups": kept}, indent=2))
        return 0
    kept = [str(p) for p in backups(path)]
    if not len(df):
        print(f"no experiments recorded for {name}: run diag train {name}")
        for b in kept:
            print(f"earlier file kept: {b}")
        return 0
    t = Table(title=escape(f"experiments of {name}"))
    for c in (
        "version",
        "created",
        "inputs",
        "held-out RMSE %",
        "HGB baseline RMSE %",
        "MAE %",
        "coverage",
    ):
        t.add_column(c)
    for rec in df.to_dict("records"):
        t.add_row(
            str(rec.get("version")),
            str(rec.get("created_at"))[:19],
            escape(", ".join(rec.get("inputs") or [])),
            _fmt(rec.get("rmse_pct"), ".2f"),
            _fmt(rec.get("hgb_baseline_rmse_pct"), ".2f"),
            _fmt(rec.get("mae_pct"), ".2f"),
            _fmt(rec.get("coverage"), ".1%") + (" ⚠" if coverage_note(rec) else ""),
        )
    table_console().print(t)
    print(
        "HGB baseline: scikit-learn's HistGradientBoostingRegressor on the version's inputs, "
        "trained and scored on the same rows as its held-out RMSE (blank: not computed, "
        "--no-baseline or --holdout 0, or a version recorded before it was)"
    )
    for b in kept:
        print(f"earlier file kept: {b} (before an edit of the inputs)")
    return 0


def _fmt(v, spec: str) -> str:
    try:
        return format(float(v), spec)
    except (TypeError, ValueError):
        return ""
