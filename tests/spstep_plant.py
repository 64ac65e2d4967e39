"""A heater with a cascade (issue 34, items 5/6: an operator's set-point step is no alarm).
Written once from the physics below for the settle guard's tests; not tuned for.

- ``INLET_T`` inlet temperature, °C (slow wander)
- ``SUPPLY_P`` heating medium supply pressure, bar (slow wander)
- ``HEAT_TGT`` the outlet temperature's set-point, °C (an operator steps it every 3–8 h
  between 60, 65 and 70 °C)
- ``TEMP`` outlet temperature, °C: first order with dead time in the heating flow,
  ``τ dT/dt = INLET_T + G · FLOW(t − θ) − T``, τ = 600 s, θ = 60 s, G = 2 °C per m³/h
- ``FLOW_SP`` the outer PI's output (TEMP at HEAT_TGT): the inner loop's set-point, a
  cascade set-point that moves every sample
- ``FLOW`` heating flow, m³/h (follows the valve in 10 s), held at FLOW_SP by the inner PI
- ``VALVE`` the inner PI's output, %

Faults from ``onset_s``: ``temp_bias`` the outlet sensor reads ``size`` °C high (default 1.5);
``flow_bias`` the flow meter reads ``size`` m³/h high (default 1.5; the inner loop holds the
reading, the true flow falls, the outer loop raises the cascade set-point);
``fouling`` the heater's gain G falls by ``size`` (default 25 %): the outer loop raises the
cascade set-point FLOW_SP to hold TEMP.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

DT = 5.0
LOOPS = ("TEMP=HEAT_TGT:FLOW_SP", "FLOW=FLOW_SP:VALVE")
#: the outlet temperatures an operator chooses, °C
SET_POINTS = (60.0, 65.0, 70.0)
#: a training window's steps: each set-point once, three steps in two days
TRAIN_STEPS = [(6 * 3600.0, 60.0), (20 * 3600.0, 70.0), (34 * 3600.0, 65.0)]
TAGS = ("INLET_T", "SUPPLY_P", "HEAT_TGT", "TEMP", "FLOW_SP", "FLOW", "VALVE")


def simulate(
    days: float,
    seed: int,
    fault: str | None = None,
    onset_s: float | None = None,
    size: float | None = None,
    steps: list[tuple[float, float]] | None = None,
) -> pd.DataFrame:
    """5 s samples over ``days``; ``steps``: (seconds, value) of HEAT_TGT instead of the
    seed's operator (who steps it every 3–8 h to another of :data:`SET_POINTS`)."""
    rng = np.random.default_rng(seed)
    n = int(days * 86400 / DT)
    sp = np.empty(n)
    if steps is None:
        i, v = int(3600 / DT), 65.0
        sp[:i] = v
        while i < n:
            k = int(rng.uniform(3, 8) * 3600 / DT)
            v = float(rng.choice([x for x in SET_POINTS if x != v]))
            sp[i : i + k] = v
            i += k
    else:
        sp[:] = 65.0
        for t, v in steps:
            sp[int(t / DT) :] = v
    on = n if onset_s is None or fault is None else int(onset_s / DT)
    th, delay, gain = 600.0, int(60.0 / DT), 2.0
    temp, flow, integ_o, integ_i = 65.0, 22.5, 22.5, 45.0
    inlet, supply = 20.0, 5.0
    hist = np.full(delay + 1, 22.5)
    out = np.empty((n, 7))
    a_f = 1.0 - np.exp(-DT / 10.0)
    kc, ti = 0.8, 600.0  # outer PI (IMC, λ = 300 s)
    kci, tii = 0.8, 20.0  # inner PI
    for i in range(n):
        inlet = 20.0 + 0.9995 * (inlet - 20.0) + 0.01 * rng.standard_normal()
        supply = 5.0 + 0.999 * (supply - 5.0) + 0.01 * rng.standard_normal()
        g = gain
        bias = f_bias = 0.0
        if i >= on:
            if fault == "fouling":
                g = gain * (1.0 - (0.25 if size is None else size))
            elif fault == "temp_bias":
                bias = 1.5 if size is None else size
            elif fault == "flow_bias":
                f_bias = 1.5 if size is None else size
        hist = np.roll(hist, 1)
        hist[0] = flow
        temp += (inlet + g * hist[delay] - temp) * (1.0 - np.exp(-DT / th))
        t_meas = temp + bias + 0.05 * rng.standard_normal()
        e = sp[i] - t_meas
        integ_o = float(np.clip(integ_o + kc * e * DT / ti, 0.0, 50.0))
        fsp = float(np.clip(kc * e + integ_o, 0.0, 50.0))
        f_meas = flow + f_bias + 0.1 * rng.standard_normal()
        ei = fsp - f_meas
        integ_i = float(np.clip(integ_i + kci * ei * DT / tii, 0.0, 100.0))
        valve = float(np.clip(kci * ei + integ_i, 0.0, 100.0))
        flow += (0.5 * valve * np.sqrt(supply / 5.0) - flow) * a_f
        out[i] = (
            inlet + 0.05 * rng.standard_normal(),
            supply + 0.01 * rng.standard_normal(),
            sp[i],
            t_meas,
            fsp,
            f_meas,
            valve,
        )
    idx = pd.date_range("2026-03-02", periods=n, freq=f"{int(DT)}s", tz="UTC")
    return pd.DataFrame(out, index=idx, columns=list(TAGS))


