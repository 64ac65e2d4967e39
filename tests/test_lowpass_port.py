"""The replay's own Butterworth design, step state and χ² levels against scipy's, bit for
bit, and that ``diag diagnose`` imports neither ``scipy.signal`` nor ``scipy.stats`` (issue
34: together 0.8–0.9 CPU s of every process)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest
from scipy import signal, stats

from diag_plugin.diagnose.butter import butter_sos, slowest_pole, sosfilt_zi
from diag_plugin.diagnose.residuals import LowPass
from diag_plugin.diagnose.unittags import chi2_isf, chi2_sf, same_level

CUTOFFS = [
    *np.geomspace(1e-4, 0.999, 25).tolist(),
    *np.random.default_rng(34).uniform(0.0005, 0.9995, 25).tolist(),
    0.01,
    0.2,
    0.5,
]


@pytest.mark.parametrize("order", range(1, 11))
def test_butter_sos_is_scipys_bit_for_bit(order):
    for wn in CUTOFFS:
        ref = signal.butter(order, wn, output="sos")
        got = butter_sos(order, wn)
        assert got.shape == ref.shape
        assert got.tobytes() == ref.tobytes(), (order, wn)
        poles = signal.sos2zpk(ref)[1]
        assert slowest_pole(ref) == float(np.abs(poles).max()), (order, wn)
        assert sosfilt_zi(ref).tobytes() == signal.sosfilt_zi(ref).tobytes(), (order, wn)


def test_butter_sos_refuses_what_scipy_refuses():
    for wn in (0.0, 1.0, 1.5, -0.1):
        with pytest.raises(ValueError):
            butter_sos(4, wn)
    with pytest.raises(ValueError):
        butter_sos(2.5, 0.1)


def test_lowpass_filters_as_with_scipys_sections():
    rng = np.random.default_rng(7)
    x = rng.normal(size=(500, 3))
    x[100:130, 1] = np.nan
    steady = [False, True, False]
    ours = LowPass(0.05, order=5, max_gap=20, steady=steady).transform(x)
    ref = LowPass(0.05, order=5, max_gap=20, steady=steady)
    ref.sos_ = signal.butter(5, 0.05, output="sos")
    ref.zi_step_ = np.ascontiguousarray(signal.sosfilt_zi(ref.sos_))
    assert ours.tobytes() == ref.transform(x).tobytes()


def _edge_values(rng):
    q = np.r_[rng.gamma(2.0, 10.0, 3000), [0.0, -0.0, -1.0, np.nan, np.inf, -np.inf]]
    q = np.r_[q, [1e-300, 5e-324, 1e300, 1500.0, 3000.0, 0.5]]
    df = np.r_[rng.integers(1, 60, 3000).astype(float), [1, 2, 3, 4, 5, 0, -1, np.nan]]
    df = np.r_[df, [7, 8, 9, 45]]
    return q, df


def test_chi2_levels_are_scipy_stats_bit_for_bit():
    q, df = _edge_values(np.random.default_rng(1))
    sf = stats.chi2.sf(q, df)
    assert chi2_sf(q, df).tobytes() == sf.tobytes()
    p = np.r_[sf, [0.0, 1.0, -0.0, 0.5, 1e-300, np.nan, -0.1, 1.1]]
    for T in (1, 3, 45, 46, 200, 0, -2):
        assert chi2_isf(p, T).tobytes() == stats.chi2.isf(p, T).tobytes(), T


def test_same_level_as_with_scipy_stats():
    q, df = _edge_values(np.random.default_rng(2))
    ok = df > 0
    q, df = q[ok], df[ok]
    ref = stats.chi2.isf(stats.chi2.sf(q, df), 45)
    got = same_level(q, df, 45)
    plain = np.isfinite(ref) | ~np.isfinite(q)  # where the log-tail branch does not step in
    assert got[plain].tobytes() == ref[plain].tobytes()


def test_diagnose_imports_no_scipy_signal_nor_stats(tmp_path):
    """The shipped units (each with a low-pass filter) loaded, their lead-in worked out and
    a replay of noisy data with gaps, in a fresh interpreter."""
    code = textwrap.dedent(
        """
        import sys
        import diag_plugin.cli
        import diag_plugin.diagnose.unit, diag_plugin.diagnose.leadin, historian.store
        assert "scipy.signal" not in sys.modules and "scipy.stats" not in sys.modules
        import glob
        import numpy as np, pandas as pd
        from diag_plugin.diagnose.unit import Unit
        from diag_plugin.diagnose.leadin import lead_in
        rng = np.random.default_rng(3)
        for path in sorted(glob.glob("rulebases/*.unit.toml")):
            unit = Unit.load(path, "rulebases")
            assert unit.lowpass is not None
            lead_in(unit)
            idx = pd.date_range("2026-01-01", periods=3000, freq=unit.period, tz="UTC")
            x = rng.uniform(0, 100, (len(idx), len(unit.tags)))
            x[rng.random(x.shape) < 0.01] = np.nan
            unit.evaluate(pd.DataFrame(x, index=idx, columns=unit.tags)).intervals()
        print(sorted(m for m in ("scipy.signal", "scipy.stats") if m in sys.modules))
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=_root()
    )
    assert out.stdout.strip() == "[]"


def _root():
    from pathlib import Path

    return Path(__file__).resolve().parents[1]
