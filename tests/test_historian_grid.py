"""The historian's grid, through a real historian (issue 38, bugs 13 and 14).

- A model's period is its *slowest* tag's typical spacing (rounded), so every tag has a real
  sample at most grid points; a fast tag is averaged over each period. Checked at rates from
  1 s to 5 min, off the grid, with jitter, and through ``diag model new``, which says it.
- A sample's grid point is the *nearest* one: a window left open at its end reaches the
  grid point of the last sample, even when that sample lies more than half a period past
  the grid point before it; each grid point holds the sample within half a period of it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from historian import Historian
from historian.sampling import model_period

T0 = pd.Timestamp("2026-04-01T00:00:00Z")


def jittered(n: int, every_s: float, offset_s: float, seed: int) -> pd.DatetimeIndex:
    """``n`` times ``every_s`` apart from T0 + offset, each moved by up to ±2 % of a period."""
    rng = np.random.default_rng(seed)
    t = offset_s + every_s * np.arange(n) + rng.uniform(-0.02, 0.02, n) * every_s
    return T0 + pd.to_timedelta(np.round(t, 3), unit="s")


@pytest.mark.parametrize(
    ("fast_s", "slow_s", "want"),
    [(1.0, 10.0, "10s"), (10.0, 60.0, "1min"), (2.0, 300.0, "5min"), (0.5, 3.0, "3s")],
)
def test_a_models_period_is_its_slowest_tags(tmp_path, fast_s, slow_s, want):
    span_s = 80 * slow_s
    fast = jittered(int(span_s / fast_s), fast_s, 0.37 * fast_s, 1)
    slow = jittered(80, slow_s, 0.41 * slow_s, 2)
    with Historian(f"sqlite:///{tmp_path / 'h.db'}") as h:
        h.write_samples(pd.Series(np.sin(np.arange(len(fast)) / 7), index=fast, name="FAST"))
        h.write_samples(pd.Series(np.arange(len(slow), dtype=float), index=slow, name="SLOW"))
        sampling = h.sampling(["FAST", "SLOW"])
        p = model_period(list(sampling.values()))
        assert p == pd.Timedelta(want).value // 1000
        assert model_period([sampling["SLOW"], sampling["FAST"]]) == p  # order is no matter
        w = h.window(["FAST", "SLOW"], period=want)
    # every grid point but the ends holds a real sample of the slow tag, each one once
    inner = w["SLOW"].iloc[1:-1]
    assert inner.notna().all() and inner.is_unique


def test_diag_model_new_takes_the_period_of_the_slowest_tag_and_says_so(tmp_path, capsys):
    from diag_plugin.cli import main

    db = f"sqlite:///{tmp_path / 'h.db'}"
    fast = jittered(2400, 1.0, 0.3, 3)
    slow = jittered(240, 10.0, 4.1, 4)
    rng = np.random.default_rng(5)
    x = pd.Series(rng.uniform(0, 100, len(slow)), index=slow, name="X")
    with Historian(db) as h:
        h.write_samples(pd.Series(rng.uniform(0, 50, len(fast)), index=fast, name="F"))
        h.write_samples(x)
    rb = tmp_path / "rb"
    argv = ["--db", db, "--rulebases", str(rb), "model", "new", "f", "--output", "F"]
    assert main([*argv, "--input", "X[k]"]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert "period 10s from the data" in out, out
    assert "F: averaged over each period" in out, out
    assert 'period = "10s"' in (rb / "f.toml").read_text()


@pytest.mark.parametrize("offset_s", [6.0, 4.0, 9.5, 0.5])
@pytest.mark.parametrize("period_s", [10.0, 60.0])
def test_an_open_window_ends_at_the_last_samples_nearest_grid_point(tmp_path, offset_s, period_s):
    n = 12
    ts = T0 + pd.to_timedelta(np.arange(n) * period_s + offset_s * period_s / 10, unit="s")
    with Historian(f"sqlite:///{tmp_path / 'h.db'}") as h:
        h.write_samples(pd.Series(np.arange(n, dtype=float), index=ts, name="T"))
        w = h.window(["T"], start=T0, period=f"{period_s:g}s")
    p = pd.Timedelta(seconds=period_s)
    nearest = [T0 + p * round((t - T0) / p) for t in ts]
    assert w.index[-1] == nearest[-1]  # the last sample's own grid point is in the window
    got = w["T"].dropna()
    assert list(got.index) == nearest and got.tolist() == list(range(n))


def test_sampling_of_sorted_unsorted_and_repeated_times_alike():
    """``sampling_of`` skips the sort of times read in order (issue 34): the same figures as
    of the distinct sorted times, for times in order, shuffled and with repeats."""
    from historian.sampling import Sampling, sampling_of

    rng = np.random.default_rng(34)
    ts = np.cumsum(rng.integers(1, 30_000_000, 5_000)).astype(np.int64)

    def reference(t):
        u = np.unique(t)
        med, q95 = np.quantile(np.diff(u), [0.5, 0.95])
        return Sampling("x", len(u), int(round(med)), int(round(q95)))

    for t in (ts, rng.permutation(ts), np.sort(np.r_[ts, ts[::7]]), ts[::-1]):
        assert sampling_of("x", t) == reference(t)
    assert sampling_of("x", ts[:1]) == Sampling("x", 1, 0, 0)
    assert sampling_of("x", np.r_[ts[:1], ts[:1]]) == Sampling("x", 1, 0, 0)
    assert sampling_of("x", np.empty(0, np.int64)) == Sampling("x", 0, 0, 0)
