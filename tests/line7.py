"""A 7-tag line built by hand (issue 34): a feed pipe with a flow loop into a tank drained
through a manual valve. Not a simulator of the package and not tuned for: written once from
the physics below, then the unit was built on it as a user would.

Tags (names follow no convention, so the loop must be declared):

- ``SUPPLY_P`` supply pressure, bar (slow random swings and a daily cycle)
- ``FEED_TARGET`` the feed flow set-point, m³/h (operators move it every few hours)
- ``FEED_FLOW`` the feed flow meter, m³/h (the loop holds it at ``FEED_TARGET``)
- ``VALVE_A`` the flow controller's output, % (PI; the valve follows it)
- ``TANK_LEVEL`` level, m (``A dL/dt = F_in − F_out``)
- ``HAND_VALVE`` the manual drain valve, % (operators adjust it now and then)
- ``OUT_FLOW`` outlet flow, m³/h (``k · HV/100 · √L``)

Faults (from ``onset`` on): ``flow_bias`` the flow meter reads +0.8 m³/h (the loop compensates:
the true flow falls), ``stiction`` the valve moves only when the output is 4 % away from its
position, ``pressure_drift`` the pressure transmitter drifts +0.6 bar a day, ``manual_moved``
the manual valve set to 78 %, a position it never had.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

PERIOD_S = 15.0
TAGS = ("SUPPLY_P", "FEED_TARGET", "FEED_FLOW", "VALVE_A", "TANK_LEVEL", "HAND_VALVE", "OUT_FLOW")
LOOP = "FEED_FLOW=FEED_TARGET:VALVE_A"
#: the tag at fault of each fault, as an operator would want it named
AT_FAULT = {"flow_bias": "FEED_FLOW", "stiction": "VALVE_A", "pressure_drift": "SUPPLY_P"}


def simulate(
    days: float, seed: int, fault: str | None = None, onset_days: float = 1.0
) -> pd.DataFrame:
    """The line's 15 s samples over ``days`` (``fault`` from ``onset_days`` on)."""
    rng = np.random.default_rng(seed)
    n = int(days * 86400 / PERIOD_S)
    onset = int(onset_days * 86400 / PERIOD_S)
    dt = PERIOD_S / 3600.0  # hours
    t = np.arange(n) * dt
    # supply pressure: AR(1) swings plus a daily cycle
    p = np.empty(n)
    x = 0.0
    for i in range(n):
        x = 0.999 * x + 0.02 * rng.standard_normal()
        p[i] = 5.0 + x + 0.3 * np.sin(2 * np.pi * t[i] / 24.0)
    # operators: the set-point every 2–6 h, the manual valve every 6–18 h
    sp = operator_steps(rng, n, PERIOD_S, (2, 6), 10.0, 1.0, (8.0, 12.0))
    hv = np.empty(n)
    i, h = 0, 50.0
    while i < n:
        k = int(rng.uniform(6, 18) * 3600 / PERIOD_S)
        h = float(np.clip(h + rng.normal(0, 4.0), 40.0, 60.0))
        hv[i : i + k] = round(h)
        i += k
    if fault == "manual_moved":
        hv[onset:] = 78.0
    cv, k_out, area = 10.0, 14.1, 5.0
    kp, ti = 2.0, 60.0 / 3600.0  # %/(m³/h), h
    flow, pos, level, integ = 10.0, 50.0, 2.0, 50.0
    out = np.empty((n, 7))
    for i in range(n):
        faulty = fault is not None and i >= onset
        drift = 0.6 * (t[i] - t[onset]) / 24.0 if faulty and fault == "pressure_drift" else 0.0
        meas_p = p[i] + drift
        bias = 0.8 if faulty and fault == "flow_bias" else 0.0
        meas_f = flow + 0.05 * rng.standard_normal() + bias
        e = sp[i] - meas_f
        op, integ, pos = pi_valve(e, integ, pos, kp, dt, ti,
                                  4.0 if faulty and fault == "stiction" else None)  # fmt: skip
        target = cv * pos / 100.0 * np.sqrt(max(p[i] - 1.0, 0.0))
        flow += (target - flow) * (1 - np.exp(-PERIOD_S / 30.0))
        f_out = k_out * hv[i] / 100.0 * np.sqrt(max(level, 0.0))
        level = max(level + (flow - f_out) * dt / area, 0.0)
        out[i] = (
            meas_p + 0.02 * rng.standard_normal(),
            sp[i],
            meas_f,
            op,
            level + 0.005 * rng.standard_normal(),
            hv[i],
            f_out + 0.05 * rng.standard_normal(),
        )
    idx = pd.date_range("2026-03-02", periods=n, freq=f"{int(PERIOD_S)}s", tz="UTC")
    return pd.DataFrame(out, index=idx, columns=list(TAGS))


def operator_steps(
    rng: np.random.Generator,
    n: int,
    period_s: float,
    hours: tuple[float, float],
    start: float,
    sd: float,
    bounds: tuple[float, float],
) -> np.ndarray:
    """``n`` samples of a set-point an operator moves every ``hours`` (uniform) by a normal
    step of ``sd`` within ``bounds``, entered to one decimal."""
    out = np.empty(n)
    i, v = 0, start
    while i < n:
        k = int(rng.uniform(*hours) * 3600 / period_s)
        v = float(np.clip(v + rng.normal(0, sd), *bounds))
        out[i : i + k] = round(v, 1)
        i += k
    return out


def tags_frame(rows: list[tuple[str, str, str, str, str]]) -> pd.DataFrame:
    """A tags CSV of ``(name, unit, description, loop, role)`` rows."""
    return pd.DataFrame(rows, columns=["name", "unit", "description", "loop", "role"])


