"""Input specs (Kościelny et al., eqs. 7–9) and lagged design matrices."""

import numpy as np
import pandas as pd
import pytest

from diag_plugin.regressors import InputSpec, build_design, direction, max_lag, needed_tags


def frame(n=10, freq="10s"):
    idx = pd.date_range("2026-01-01", periods=n, freq=freq, tz="UTC", name="ts")
    return pd.DataFrame(
        {"CV": np.arange(n, dtype=float), "F": 100 + np.arange(n, dtype=float), "P1": 5.0},
        index=idx,
    )


@pytest.mark.parametrize(
    "text,fn,tags,lag",
    [
        ("CV[k]", "", ("CV",), 0),
        ("CV[k-1]", "", ("CV",), 1),
        (" LC51_03.CV [ k - 12 ] ", "", ("LC51_03.CV",), 12),
        ("diff(P1,P2)[k]", "diff", ("P1", "P2"), 0),
        ("dir(CV)[k-1]", "dir", ("CV",), 1),
        ("rate(X)[k-2]", "rate", ("X",), 2),
        ("hour()[k]", "hour", (), 0),
    ],
)
def test_parse_specs(text, fn, tags, lag):
    s = InputSpec.parse(text)
    assert (s.fn, s.tags, s.lag) == (fn, tags, lag)
    assert InputSpec.parse(str(s)) == s


@pytest.mark.parametrize(
    "text,msg,pos",
    [("CV", "expected '\\['", 2), ("CV[k+1]", "future sample", 4), ("LT101[k-]", "whole number", 8),
     ("foo(CV)[k]", "unknown function", 0), ("diff(P1)[k]", "takes 2", 0),
     ("dir(CV,abc)[k]", "threshold", 7), ("Flow (t/h)[k]", "double quotes", 4),
     ('"Flow (t/h)[k]', "closing double quote", 0), ("X[k] Y", "after the spec", 5)],
)  # fmt: skip
def test_bad_specs_say_what_is_wrong_and_where(text, msg, pos):
    """A spec that does not parse names the spec, what is wrong and the position, with a
    caret under it (issue 22: `LT101[k-]`, `X[k+1]` ended in tracebacks)."""
    from diag_plugin.regressors import SpecError

    with pytest.raises(SpecError, match=msg) as err:
        InputSpec.parse(text)
    assert err.value.pos == pos
    lines = str(err.value).splitlines()
    assert lines[1] == f"  {text}" and lines[2] == "  " + " " * pos + "^"


@pytest.mark.parametrize(
    "text,tags",
    [('"Flow (t/h)"[k-1]', ("Flow (t/h)",)), ("Füllstand[k]", ("Füllstand",)),
     ('diff("P 1",P2.PV)[k]', ("P 1", "P2.PV")), ('rate("TI-101 (°C)")[k-1]', ("TI-101 (°C)",))],
)  # fmt: skip
def test_tag_names_with_spaces_brackets_or_any_alphabet_work_in_specs(text, tags):
    s = InputSpec.parse(text)
    assert s.tags == tags
    assert InputSpec.parse(str(s)) == s


def test_lagged_design_matrix_aligns_and_counts_drops():
    f = frame()
    f.loc[f.index[5], "CV"] = np.nan
    d = build_design(f, ["CV[k-1]", "P1[k]"], "F[k]")
    # row k uses CV[k-1]: row 0 has no history, row 6 needs the NaN at 5
    assert list(d.index) == [f.index[i] for i in (1, 2, 3, 4, 5, 7, 8, 9)]
    np.testing.assert_array_equal(d.X[:, 0], [0, 1, 2, 3, 4, 6, 7, 8])
    np.testing.assert_array_equal(d.y, [101, 102, 103, 104, 105, 107, 108, 109])
    assert d.dropped == {"history for the lags": 1, "CV missing or bad": 1}
    assert d.n_dropped == 2


def test_bad_quality_values_are_dropped():
    f = frame()
    q = pd.DataFrame(0, index=f.index, columns=f.columns)
    q.loc[f.index[3], "F"] = 2
    d = build_design(f, ["CV[k]"], "F[k]", quality=q)
    assert f.index[3] not in d.index
    assert d.dropped == {"F missing or bad": 1}


def test_irregular_grid_is_refused():
    f = frame().drop(frame().index[4])
    with pytest.raises(ValueError, match="regular"):
        build_design(f, ["CV[k-1]"], "F[k]")


