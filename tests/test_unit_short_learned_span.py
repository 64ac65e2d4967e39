"""A short window's linear test guards the range it learned, with or without a tags CSV (issue
34, item 3; docs/how-to/unit-short-windows.md).

A line learned from a few hundred samples says nothing of a range it never saw: past its
inputs' observed range, widened by a quarter on each side, the test answers only while the
line's move stays within a quarter of the output's learned range, then it is unknown
(CHECK_FUNCTION naming the input). With ``diag import --tags`` every tag has an instrument
range (``lo``/``hi``), and the build gave the inputs that range and the allowance a quarter
of the output's meter range: the test judged the whole instrument span along its line (the
chilled-water plant's pump test, learned at ~80 % speed, in alarm all night at 57 %;
docs/explanation/acceptance-chiller.md). Here the tank of
:mod:`diag_plugin.simulate.smallplants` (not the plant that showed it), 400 samples at 15 s,
imported once without and once with a tags CSV whose ranges hold three times the data's: the
same tests are unknown on the same samples of the continuation.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.regressors import InputSpec
from diag_plugin.simulate import smallplants as sp
from tests.test_any_plant_tour import diag, fmt, import_csv

ROWS = 400


def _unit(tmp_path, build: pd.DataFrame, tags=None):
    """Unit ``u`` built as a user would from ``build`` (CSV → ``diag import [--tags]`` →
    ``diag unit build``)."""
    from diag_plugin.diagnose.unit import Unit

    tmp_path.mkdir()
    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(tmp_path / "rb")]
    import_csv(g, build, tmp_path / "train.csv", tags=tags)
    t1 = build.index[-1] + pd.Timedelta(seconds=1)
    rc, text = diag(g, "unit", "build", "u", "--from", fmt(build.index[0]), "--to", fmt(t1))
    assert rc == 0, text
    return Unit.load(tmp_path / "rb" / "u.unit.toml", tmp_path / "rb")


def _linear(unit) -> dict[str, object]:
    """The unit's linear tests that read inputs (not a joint or pair test, which extrapolates):
    name → its model as loaded."""
    from diag_plugin.models.linear import LinearRegressor

    return {
        t: m
        for t in unit.tests
        if type((m := unit.models[t]).model) is LinearRegressor and m.inputs
    }


def test_a_tags_csv_range_keeps_a_short_window_s_guard(tmp_path):
    run = sp.simulate_tank(0.5, seed=43, start="2026-05-04")
    frame = sp.export(run, 15.0, timing="grid", seed=43)
    build, rest = frame.iloc[:ROWS], frame.iloc[ROWS:]
    tags = tmp_path / "tags.csv"
    ranges = {c: (0.0, float(f"{3.0 * frame[c].abs().max():g}")) for c in frame.columns}
    tags.write_text(
        "name,unit,lo,hi\n" + "".join(f"{c},,{lo:g},{hi:g}\n" for c, (lo, hi) in ranges.items())
    )
    bare = _unit(tmp_path / "bare", build)
    ranged = _unit(tmp_path / "ranged", build, tags)

    # the ranged unit's inputs: inside the instrument's range, and no wider than learned
    for name, m in _linear(ranged).items():
        for spec, (lo, hi) in zip(m.inputs, m.model.spans_, strict=True):
            s = InputSpec.parse(spec)
            if s.fn:
                continue
            tag = s.tags[0]
            seen = build[tag].to_numpy(float)
            w = seen.max() - seen.min()
            assert ranges[tag][0] <= lo and hi <= ranges[tag][1], (name, spec, lo, hi)
            assert hi - lo <= 1.6 * w, (name, spec, lo, hi, seen.min(), seen.max())

    unknown_bare = bare.reset().evaluate(rest).residuals.isna()
    unknown_ranged = ranged.reset().evaluate(rest).residuals.isna()
    left = [t for t in _linear(bare) if unknown_bare[t].mean() > 0.01]
    assert left, "the continuation never leaves the window's range: nothing to check"
    for t in left:
        assert t in unknown_ranged, f"{t}: no such test with the tags CSV"
        was = unknown_bare[t].to_numpy()
        now = unknown_ranged[t].to_numpy()
        # unknown where the bare unit is (a few samples apart at the edges at most)
        assert now[was].mean() > 0.9, (t, was.mean(), now.mean(), now[was].mean())
        assert np.abs(now.mean() - was.mean()) < 0.1 * was.mean() + 0.01, (
            t,
            was.mean(),
            now.mean(),
        )


def test_accept_widens_the_output_s_learned_range():
    """``diag unit accept`` grows a linear test's ``[rules] learned_output`` to hold the
    accepted window's output, as it grows the inputs' spans (``accept.widen_spans``): the
    allowance past an input's span then covers the new operating point too."""
    from diag_plugin.models.spec import Variable
    from diag_plugin.rulebase.document import RuleBase
    from diag_plugin.unitbuild.accept import widen_spans

    rng = np.random.default_rng(5)
    ins = [Variable("a[k]", "a", "", (0.0, 5.0))]
    rb = RuleBase.new("m", Variable("y[k]", "y", "", (0.0, 100.0)), ins, method="linear")
    rb.doc["rules"]["learned_output"] = [10.0, 20.0]
    rb.edited()
    x = rng.uniform(0.0, 5.0, 200)
    rb.apply_training(rb.new_model().fit(x[:, None], 10.0 + 2.0 * x), {"source": "test"})
    rb = RuleBase(rb.dumps(), "m.toml")
    new = pd.DataFrame({"a": rng.uniform(1.0, 4.0, 50), "y": rng.uniform(8.0, 31.0, 50)})
    out, said = widen_spans(rb, new)
    lo, hi = out.options["learned_output"]
    assert lo == pytest.approx(new.y.min()) and hi == pytest.approx(new.y.max())
    assert any("learned range" in s for s in said), said
    assert out.output.span == (0.0, 100.0)  # the meter's span is not the learned range
    inside = pd.DataFrame({"a": [1.0, 2.0], "y": [12.0, 18.0]})
    assert widen_spans(RuleBase(out.dumps(), "m.toml"), inside)[1] == []