def pi_valve(
    e: float, integ: float, pos: float, kp: float, dt: float, ti: float, stick: float | None
) -> tuple[float, float, float]:
    """One step of a PI controller (error ``e``, output and integral clipped to 0–100 %) and
    its valve: the valve's position follows the output, or, sticking (``stick`` %), moves
    only once the output is more than that away from it. Returns (output, integral,
    position)."""
    integ = float(np.clip(integ + kp * e * dt / ti, 0.0, 100.0))
    op = float(np.clip(kp * e + integ, 0.0, 100.0))
    if stick is None or abs(op - pos) > stick:
        pos = op
    return op, integ, pos


def tags_csv() -> pd.DataFrame:
    """The line's tags CSV, the loop declared in its ``loop`` and ``role`` columns."""
    rows = [
        ("SUPPLY_P", "bar", "supply pressure", "", ""),
        ("FEED_TARGET", "m3/h", "feed flow target", "feed", "sp"),
        ("FEED_FLOW", "m3/h", "feed flow meter", "feed", "pv"),
        ("VALVE_A", "%", "feed valve output", "feed", "out"),
        ("TANK_LEVEL", "m", "tank level", "", ""),
        ("HAND_VALVE", "%", "manual drain valve", "", ""),
        ("OUT_FLOW", "m3/h", "outlet flow", "", ""),
    ]
    return tags_frame(rows)


def cli_build(folder, days: float = 6.0) -> tuple[list[str], str]:
    """The line's unit built as a user builds it: ``simulate(days, 1)`` and the tags CSV
    imported into SQLite under ``folder`` (a CSV file, ``diag import --tags``), then ``diag
    unit build line --loops-from tags.csv --far 0.01 --json`` over the whole run. Returns the
    global arguments (``--db``, ``--rulebases``) and the build's JSON text."""
    from pathlib import Path

    from tests.test_any_plant_tour import diag, fmt, import_csv

    tmp = Path(folder)
    g = ["--db", f"sqlite:///{tmp / 'h.db'}", "--rulebases", str(tmp / "rb")]
    frame = simulate(days, seed=1)
    tags_csv().to_csv(tmp / "tags.csv", index=False)
    import_csv(g, frame, tmp / "line.csv", tags=tmp / "tags.csv")
    t0, t1 = frame.index[0], frame.index[-1] + pd.Timedelta(seconds=PERIOD_S)
    rc, text = diag(g, "unit", "build", "line", "--from", fmt(t0), "--to", fmt(t1),
                    "--loops-from", str(tmp / "tags.csv"), "--far", "0.01", "--json")  # fmt: skip
    assert rc == 0, text
    return g, text


def how_to_table(seed: int = 101, train_days: float = 6.0) -> str:
    """The 7-tag line's table in docs/how-to/unit-loops.md, as markdown rows: the unit built
    through the Python API (``build_unit(…, loops=[parse_loop(LOOP)], far=0.01)`` on
    ``simulate(train_days, 1)``), each run ``simulate(2, seed, fault)``, the fault from day 1.
    Detection and alarm episodes (the most in any 10 minutes) are counted from day 1 on;
    *named* is the held top 1's share of the alarm samples from day 1 on, the faulted tag's
    place among the tags most often in the top three. Run: ``python -m tests.line7``."""
    import tempfile

    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.status import NE107
    from diag_plugin.unitbuild.build import CHATTER_WINDOW_S, build_unit
    from diag_plugin.unitbuild.loops import parse_loop

    folder = tempfile.mkdtemp()
    res = build_unit("line", simulate(train_days, 1), folder=folder, period=f"{int(PERIOD_S)}s",
                     loops=[parse_loop(LOOP)], far=0.01, force=True)  # fmt: skip
    unit = Unit.load(res.path, folder)
    onset, w = int(86400 / PERIOD_S), int(CHATTER_WINDOW_S / PERIOD_S)
    rows = []
    for fault in (None, *AT_FAULT, "manual_moved"):
        d = unit.reset().evaluate(simulate(2.0, seed, fault))
        alarm = d.detected.to_numpy() == 1
        after = alarm[onset:]
        ep = np.flatnonzero(after & ~np.r_[False, after[:-1]])
        worst = max(((ep >= e) & (ep < e + w)).sum() for e in ep) if ep.size else 0
        check = (d.status.to_numpy()[onset:] == int(NE107.CHECK_FUNCTION)).mean()
        top = d.top_tags.iloc[onset:]
        first = top["top1"][after & (top["top1"] != "").to_numpy()]
        share = first.value_counts(normalize=True)
        names = pd.concat([top[f"top{i}"] for i in (1, 2, 3)])
        ranked = names[names != ""].value_counts().index[:3].tolist()
        tag = AT_FAULT.get(fault or "")
        held = ", ".join(
            f"{'**' + t + '**' if t == tag else t} {v:.0%}" for t, v in share[share >= 0.05].items()
        )
        place = (
            f"; **{tag}** {ranked.index(tag) + 1} of the top 3 {ranked}"
            if tag in ranked
            else (f"; {tag} not in the top 3 {ranked}" if tag else "")
        )
        det = f"{after.mean():.1%}" + (
            f" ({alarm[:onset].mean():.1%} before day 1)" if fault is None else ""
        )
        if check:
            det += f" (CHECK_FUNCTION {check:.0%})"
        rows.append(
            f"| {fault or 'fault-free'} | {det} | {ep.size} ({worst}) | {held or '—'}{place} |"
        )
    return "\n".join(rows)


if __name__ == "__main__":
    print(how_to_table())
