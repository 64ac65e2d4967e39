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
    names = list(out["baselines"]["summary"]) if out.get("baselines") else []
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
        *_baseline_head(out),
        "",
        "| fault | mode | fs | detected | t_dt s (median) | r_td | unknown | isolated | column |"
        + "".join(f" {m} detected | {m} t_dt s | {m} r_td |" for m in names),
        "|---|---|---|---|---|---|---|---|---|" + "---|" * (3 * len(names)),
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
        for m in names:
            b = [r["baselines"][m] for r in rows]
            cells += [_count(b, "detected"), _median(b, "detection_time_s", ".0f"),
                      _mean(b, "true_detection_rate", ".2f")]  # fmt: skip
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
    ]
    if names:
        mean = {"unit": _mean(out["scenarios"], "true_detection_rate", ".2f")}
        for m in names:
            mean[m] = _mean([r["baselines"][m] for r in out["scenarios"]], "true_detection_rate",
                            ".2f")  # fmt: skip
        lines.append(
            "- mean r_td over the scenarios (share of the horizon after the onset in alarm) at "
            "the unit's false-alarm rate: " + ", ".join(f"{k} {v}" for k, v in mean.items())
        )
    for m in names:
        b = out["baselines"]["summary"][m]
        lit = b["literature_detectable_share"]
        lines.append(
            f"- {m} at the unit's rate: detected {b['scenarios_detected']} of {b['scenarios']} "
            f"scenarios; faults detected at some strength: {', '.join(b['faults_detected']) or '—'}"
            f"; of the {b['literature_detectable']} the literature detects "
            f"{b['literature_detectable_detected']}"
            + ("" if lit is None else f" ({lit:.0%})")
            + f"; false detection rate before the onsets: mean "
            f"{b['mean_false_detection_rate']:.4f}, max {b['max_false_detection_rate']:.4f}"
        )
    return "\n".join([*lines, ""])


def _baseline_head(out: dict[str, Any]) -> list[str]:
    """The page's account of PCA and DPCA beside the unit: what they learned from, the
    calibration runs their limits were matched on and the rates reached there."""
    b = out.get("baselines")
    if not b:
        return []
    tr, cal = b["train"], b["calibration"]
    n, k = cal["samples"], cal["unit"]["alarms"]
    reached = ", ".join(
        f"{m} {cal[m]['alarms']} ({cal[m]['share']:.4%}, {cal[m]['per_hour']:.3g}/h; "
        f"{cal[m]['next_alarms']} at its next lower limit)"
        for m in b["summary"]
    )
    comps = ", ".join(f"{m} {c}" for m, c in tr["components"].items())
    dagger = "" if all(b["supported"].values()) else (
        " † under 5 alarm samples expected: the calibration resolves the rate only to "
        f"1/{n} of its samples"
    )  # fmt: skip
    return [
        f"- PCA and DPCA ({tr['lags']['DPCA']} lags) beside the unit, T² + Q on its tags "
        f"({', '.join(tr['tags'])}; components to 90 % of the variance: {comps}), each "
        f"statistic after the unit's on/off delays ({b['delays'][0]}/{b['delays'][1]} samples), "
        "scored as on the `--match-far` pages (`diag_plugin/bench/publicbench.py`)",
        f"- runs and what each is for: **learn** — the unit from the example build's run "
        f"(`simulate_valve` seed {tr['seed']}, {tr['unit_days']:g} days, "
        "`diag_plugin/examples/build.py`), "
        f"PCA and DPCA from its first {tr['days']:g} days ({tr['samples']} samples); "
        f"**calibration** — fault-free seeds {', '.join(map(str, cal['seeds']))}, "
        f"{cal['days']:g} days each after the same warm-up, which no method learned from: the "
        f"unit at its own thresholds alarms on {k} of their {n} samples "
        f"({cal['unit']['share']:.4%}, {cal['unit']['per_hour']:.3g} episodes/h) and each "
        f"baseline's limit is the smallest with at most {k}: {reached}{dagger}; **scoring** — "
        "the scenarios' seeds: their fault-free hours before the onsets are the held-out "
        "check of the matched rate (*false detection rate* in the summary)",
        "- PCA and DPCA have no fault matrix: detection indexes only, as the unit's "
        "(*detected*, median *t_dt*, mean *r_td*)",
    ]
