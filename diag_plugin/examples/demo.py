"""``diag demo``: the main job on the embedded default, end to end (``make run``).

Simulates weeks of the servomotor–valve assembly, stores them in a SQLite
historian, trains the paper's Model B ``F = f(CV[k-1])`` (Kościelny et al.,
eq. 9), compares it with the measurements, asks ``explain`` for the missing
effect, adds it, retrains and shows the error falling in the experiment log.
Everything goes to ``--workdir`` (default ``out/demo``), never to the user's
own historian or rule bases. The arguments are in :mod:`diag_plugin.examples.cli`.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path


def cmd_demo(args) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from diag_plugin.simulate.valve import TAGS, simulate_valve
    from diag_plugin.training.chunked import DEFAULT_CHUNK
    from diag_plugin.training.jobs import train_one
    from diag_plugin.workbench.compare import compare
    from diag_plugin.workbench.explain import explain
    from diag_plugin.workbench.model_edit import add_input, new_model
    from historian.access import experiments, open_data
    from historian.store import Historian

    con = Console()
    work = Path(args.workdir)
    if work.exists():
        shutil.rmtree(work)
    (work / "rulebases").mkdir(parents=True)
    url = f"sqlite:///{work / 'diag.db'}"

    t = time.perf_counter()
    frame = simulate_valve(args.days, seed=args.seed)
    con.print(
        f"[bold]1. simulate[/] {args.days:g} days of the valve assembly at 10 s: "
        f"{len(frame):,} samples × {len(frame.columns)} tags ({time.perf_counter() - t:.1f} s)"
    )
    t = time.perf_counter()
    with Historian.open(url) as h:
        for name, meta in TAGS.items():
            if name in frame.columns:
                h.ensure_tag(
                    name,
                    unit=meta.unit,
                    lo=meta.lo,
                    hi=meta.hi,
                    description=meta.description,
                    source="simulator",
                )
        n = h.write_samples(frame)
    con.print(f"[bold]2. historian[/] {n:,} samples into {url} ({time.perf_counter() - t:.1f} s)")

    data, info = open_data(url, None, None, None, "10s")
    desc = "Model B of the servomotor-valve assembly (Kościelny et al., eq. 9)"
    rb = new_model(
        work / "rulebases" / "valve.toml",
        "valve",
        "F[k]",
        ["CV[k-1]"],
        frame=data,
        tag_info=info,
        description=desc,
    )
    r = train_one(rb.path, url, chunk=DEFAULT_CHUNK)
    con.print(
        f"[bold]3. train[/] {r['model']} F = f(CV\\[k-1]): held-out RMSE "
        f"{r['validation']['rmse_pct']:.2f} % of span, {r['rules']} rules ({r['seconds']:.1f} s)"
    )
    from diag_plugin.rulebase.document import RuleBase

    rb = RuleBase.load(rb.path)
    c = compare(rb, data)
    worst = c.as_dict()["worst_periods"][0]
    con.print(
        f"[bold]4. compare[/] RMSE {c.metrics['rmse_pct']:.2f} %, coverage "
        f"{c.metrics['coverage']:.1%}; worst window {worst['start'][:16]} "
        f"({worst['rmse_pct']:.1f} %); the residual follows "
        f"{c.tags['tag'].iloc[0] if len(c.tags) else '—'} most"
    )
    e = explain(rb, data, tag_info=info, top=5)
    tab = Table(title="5. explain: candidate missing effects, best first")
    tab.add_column("effect")
    tab.add_column("command")
    for cand in e.candidates[:5]:
        tab.add_row(escape(cand.effect), escape(cand.command))
    con.print(tab)
    best = e.candidates[0]
    rb = add_input(rb, best.input, frame=data, tag_info=info, replace=best.replaces)
    r = train_one(rb.path, url, chunk=DEFAULT_CHUNK)
    con.print(
        f"[bold]6. add-input + train[/] {escape(best.input)}: held-out RMSE "
        f"{r['validation']['rmse_pct']:.2f} % of span"
    )
    ex = experiments(url, "valve")
    tab = Table(title="7. experiments: the error falls")
    for col in ("version", "inputs", "held-out RMSE % of span"):
        tab.add_column(col)
    for rec in ex.to_dict("records"):
        tab.add_row(str(rec["version"]), escape(", ".join(rec["inputs"])), f"{rec['rmse_pct']:.2f}")
    con.print(tab)
    from diag_plugin.workbench.report import write_report

    rb = RuleBase.load(rb.path)
    html = write_report(
        work / "valve.html", rb, compare(rb, data), explain(rb, data, tag_info=info), ex
    )
    con.print(f"[bold]8. report[/] {html} (open it in a browser; works offline)")
    con.print(
        f"files: {work}/rulebases/valve.toml, database {url}. Try: diag --db {url} "
        f"--rulebases {work}/rulebases rules show valve",
        markup=False,
    )
    return 0
