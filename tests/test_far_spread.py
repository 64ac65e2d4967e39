"""An answer past a Wang–Mendel model's span is an extrapolation: the unit divides its residual
by ``1 + FAR_SPREAD · d`` (``d`` the farthest input past its span, in spans; issue 34, branch
i34-far). Inside the spans the residuals are the same bits as without it; the unit, the
threshold learning's residual and the plant (the live loop's evaluator) divide alike."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose import residuals as R


def test_past_span_is_the_farthest_input_past_its_span_in_spans():
    lo, hi = np.array([0.0, 10.0, np.nan]), np.array([2.0, 20.0, np.nan])
    X = np.array(
        [
            [1.0, 15.0, 5.0],  # inside
            [2.5, 15.0, 5.0],  # a quarter span above input 0
            [1.0, 8.0, 5.0],  # a fifth below input 1
            [3.0, 5.0, 99.0],  # both past: the farther (half a span each)
            [np.nan, 25.0, 0.0],  # NaN counts 0; input 1 half a span above
        ]
    )
    np.testing.assert_allclose(R.past_span(X, lo, hi), [0.0, 0.25, 0.2, 0.5, 0.5])
    assert R.far_factor(X[:1], (lo, hi)).size == 0  # nothing past: nothing to divide
    assert R.far_factor(X, None).size == 0  # a model without a rule grid
    np.testing.assert_allclose(
        R.far_factor(X, (lo, hi)), 1.0 + R.FAR_SPREAD * np.array([0, 0.25, 0.2, 0.5, 0.5])
    )


@pytest.fixture(scope="module")
def hx(tmp_path_factory):
    """The heat exchanger's unit (4 days, thresholds learned) and a fault-free day whose hot
    inlet temperature (its rules reach the span's top) is pushed past its span for 200
    samples (to 0.4 span beyond)."""
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.diagnose.unitfile import UnitFile
    from diag_plugin.examples.rigs import build_unit, runs
    from diag_plugin.learn.thresholds import learn_thresholds

    tmp = tmp_path_factory.mktemp("hx")
    path = build_unit(tmp, "hx", runs("hx", [31], length=4))
    unit = Unit.load(path)
    uf = UnitFile.load(path)
    uf.set_learned(learn_thresholds(unit, [runs("hx", [31], length=4)], far=0.01))
    uf.save()
    unit = Unit.load(path)
    m = unit.models["r_h"]
    assert m.inputs[2] == "THI[k]" and m.model.cell_indices()[:, 2].max() == 10
    tag = unit.file.tags.get("THI", "THI")
    p = m.model.partitions_[2]
    later = runs("hx", [32], length=1)
    later.iloc[300:500, later.columns.get_loc(tag)] = p.hi + np.linspace(0.0, 0.4, 200) * (
        p.hi - p.lo
    )
    return path, later


def test_past_the_span_the_residual_is_divided_inside_it_is_the_same_bits(hx, monkeypatch):
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.regressors import build_design

    path, later = hx
    unit = Unit.load(path)
    m = unit.models["r_h"]
    X = build_design(later, m.inputs, m.output).X
    d = R.past_span(X, *R.span_ends(m.model))
    assert (d > 0.3).sum() > 20 and (d == 0).sum() > 1000
    got = unit.reset().raw_residuals(later)["r_h"].to_numpy()[-len(d) :]
    monkeypatch.setattr(R, "FAR_SPREAD", 0.0)
    plain = unit.reset().raw_residuals(later)["r_h"].to_numpy()[-len(d) :]
    inside = d == 0
    assert np.array_equal(got[inside], plain[inside], equal_nan=True)
    past = (d > 0) & np.isfinite(plain)
    assert past.sum() > 100
    monkeypatch.undo()
    np.testing.assert_allclose(got[past], plain[past] / (1 + R.FAR_SPREAD * d[past]), rtol=1e-12)
    # the threshold learning's residual (Unit.residual with the model's inputs) agrees
    t = unit.file.test("r_h")
    y = build_design(later, m.inputs, m.output).y
    again = unit.residual(t, y, m.model.predict_detail(X), X)
    np.testing.assert_allclose(again, got, rtol=1e-12, equal_nan=True)


def test_the_plant_divides_as_the_unit_does(hx):
    from diag_plugin.diagnose.plant import Plant
    from diag_plugin.diagnose.unit import Unit

    path, later = hx
    part = later.iloc[250:560]
    plant = Plant({"hx": Unit.load(path)}, {})
    cyc = [plant.cycle(ts, row.to_dict())[0] for ts, row in part.iterrows()]
    alone = Unit.load(path).evaluate(part)
    r = np.array([s.residuals["r_h"] for s in cyc])
    np.testing.assert_allclose(r, alone.residuals["r_h"].to_numpy(), rtol=1e-9, equal_nan=True)
    assert [int(s.status) for s in cyc] == alone.status.tolist()
    assert isinstance(alone.residuals, pd.DataFrame)