def test_missing_tag_is_named():
    with pytest.raises(KeyError, match="P2"):
        build_design(frame(), ["diff(P1,P2)[k]"], "F[k]")


def test_direction_is_a_play_operator():
    x = np.array([0, 0.2, 1.5, 3, 2.9, 2.0, 1.0, 1.2, np.nan, 5, 7])
    d = direction(x, 1.0)
    np.testing.assert_array_equal(d[:8], [np.nan, np.nan, 1, 1, 1, 1, -1, -1][:8])
    assert np.isnan(d[8]) and np.isnan(d[9]) and d[10] == 1


def test_derived_features_and_helpers():
    f = frame(n=5)
    d = build_design(f, ["rate(CV)[k]", "diff(F,CV)[k]", "hour()[k]"], None)
    np.testing.assert_array_equal(d.X[:, 0], 1.0)
    np.testing.assert_array_equal(d.X[:, 1], 100.0)
    assert d.X[0, 2] == pytest.approx(10 / 3600)
    assert needed_tags(["diff(P1,P2)[k]", "P1[k-2]", "CV[k]"]) == ["P1", "P2", "CV"]
    assert max_lag(["rate(CV)[k-2]", "P1[k]"]) == 3


def test_columns_read_once_give_the_frames_design_rows():
    """A piece read once into :class:`Columns` (renamed, for many builders) gives each builder
    the rows, state and counts the frame gives, across pieces with a missed cycle."""
    from diag_plugin.regressors import Columns, DesignBuilder

    f = frame().rename(columns={"CV": "plant CV"})
    f.loc[f.index[2], "P1"] = np.nan
    specs = ["CV[k-1]", "rate(P1)[k]", "dir(CV)[k-2]", "diff(P1,CV)[k]"]
    a, b = DesignBuilder(specs, "F[k]"), DesignBuilder(specs, "F[k]")
    names = {"CV": "plant CV", "P1": "P1", "F": "F"}
    for piece in (f.iloc[:4], f.iloc[5:6], f.iloc[6:]):  # a missed cycle between the first two
        da = a.transform(piece.rename(columns={"plant CV": "CV"}), lean=True)
        db = b.transform(Columns(piece, names), lean=True)
        np.testing.assert_array_equal(da.X, db.X)
        np.testing.assert_array_equal(da.y, db.y)
        np.testing.assert_array_equal(da.positions, db.positions)
        assert a.to_state() == b.to_state()
    with pytest.raises(KeyError, match="P2"):
        DesignBuilder(["diff(P1,P2)[k]"], "F[k]").transform(Columns(f, names))
    with pytest.raises(ValueError, match="regular"):
        Columns(f.drop(f.index[4]), names)


@pytest.mark.parametrize("kind", ["floats", "ints", "text", "few", "nullable"])
def test_columns_hold_the_frames_floats(kind):
    """:class:`Columns` reads what ``frame[cols].to_numpy(float)`` gives, bit for bit: from the
    frame's values taken whole (floats, ints beside them), or through pandas where the frame
    holds a column that is not a number, reads few of many columns or has missing values."""
    from diag_plugin.regressors import Columns

    f = frame()
    f.loc[f.index[3], "F"] = -0.0
    f.loc[f.index[5], "CV"] = np.nan
    if kind == "ints":
        f["P1"] = np.arange(len(f), dtype=np.int64) * 3
    elif kind == "text":
        f["note"] = "x"
    elif kind == "few":
        for i in range(8):
            f[f"other{i}"] = float(i)
    elif kind == "nullable":
        f["P1"] = pd.array([1.5, None] * 5, dtype="Float64")
    names = {"F": "F", "P1": "P1", "CV": "CV"}
    got = Columns(f, names)
    want = f[list(names.values())].to_numpy(dtype=float, na_value=np.nan)
    for j, t in enumerate(names):
        assert got.values(t).tobytes() == want[:, j].tobytes()


