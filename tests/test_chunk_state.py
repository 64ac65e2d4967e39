"""Derived-input state carried across chunks, into validation, between processes and cycle by
cycle: the rule base never depends on how the range is cut (issue 7)."""

import json

import numpy as np
import pandas as pd
import pytest

from diag_plugin.regressors import DesignBuilder, build_design, direction
from diag_plugin.rulebase.document import RuleBase, Variable
from diag_plugin.training.chunked import train

#: one input of every derived kind, several with lags (dead time)
ALL_KINDS = (
    "CV[k]",
    "dir(CV,0.5)[k-1]",
    "rate(CV)[k-2]",
    "diff(P1,P2)[k-3]",
    "hour()[k]",
    "days()[k]",
)
SPANS = {
    "CV": (0.0, 100.0),
    "dir(CV,0.5)": (-1.0, 1.0),
    "rate(CV)": (-3.0, 3.0),
    "diff(P1,P2)": (0.0, 400.0),
    "hour()": (0.0, 24.0),
    "days()": (9496.0, 9506.0),
}


def still_valve(days: float, seed: int, hold_hours: float = 20.0) -> pd.DataFrame:
    """A valve that holds still for ``hold_hours`` at a time, then travels; the position
    lags behind with backlash (so the direction of travel matters); NaN gaps in each tag."""
    rng = np.random.default_rng(seed)
    n = int(days * 8640)
    idx = pd.date_range("2026-01-01", periods=n, freq="10s", tz="UTC", name="ts")
    hold = int(hold_hours * 360)
    levels = rng.uniform(10, 90, n // hold + 2)
    steps = np.repeat(levels, hold)[:n]
    cv = pd.Series(steps).rolling(240, min_periods=1).mean().to_numpy() + rng.normal(0, 0.05, n)
    x = np.empty(n)
    ref = cv[0]
    for i in range(n):  # play operator with 3 % backlash
        ref = min(max(ref, cv[i] - 1.5), cv[i] + 1.5)
        x[i] = ref
    p1 = 500 + 100 * np.sin(np.arange(n) / 8640 * 2 * np.pi) + rng.normal(0, 2, n)
    p2 = 300 + rng.normal(0, 2, n)
    frame = pd.DataFrame({"CV": cv, "P1": p1, "P2": p2, "X": x}, index=idx)
    frame.iloc[rng.choice(n, 40, replace=False), 2] = np.nan
    frame.iloc[n // 3 : n // 3 + 50, 1] = np.nan  # a 50-sample gap in P1
    frame.iloc[n // 2 : n // 2 + 30, 0] = np.nan  # and one in CV: direction unknown after it
    return frame


def rulebase(tmp_path, inputs) -> RuleBase:
    return RuleBase.new(
        "m",
        Variable("X[k]", "X", "%", (0.0, 100.0), 21),
        [Variable(s, f"I{i}_", "", SPANS[s.split("[")[0]], 9) for i, s in enumerate(inputs)],
        path=tmp_path / "m.toml",
    )


def reader(frame):
    return lambda a, b: frame[(frame.index >= a) & (frame.index < b)]


def _state(m):
    st = m.to_state()
    return {k: v for k, v in st.items() if isinstance(v, np.ndarray)}


@pytest.mark.parametrize("spec", ALL_KINDS)
def test_rules_do_not_depend_on_the_chunking(tmp_path, spec):
    """1, 7 and 1,000 chunks give identical rules for every derived kind (with lags)."""
    f = still_valve(10, seed=41)
    a, b = f.index[0], f.index[-1] + pd.Timedelta("10s")
    rb = rulebase(tmp_path, ("CV[k]", spec) if spec != "CV[k]" else (spec,))
    runs = [
        train(rb, reader(f), a, b, chunk=(b - a) / n + pd.Timedelta("1s")) for n in (1, 7, 1000)
    ]
    first = runs[0]
    assert first.samples > 0.9 * len(f)
    for other in runs[1:]:
        for k, v in _state(first.model).items():
            np.testing.assert_array_equal(v, _state(other.model)[k], err_msg=k)
        assert other.samples == first.samples
        assert other.dropped == first.dropped
        assert other.validation == pytest.approx(first.validation, rel=1e-12)


def test_direction_survives_a_valve_that_holds_still(tmp_path):
    """The issue's case: chunks shorter than the holds lose no samples to 'undefined'."""
    f = still_valve(6, seed=7, hold_hours=30)
    a, b = f.index[0], f.index[-1] + pd.Timedelta("10s")
    rb = rulebase(tmp_path, ("CV[k]", "dir(CV,0.5)[k]"))
    long = train(rb, reader(f), a, b, chunk=pd.Timedelta(days=30))
    short = train(rb, reader(f), a, b, chunk=pd.Timedelta(hours=6))
    assert short.samples == long.samples
    assert short.dropped == long.dropped
    # undefined only where one pass over all data has no direction yet (before the first
    # move, and after the CV gap until the valve moves again)
    cv = f["CV"].to_numpy()
    one_pass = int((np.isnan(direction(cv, 0.5)) & ~np.isnan(cv)).sum())
    assert short.dropped["derived value undefined"] == one_pass < 0.5 * len(f)


def test_dask_chunks_start_from_the_carried_state(tmp_path):
    """On workers each chunk starts from the state one pass would have (dir: unbounded)."""
    from diag_plugin.training.dask_engine import dask_fitter

    f = still_valve(4, seed=3)
    a, b = f.index[0], f.index[-1] + pd.Timedelta("10s")
    rb = rulebase(tmp_path, ("CV[k]", "dir(CV,0.5)[k-1]", "rate(CV)[k-2]"))
    local = train(rb, reader(f), a, b, chunk=pd.Timedelta(hours=5))
    remote = train(
        rb, reader(f), a, b, chunk=pd.Timedelta(hours=5), fit_chunks=dask_fitter(None, reader(f))
    )
    for k, v in _state(local.model).items():
        np.testing.assert_array_equal(v, _state(remote.model)[k], err_msg=k)
    assert remote.dropped == local.dropped and remote.samples == local.samples
    assert remote.validation == pytest.approx(local.validation, rel=1e-12)


def test_cycle_by_cycle_equals_one_pass_across_a_restart():
    """The live loop: one row per cycle, the state saved as JSON half way and restored."""
    f = still_valve(0.5, seed=11, hold_hours=1)
    inputs = list(ALL_KINDS)
    whole = build_design(f, inputs, "X[k]")
    b = DesignBuilder(inputs, "X[k]")
    rows, ys = [], []
    half = len(f) // 2
    for i in range(len(f)):
        if i == half:  # the plug-in restarts: state through JSON into a new builder
            b = DesignBuilder(inputs, "X[k]").load_state(json.loads(json.dumps(b.to_state())))
        d = b.transform(f.iloc[i : i + 1])
        rows.append(d.X)
        ys.append(d.y)
    np.testing.assert_array_equal(np.vstack(rows), whole.X)
    np.testing.assert_array_equal(np.concatenate(ys), whole.y)


def test_a_missed_cycle_counts_as_missing_samples_and_overlap_is_refused():
    """Lags count grid samples across pieces too: rows nobody delivered are missing."""
    f = still_valve(0.2, seed=2, hold_hours=0.5)
    inputs = ["CV[k-3]", "rate(CV)[k-1]", "dir(CV,0.5)[k]"]
    lost = np.zeros(len(f), bool)
    lost[[100, 101, 102, 500, 900]] = True
    masked = f.copy()
    masked.loc[lost] = np.nan  # what one pass over the grid sees
    one_pass = build_design(masked, inputs, "X[k]")
    b = DesignBuilder(inputs, "X[k]", period="10s")
    rows = [b.transform(f.iloc[i : i + 1]).X for i in np.flatnonzero(~lost)]
    np.testing.assert_array_equal(np.vstack(rows), one_pass.X)
    with pytest.raises(ValueError, match="do not continue the previous piece"):
        b.transform(f.iloc[-5:])