def at_period(frame: pd.DataFrame, period_s: int) -> pd.DataFrame:
    """The historian's means over ``period_s`` (5 s: as simulated)."""
    if period_s <= DT:
        return frame
    return frame.resample(f"{period_s}s").mean()


def step_rows(frame: pd.DataFrame) -> np.ndarray:
    """The rows where HEAT_TGT moves (the operator's steps; a mean may split one in two)."""
    d = np.abs(np.diff(frame["HEAT_TGT"].to_numpy()))
    rows = np.flatnonzero(d > 0.5) + 1
    return rows[np.r_[True, np.diff(rows) > 2]] if rows.size else rows


def how_to_table() -> str:
    """The heater's rows in docs/how-to/unit-loops.md ("An operator's set-point step: the
    settle"), as markdown: at 5 s (built on 2 days) and 2 min (6 days), each window with
    :data:`TRAIN_STEPS`, loops declared, ``far=0.01``; judged on seeds 2 and 3 (1 day at 5 s,
    2 days at 2 min), main being the same unit without its guard (no ``settle_max_s``), and a
    flow meter bias 2 min after a step (seed 4). Run: ``python -m tests.spstep_plant``."""
    import tempfile

    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.build import build_unit
    from diag_plugin.unitbuild.loops import parse_loop

    rows = []
    for period, days, judge in ((5, 2.0, 1.0), (120, 6.0, 2.0)):
        folder = tempfile.mkdtemp()
        res = build_unit("heater", at_period(simulate(days, 1, steps=TRAIN_STEPS), period),
                         folder=folder, period=f"{period}s", far=0.01, force=True,
                         loops=[parse_loop(lp) for lp in LOOPS])  # fmt: skip
        unit, plain = Unit.load(res.path, folder), Unit.load(res.path, folder)
        plain.settle = None
        settle = unit.ev["settle_max_s"]
        for seed in (2, 3):
            x = at_period(simulate(judge, seed), period)
            st0 = plain.reset().evaluate(x).status.to_numpy()
            st = unit.reset().evaluate(x).status.to_numpy()
            a0, a = (st0 == 1) | (st0 == 3), (st == 1) | (st == 3)
            ep = [int((v & ~np.r_[False, v[:-1]]).sum()) for v in (a0, a)]
            moved = ((st0 == 0) & (st == 2)).mean()
            rows.append(f"| {period} s | {settle:.0f} s | seed {seed}: {len(step_rows(x))} steps "
                        f"| {ep[0]} | {ep[1]} | {moved:.1%} |")  # fmt: skip
        steps = [(3 * 3600.0, 60.0), (8 * 3600.0, 70.0)]
        onset = steps[1][0] + 120.0
        x = at_period(simulate(0.6, 4, "flow_bias", onset, steps=steps), period)
        st = unit.reset().evaluate(x).status.to_numpy()
        t = (x.index - x.index[0]).total_seconds().to_numpy()
        after, late = t >= onset, t >= steps[1][0] + settle
        rows.append(f"| {period} s | {settle:.0f} s | flow meter +1.5 m³/h 2 min after a step "
                    f"| FAILURE from {t[after & (st == 1)][0] - steps[1][0]:.0f} s after the "
                    f"step | {(st[late] == 1).mean():.1%} after settle_max_s, "
                    f"{(st[after] == 1).mean():.1%} after the onset | |")  # fmt: skip
    return "\n".join(rows)


if __name__ == "__main__":
    print(how_to_table())
