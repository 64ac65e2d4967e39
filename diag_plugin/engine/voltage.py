"""The seed's sensor voltages (Laukonen et al., captions of Figs. 3–7).

The seed's engine signals are the sensors' voltages: Figs. 3–7 plot them in volts, and each
caption gives the calibration from the voltage ``x`` to the physical value:

* m_a = −4.2073·10⁻⁴ + 5.2296·10⁻³ x + 1.3396·10⁻³ x² + 2.1860·10⁻³ x³  (lbm/s, Fig. 3)
* ω = −1990.5 + 1044.7 x  (rev/min, Fig. 4)
* α = −82.905 + 124.70 x − 46.241 x² + 9.1047 x³ − 0.67342 x⁴  (%, Fig. 5)
* T_L = −2.5384 + 0.99857 x  (lb·ft, Fig. 6)
* m_f = 5.3·10⁻⁶ (−1.2015 + 3.3304 x)  (lbm, Fig. 7; per injection)

A calibration fault that multiplies such a voltage by 1.2 is not 1.2 × the physical value:
the offsets make it ``1.2 ω + 0.2 · 1990.5 rpm`` for ω (+558 rpm at 800 rpm, where 1.2 ω
is +160). This module maps the simulator's columns (rpm, g/s, %, mg/rev, N·m) to those
voltages and back. Two choices of ours: m_f is the simulator's fuel per revolution divided by
3 (a V-6 four-stroke injects three times per revolution) for the seed's per-injection mass,
and ω_dy, whose calibration the seed does not give, takes the ω sensor's.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

__all__ = ["CALIBRATIONS", "from_volts", "to_volts", "volt_fault"]

LBM_G = 453.59237  # grams per pound-mass
LBFT_NM = 1.3558179  # N·m per lb·ft
INJECTIONS_PER_REV = 3.0  # six cylinders, four strokes: three injections per revolution

#: per column: polynomial coefficients (x⁰, x¹, …) of the seed's calibration in the seed's
#: unit, the factor from that unit to the simulator's, and the voltage range it is valid on
CALIBRATIONS: dict[str, tuple[tuple[float, ...], float, tuple[float, float]]] = {
    "m_a": ((-4.2073e-4, 5.2296e-3, 1.3396e-3, 2.1860e-3), LBM_G, (0.0, 10.0)),
    "omega": ((-1990.5, 1044.7), 1.0, (0.0, 10.0)),
    "omega_dy": ((-1990.5, 1044.7), 1.0, (0.0, 10.0)),  # not printed: the ω sensor's
    "alpha": ((-82.905, 124.70, -46.241, 9.1047, -0.67342), 1.0, (0.5, 5.2)),
    "T_L": ((-2.5384, 0.99857), LBFT_NM, (-100.0, 300.0)),
    "m_f": (
        tuple(5.3e-6 * c for c in (-1.2015, 3.3304)),
        LBM_G * 1e3 * INJECTIONS_PER_REV,  # lbm per injection -> mg per revolution
        (0.0, 20.0),
    ),
}


def _value(col: str, x: np.ndarray) -> np.ndarray:
    coef, factor, _ = CALIBRATIONS[col]
    return factor * np.polynomial.polynomial.polyval(x, coef)


def _volts(col: str, v: np.ndarray) -> np.ndarray:
    """Inverse of the calibration: linear ones exactly, the others by interpolation on a fine
    grid over their valid range (all are increasing there)."""
    coef, factor, (lo, hi) = CALIBRATIONS[col]
    if len(coef) == 2:
        return (v / factor - coef[0]) / coef[1]
    grid = np.linspace(lo, hi, 200_001)
    vals = _value(col, grid)
    if not np.all(np.diff(vals) > 0):
        raise ValueError(f"{col}: calibration not increasing over {lo}-{hi} V")
    out = np.interp(v, vals, grid, left=np.nan, right=np.nan)
    if np.isnan(out[np.isfinite(v)]).any():
        raise ValueError(f"{col}: values outside the calibration's {lo}-{hi} V")
    return out


def to_volts(df: pd.DataFrame, columns: Sequence[str] | None = None) -> pd.DataFrame:
    """``df`` with the calibrated columns (default: every one present) as sensor volts."""
    cols = [c for c in (columns or CALIBRATIONS) if c in df.columns]
    return df.assign(**{c: _volts(c, df[c].to_numpy(float)) for c in cols})


def from_volts(df: pd.DataFrame, columns: Sequence[str] | None = None) -> pd.DataFrame:
    """Inverse of :func:`to_volts`: volts back to the simulator's units."""
    cols = [c for c in (columns or CALIBRATIONS) if c in df.columns]
    return df.assign(**{c: _value(c, df[c].to_numpy(float)) for c in cols})


def volt_fault(
    df: pd.DataFrame, gains: Mapping[str, float], onset: int, *, volts: bool = False
) -> pd.DataFrame:
    """A calibration fault on the sensor voltage: each column of ``gains`` has its voltage
    multiplied by the gain from revolution ``onset`` on (the seed's "multiply ... by 1.20"
    applied to the recorded voltage). ``df`` is in the simulator's units and so is the result,
    unless ``volts``: then ``df`` is in volts and stays so."""
    rev = df["rev"].to_numpy() if "rev" in df else np.arange(len(df))
    on = rev >= onset
    cols = {}
    for c, g in gains.items():
        x = df[c].to_numpy(float)
        bad = g * x if volts else _value(c, g * _volts(c, x))
        cols[c] = np.where(on, bad, x)  # untouched before the onset
    return df.assign(**cols)
