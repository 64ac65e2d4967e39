"""Result pages the benchmark commands write (docs/results/): the provenance every page
starts with, and the DAMADICS page of ``diag benchmark --page FILE``.

A page is generated, never hand-edited: it names the command that wrote it, the date, the
commit (and whether the tree had uncommitted changes) and the seeds, so that a figure quoted
anywhere can be traced to a run and run again.
"""

from __future__ import annotations

import datetime as _dt
import subprocess
from pathlib import Path
from statistics import median
from typing import Any


def commit() -> str:
    """The checkout's short commit, marked when tracked files have uncommitted changes;
    the generated pages under ``docs/results/`` are not counted (several benchmarks run at
    once each rewrite their own page; none reads another's)."""
    try:
        p = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                           text=True, timeout=10, cwd=Path(__file__).parent)  # fmt: skip
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--",
                                ":(top)", ":(top,exclude)docs/results"],
                               capture_output=True, text=True, timeout=10,
                               cwd=Path(__file__).parent).stdout.strip()  # fmt: skip
        return p.stdout.strip() + (" (with uncommitted changes)" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def provenance(command: str, started: str | None = None) -> list[str]:
    """The first lines of every generated page: the note, the command, the date, the commit
    (``started``: the commit taken when the run began, else now)."""
    return [
        "*Generated — do not edit by hand; run the command again.*",
        "",
        f"- command: `{command}`",
        f"- date: {_dt.datetime.now(_dt.UTC).strftime('%Y-%m-%d %H:%M UTC')}",
        f"- commit: {started or commit()}",
    ]


def write(text: str, path: str | Path) -> Path:
    """Write a page (folders made)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text, encoding="utf-8")
    return p


def _count(rows: list[dict], key: str) -> str:
    vals = [r[key] for r in rows if r[key] is not None]
    return f"{sum(bool(v) for v in vals)}/{len(vals)}" if vals else "—"


def _median(rows: list[dict], key: str, spec: str) -> str:
    vals = [r[key] for r in rows if r[key] is not None]
    return format(median(vals), spec) if vals else "—"


def _mean(rows: list[dict], key: str, spec: str) -> str:
    vals = [r[key] for r in rows if r[key] is not None]
    return format(sum(vals) / len(vals), spec) if vals else "—"


def render_damadics(out: dict[str, Any], command: str, started: str | None = None) -> str:
    """The DAMADICS result (:func:`diag_plugin.bench.damadics.run_benchmark`) as markdown: one
    row per fault, mode and strength over the seeds (detected and isolated k of n, median
    detection time, mean true detection rate and unknown share), then the summary."""
    st, s = out["setup"], out["summary"]
    seeds = ", ".join(map(str, st["seeds"]))
    lines = [
        f"# DAMADICS faults against the unit {out['unit']}",
        "",
        *provenance(command, started),
        f"- unit: `{out['unit']}`; seeds {seeds}; "
        + ("one strength per fault (--quick)" if st["quick"] else "every strength"),
        f"- each scenario: {st['warmup_s'] / 3600:g} h of warm-up, {st['fault_free_s'] / 3600:g} h"
        f" fault-free, then the fault over a {st['horizon_s'] / 3600:g} h horizon at "
        f"{st['period_s']:g} s (incipient: a {st['incipient_ramp_s'] / 3600:g} h ramp to the "
        "strength)",
        "- indexes of the Benchmark Definition v1.0 App. II (`diag_plugin/bench/damadics.py`): "
        "*detected* = the detection decision holds over the last tenth of the horizon; "
        "*unknown* = share of the horizon with no symptom and some test unknown; *isolated* = "
        "the isolated faults include the fault's column",
        "",
        "| fault | mode | fs | detected | t_dt s (median) | r_td | unknown | isolated | column |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    groups: dict[tuple, list[dict]] = {}
    for r in out["scenarios"]:
        groups.setdefault((r["fault"], r["mode"], r["strength"]), []).append(r)
    for (fault, mode, fs), rows in groups.items():
        col = rows[0]["unit_fault"]
        cells = [fault, mode, f"{fs:g}", _count(rows, "detected"),
                 _median(rows, "detection_time_s", ".0f"),
                 _mean(rows, "true_detection_rate", ".2f"), _mean(rows, "unknown_rate", ".2f"),
                 _count(rows, "isolated") if col else "—", col or "—"]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    lit = s["literature_detectable_share"]
    lines += [
        "",
        "## Summary",
        "",
        f"- detected {s['scenarios_detected']} of {s['scenarios']} scenarios; faults detected "
        f"at some strength: {', '.join(s['faults_detected']) or '—'}; missed: "
        f"{', '.join(s['faults_missed']) or '—'}",
        f"- of the {s['literature_detectable']} faults the literature detects: "
        f"{s['literature_detectable_detected']}" + ("" if lit is None else f" ({lit:.0%})"),
        f"- false detection rate before the onsets: mean {s['mean_false_detection_rate']:.4f}, "
        f"max {s['max_false_detection_rate']:.4f}; unknown before the onsets "
        f"{s['mean_unknown_rate_before']:.1%}",
        f"- isolated {s['scenarios_isolated']} of the {s['scenarios_with_isolation']} scenarios "
        f"with a matrix column: {', '.join(s['faults_isolated']) or '—'}",
        "",
    ]
    return "\n".join(lines)
