"""Units whose tests read derived inputs stay on the live plant's stacked fast path (issue 34:
a manipulated flow's balance test reads a level's ``rate()``; such a unit used to be evaluated
one by one, ``Unit.evaluate`` a cycle each).

Two units of the coupled process with the settings ``diag unit build`` writes (deadband,
off-delay in seconds, a spread test, combined test, isolation to tags): ``u1`` reads
``rate(B,3)[k]`` and ``rate(A)[k-1]`` in Wang–Mendel models and ``rate(C)[k]`` and
``mean(D,4)[k]`` in a linear one;
``u2`` reads ``diff``, ``const``, ``dir`` with its threshold, ``hour()`` and ``days()``. Cycled
row by row through the fast path and one by one (``batched=False``), they give the same
statuses, faults, named tags, messages (the warm-up while a rate has no history yet and
CHECK_FUNCTION's reasons included) and symptoms, and residuals equal to 1e-9 (the inputs the
models read are equal bit for bit) — through biases that come and go, gaps in the rates' tags
and a restart from the saved state."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import plant_statuses, same_status

from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.unit import Unit
from diag_plugin.diagnose.unitfile import UnitFile
from diag_plugin.examples.coupled import DAY, TAGS, build, process
from diag_plugin.learn.thresholds import learn_thresholds
from diag_plugin.status import NE107
from diag_plugin.unitbuild.build import alarm_settings

#: what ``diag unit build`` writes at the process's 60 s, a combined test and isolation to tags
BUILT = {"combined": True, "isolation": "tags", **alarm_settings(pd.Timedelta("60s"))}
UNITS = {
    "u1": {
        "rC": ("C[k]", ["A[k]", "B[k]"]),
        "rD": ("D[k]", ["C[k]", "rate(B,3)[k]"]),
        "rE": ("E[k]", ["D[k]", "rate(A)[k-1]"]),
        # linear (below): the other methods' group; a mean over 4 samples (a balance's flow)
        "rF": ("F[k]", ["E[k]", "rate(C)[k]", "mean(D,4)[k]"]),
    },
    "u2": {
        "rC": ("C[k]", ["diff(A,B)[k]", "B[k]", "const(50)[k-1]"]),
        "rD": ("D[k]", ["C[k]", "dir(B,0.5)[k-1]"]),
        "rE": ("E[k]", ["D[k]", "A[k]", "hour()[k]"]),
        "rF": ("F[k]", ["E[k]", "C[k]", "days()[k-2]"]),
    },
}
#: the tests of a unit whose model is linear, not a rule base
LINEAR = {("u1", "rF")}


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """The units of :data:`UNITS`, thresholds learned on 3 fault-free days (seed 1), each
    reading its own plant tags (``U1.A`` …) through ``[tags]``."""
    return make_units(tmp_path_factory.mktemp("derived"))


def make_units(out: Path) -> Path:
    """The units of :func:`folder` written in ``out`` (one folder a unit)."""
    from diag_plugin.training.chunked import train
    from diag_plugin.workbench.model_edit import new_model
    from historian.taginfo import TagInfo

    window = process(3 * DAY, 1)
    info = {k: TagInfo(k, unit="u", lo=lo, hi=hi, description=k) for k, (lo, hi) in TAGS.items()}
    a, b = window.index[0], window.index[-1] + pd.Timedelta("60s")
    for name, tests in UNITS.items():
        d = out / name
        d.mkdir()
        for test, (y, xs) in tests.items():
            if (name, test) in LINEAR:  # written first: build() trains the others
                path = d / f"p_{test}.toml"
                rb = new_model(path, f"p_{test}", y, xs, frame=window, tag_info=info,
                               method="linear", period="60s")  # fmt: skip
                res = train(rb, lambda x, z: window[(window.index >= x) & (window.index < z)], a, b)
                rb.apply_training(res.model, {"from": a.isoformat(), "to": b.isoformat()})
                rb.save()
        path = build(d, window, BUILT, tests=tests)
        text = path.read_text().replace(
            "[tests]\n", '[tests]\nrD_spread = {model = "p_rD.toml", statistic = "spread"}\n', 1
        )
        path.write_text(text)
        uf = UnitFile.load(path)
        uf.set_learned(learn_thresholds(Unit.load(path), [window], far=0.01))
        uf.save()
        mapping = "\n".join(f'{t} = "{name.upper()}.{t}"' for t in TAGS)
        body = path.read_text().replace('name = "p"', f'name = "{name}"')
        (d / f"{name}.unit.toml").write_text(body + "\n[tags]\n" + mapping + "\n")
    return out


def _rows(n: int = DAY // 2) -> pd.DataFrame:
    """Half a day per unit: a bias that comes and goes, a toggling one (held by the unit's
    off-delay), gaps in the rates' tags (short, and long: CHECK_FUNCTION), a tag far outside
    what the units learned."""
    parts = {}
    for k, seed in (("U1", 401), ("U2", 402)):
        f = process(n, seed)
        at = np.arange(n)
        f.iloc[60:200, f.columns.get_loc("D")] += 16.0
        toggling = (at >= 240) & (at < 420) & ((at - 240) % 55 < 40)
        f.loc[toggling, "C"] += 12.0
        f.iloc[450:452, f.columns.get_loc("B")] = np.nan  # shorter than rate(B,3)'s span
        f.iloc[500:503, f.columns.get_loc("A")] = np.nan
        f.iloc[560:600, f.columns.get_loc("B")] = np.nan  # long: CHECK_FUNCTION
        f.iloc[640:680, f.columns.get_loc("C")] = 190.0  # outside what the units learned
        for t in TAGS:
            parts[f"{k}.{t}"] = f[t]
    return pd.DataFrame(parts)


def _paths(folder: Path) -> list[Path]:
    return [folder / n / f"{n}.unit.toml" for n in UNITS]


def _plant(folder: Path, batched: bool = True) -> Plant:
    """The two units (each folder its own models) as one plant."""
    units = {n: Unit.load(p, p.parent) for n, p in zip(UNITS, _paths(folder), strict=True)}
    return Plant(units, batched=batched)


def test_units_reading_derived_inputs_take_the_fast_path_with_the_one_by_one_results(folder):
    fast, slow = _plant(folder), _plant(folder, batched=False)
    assert fast.fast == ["u1", "u2"] and fast.slow == []
    assert slow.slow == ["u1", "u2"]
    rows = _rows()
    a, b = plant_statuses(fast, rows), plant_statuses(slow, rows)
    for name in UNITS:
        for i, (x, y) in enumerate(zip(a[name], b[name], strict=True)):
            same_status(x, y, (name, i), exact=False)
    # the run exercises what matters: the warm-up while rate(B,3) has no history (3 samples)
    # and after it, the rate unknown around its tag's short gap, alarms with tags named, and
    # CHECK_FUNCTION with its reason
    u1 = a["u1"]
    rD = np.array([s.residuals["rD"] for s in u1])
    assert np.isnan(rD[:3]).all() and np.isfinite(rD[3:40]).all()
    assert "warming up" in u1[0].message and "rD" in u1[0].message
    # B missing at 450–451: rate(B,3) = (B[k] − B[k−3]) / 3 unknown there and 3 samples on,
    # known at 452 (B[452] and B[449] both there)
    assert np.isnan(rD[[450, 451, 453, 454]]).all() and np.isfinite(rD[452:453]).all()
    assert np.isfinite(rD[455:460]).all()
    rE = np.array([s.residuals["rE"] for s in u1])
    # A missing at 500–502: rate(A)[k-1] = A[k−1] − A[k−2] unknown at 501–504 only
    assert np.isnan(rE[501:505]).all() and np.isfinite(rE[[500, *range(505, 510)]]).all()
    for name in UNITS:
        got = a[name]
        assert any(s.status == NE107.FAILURE and s.tags for s in got), name
        checking = [s for s in got[560:600] if s.status == NE107.CHECK_FUNCTION]
        assert checking and all(s.message for s in checking), name
    assert any("U1.C = 190" in s.message for s in u1[640:680])


def test_a_restarted_plant_with_derived_inputs_goes_on_where_it_stopped(folder):
    """Stopped inside the toggling bias and one sample after a gap in B (u1's rate(B,3) still
    unknown, u2's dir(B) restarting) and restarted from its JSON state, the fast path gives
    what an uninterrupted run of the one-by-one path gives; a fresh plant does not."""
    rows = _rows().iloc[:480]
    whole = plant_statuses(_plant(folder, batched=False), rows)
    first = _plant(folder)
    stop = 453
    plant_statuses(first, rows.iloc[:stop])
    state = json.loads(json.dumps(first.to_state()))  # what the live loop writes and reads
    again = _plant(folder).load_state(state)
    assert first.fast == again.fast == ["u1", "u2"]
    rest = plant_statuses(again, rows.iloc[stop:])
    fresh = plant_statuses(_plant(folder), rows.iloc[stop:])
    for name in UNITS:
        for i, (x, y) in enumerate(zip(rest[name], whole[name][stop:], strict=True)):
            same_status(x, y, (name, stop + i), exact=False)
    assert "warming up" in fresh["u1"][0].message
    assert "warming up" not in rest["u1"][0].message


def test_the_fast_path_reads_the_builders_inputs_bit_for_bit(folder):
    """Every model input and output the fast path reads each cycle (its history's columns at
    their lags, derived ones included) is the row :class:`DesignBuilder` gives
    :meth:`Unit.evaluate`, bit for bit, on the same samples (known where the builder keeps
    the row, NaN elsewhere). The residuals then differ from the one-by-one path's in the
    last bits only, as a plain test's do (their arithmetic differs, not their inputs)."""
    from diag_plugin.regressors import DesignBuilder

    rows = _rows()
    plant = _plant(folder)
    assert plant.fast == ["u1", "u2"] and len(plant.slots) == 10
    read: list[list[np.ndarray]] = [[] for _ in plant.slots]
    for ts, row in rows.iterrows():
        plant.cycle(ts, row.to_dict())
        have = plant._cycles - 1
        for i, s in enumerate(plant.slots):
            lags = np.r_[s.inputs[:, 0], s.output[0]]
            x = plant._hist[lags, np.r_[s.inputs[:, 1], s.output[1]]]
            read[i].append(np.where(lags > have, np.nan, x))
    for i, s in enumerate(plant.slots):
        u = plant._units[s.unit]
        m = u.models[u.tests[s.test]]
        d = DesignBuilder(m.inputs, m.output, period=m.period).transform(u._model_frame(rows))
        got = np.array(read[i])
        known = np.flatnonzero(~np.isnan(got).any(axis=1))
        np.testing.assert_array_equal(known, d.positions, err_msg=f"{u.name}.{u.tests[s.test]}")
        assert np.array_equal(got[known], np.c_[d.X, d.y]), (u.name, u.tests[s.test])