def test_rate_over_l_samples_is_the_change_over_l_per_sample_across_pieces():
    """``rate(TAG,L)[k]`` is ``(TAG[k] − TAG[k-L]) / L`` (a slow tag's rate, issue 34):
    it parses and prints back, needs ``L`` samples of history, and gives the same values fed
    in pieces shorter than ``L`` (its last ``L`` samples carried, also through its state) as
    in one pass; ``L`` must be a whole number of samples."""
    from diag_plugin.regressors import DesignBuilder, SpecError

    s = InputSpec.parse('rate("T 1",7)[k-2]')
    assert (s.fn, s.tags, s.lag, s.param) == ("rate", ("T 1",), 2, 7.0)
    assert InputSpec.parse(str(s)) == s and str(s) == 'rate("T 1",7)[k-2]'
    assert max_lag(["rate(T,7)[k-2]", "P1[k]"]) == 9 and max_lag(["rate(T)[k]"]) == 1
    for bad in ("rate(T,0)[k]", "rate(T,2.5)[k]", "rate(T,x)[k]"):
        with pytest.raises(SpecError, match="rate"):
            InputSpec.parse(bad)
    rng = np.random.default_rng(3)
    idx = pd.date_range("2026-01-01", periods=60, freq="1s", tz="UTC")
    x = np.cumsum(rng.normal(0, 1, 60))
    f = pd.DataFrame({"T": x, "F": rng.normal(0, 1, 60)}, index=idx)
    whole = DesignBuilder(["rate(T,7)[k]"], "F[k]").transform(f)
    want = (x[7:] - x[:-7]) / 7
    np.testing.assert_allclose(whole.X[:, 0], want)
    assert whole.X.shape[0] == 53  # the first 7 samples have no sample 7 earlier
    b = DesignBuilder(["rate(T,7)[k]"], "F[k]")
    parts = [b.transform(f.iloc[:3]).X]
    c = DesignBuilder(["rate(T,7)[k]"], "F[k]")
    c.load_state(b.to_state())  # the carried samples survive a restart
    for lo, hi in ((3, 5), (5, 30), (30, 60)):
        parts.append(c.transform(f.iloc[lo:hi]).X)
    np.testing.assert_array_equal(np.vstack(parts)[:, 0], whole.X[:, 0])


def test_mean_over_l_samples_is_the_window_a_rate_over_l_spans_across_pieces():
    """``mean(TAG,L)[k]`` is the mean of ``TAG[k-L+1] … TAG[k]``: the samples whose changes
    ``rate(LEVEL,L)[k]`` adds up, so a balance reads its flows and its level's rate over one
    window (the integral form, docs/how-to/unit-loops.md, branch ``i34-balance2``). It parses
    and prints back, needs ``L − 1`` samples of history, is unknown where its window holds a
    gap, and gives the same values fed in pieces shorter than ``L`` (also through a restart
    from its state) as in one pass; ``L`` is a whole number and must be given."""
    from diag_plugin.regressors import DesignBuilder, SpecError, feature

    s = InputSpec.parse('mean("F 1",5)[k-2]')
    assert (s.fn, s.tags, s.lag, s.param) == ("mean", ("F 1",), 2, 5.0)
    assert InputSpec.parse(str(s)) == s and str(s) == 'mean("F 1",5)[k-2]'
    assert max_lag(["mean(F,5)[k-2]"]) == 6 and max_lag(["mean(F,1)[k]"]) == 0
    for bad in ("mean(F)[k]", "mean(F,0)[k]", "mean(F,2.5)[k]"):
        with pytest.raises(SpecError, match="mean"):
            InputSpec.parse(bad)
    rng = np.random.default_rng(4)
    idx = pd.date_range("2026-01-01", periods=60, freq="1s", tz="UTC")
    x = rng.normal(10.0, 1.0, 60)
    x[20] = np.nan
    f = pd.DataFrame({"F": x, "Y": rng.normal(0, 1, 60)}, index=idx)
    np.testing.assert_allclose(feature(f, InputSpec.parse("mean(F,5)[k]")),
                               f["F"].rolling(5).mean().to_numpy())  # fmt: skip
    whole = DesignBuilder(["mean(F,5)[k]"], "Y[k]").transform(f)
    assert whole.X.shape[0] == 60 - 4 - 5  # the first 4 rows, and the 5 windows holding x[20]
    b = DesignBuilder(["mean(F,5)[k]"], "Y[k]")
    parts = [b.transform(f.iloc[:2]).X]
    c = DesignBuilder(["mean(F,5)[k]"], "Y[k]")
    c.load_state(b.to_state())
    for lo, hi in ((2, 5), (5, 33), (33, 60)):
        parts.append(c.transform(f.iloc[lo:hi]).X)
    np.testing.assert_allclose(np.vstack(parts)[:, 0], whole.X[:, 0], rtol=1e-12)
