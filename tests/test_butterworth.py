"""The residual filter's design and the combined test's χ² levels without scipy.signal and
scipy.stats (issue 34, speed): the same bits as scipy's own functions, over orders and
cut-offs no unit was tuned on, and ``diag diagnose`` imports neither."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import signal, stats

from diag_plugin.diagnose.butterworth import butter_sos, sos_poles, sosfilt_zi
from diag_plugin.diagnose.residuals import LowPass
from diag_plugin.diagnose.unittags import chi2_isf, chi2_sf, same_level

#: cut-offs from a hundredth of a per cent of Nyquist to just under it, and the ones units use
CUTOFFS = [*np.geomspace(1e-4, 0.999, 97).tolist(), 0.01, 0.2, 0.5, 1 / 3]


@pytest.mark.parametrize("order", range(1, 13))
def test_design_is_scipys_bit_for_bit(order):
    for wn in CUTOFFS:
        ref = signal.butter(order, wn, output="sos")
        sos = butter_sos(order, wn)
        assert sos.tobytes() == ref.tobytes(), (order, wn)
        assert sosfilt_zi(sos).tobytes() == signal.sosfilt_zi(ref).tobytes(), (order, wn)
        assert sos_poles(sos).tobytes() == signal.sos2zpk(ref)[1].tobytes(), (order, wn)


def test_design_refuses_what_scipy_refuses():
    for order, wn in ((4, 0.0), (4, 1.0), (4, -0.1), (0, 0.1), (2.5, 0.1)):
        with pytest.raises(ValueError):
            butter_sos(order, wn)


def test_lowpass_filters_as_sosfilt():
    """The filter as the unit runs it: scipy's sosfilt from scipy's design, same bits."""
    rng = np.random.default_rng(11)
    x = rng.normal(size=(3000, 3)).cumsum(axis=0)
    for order, wn in ((4, 0.01), (3, 0.2), (6, 0.05)):
        got = LowPass(wn, order).transform(x)
        ref = signal.sosfilt(signal.butter(order, wn, output="sos"), x, axis=0)
        assert got.tobytes() == ref.tobytes()


def test_chi2_is_scipy_stats():
    rng = np.random.default_rng(5)
    q = np.concatenate([rng.gamma(3.0, 25.0, 5000), [0, -1, np.nan, np.inf, -np.inf, 1e-300]])
    q = np.concatenate([q, [1500.0, 4000.0, 1e6]])
    for df in (np.full(q.shape, 7.0), rng.integers(-1, 60, q.shape).astype(float)):
        sf = chi2_sf(q, df)
        assert sf.tobytes() == stats.chi2.sf(q, df).tobytes()
        for T in (1, 2, 13, 60, 0):
            assert chi2_isf(sf, T).tobytes() == stats.chi2.isf(sf, T).tobytes()
    p = np.array([0.0, 1.0, 0.5, -0.1, 1.1, np.nan, 1e-320])
    assert chi2_isf(p, 9).tobytes() == stats.chi2.isf(p, 9).tobytes()
    # the mapping the combined test makes, with the far tail matched in logarithms
    df = rng.integers(1, 30, q.shape)
    q = np.clip(np.nan_to_num(q, posinf=9e3), 0, 9e3)
    out = same_level(q, df, 31)
    ref = stats.chi2.isf(stats.chi2.sf(q, df), 31)
    fin = np.isfinite(ref)
    assert out[fin].tobytes() == ref[fin].tobytes() and np.isfinite(out).all()


def test_unit_modules_import_neither():
    code = (
        "import sys; import diag_plugin.diagnose.unit, diag_plugin.diagnose.leadin; "
        "print(sorted(m for m in sys.modules if m in ('scipy.signal', 'scipy.stats')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_a_units_load_imports_neither():
    """Loading a unit (its settle's quiet time reads the residual filter's step response) does
    not import scipy.signal either: i34-holdsettle's hold read it at the load, ~0.9 s of each
    ``diag diagnose`` (lead, 2026-11-30: 200,000 rows 2.13 -> 2.53 s wall)."""
    code = (
        "import sys; from diag_plugin.diagnose.unit import Unit; "
        "Unit.load('rulebases/valve_unit.unit.toml', 'rulebases'); "
        "print(sorted(m for m in sys.modules if m in ('scipy.signal', 'scipy.stats')))"
    )
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=root
    )
    assert out.stdout.strip() == "[]"
