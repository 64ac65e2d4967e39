"""The control loop's model (method ``track``): the measurement at its set-point plus the
loop's steady offset — exact in chunks and merged, valid at any set-point, a plain file an
expert edits with ``file:line`` errors."""

from __future__ import annotations

import numpy as np
import pytest

from diag_plugin.models.registry import METHODS, get_method
from diag_plugin.models.spec import Variable
from diag_plugin.models.track import TrackRegressor
from diag_plugin.rulebase.document import RuleBase, RuleBaseError


def _loop(n: int, seed: int, values, offset: float = 0.3):
    rng = np.random.default_rng(seed)
    sp = np.repeat(rng.choice(values, n // 50 + 1), 50)[:n].astype(float)
    y = sp + offset + rng.normal(0, 0.2, n)
    return sp[:, None], y


def test_the_offset_is_learned_exactly_in_chunks_and_merged():
    X, y = _loop(4000, 1, [40.0, 50.0])
    one = TrackRegressor().fit(X, y)
    assert one.offset_ == pytest.approx(np.mean(y - X[:, 0]))
    chunked = TrackRegressor()
    for a in range(0, len(y), 613):
        chunked.partial_fit(X[a : a + 613], y[a : a + 613])
    assert chunked.offset_ == pytest.approx(one.offset_, abs=1e-12)
    left = TrackRegressor(input_spans=[(0, 100)]).fit(X[:1500], y[:1500])
    right = TrackRegressor(input_spans=[(0, 100)]).fit(X[1500:], y[1500:])
    assert left.merge(right).offset_ == pytest.approx(one.offset_, abs=1e-12)
    back = TrackRegressor.from_state(one.to_state())
    assert np.array_equal(back.predict(X), one.predict(X))


def test_it_holds_at_set_points_never_seen_and_never_clips():
    X, y = _loop(4000, 2, [40.0, 45.0])
    m = TrackRegressor().fit(X, y)  # spans: the range seen, 40 … 45
    new = np.array([[10.0], [62.0], [np.nan]])
    p = m.predict_detail(new)
    assert p.y[:2] == pytest.approx(new[:2, 0] + m.offset_)
    assert np.isnan(p.y[2]) and p.reason[2] != 0 and p.support[:2].tolist() == [1.0, 1.0]
    # a polynomial of the same two set-points does not hold there
    poly = get_method("narmax2").estimator().fit(X, y)
    assert abs(poly.predict(new[1:2])[0] - 62.3) > 1.0
    with pytest.raises(ValueError, match="one input"):
        TrackRegressor().fit(np.column_stack([X, X]), y)


def test_the_file_round_trips_and_a_bad_term_is_an_error_with_its_line(tmp_path):
    assert not METHODS["track"].identifies and METHODS["narmax2"].identifies
    out = Variable("TI103[k]", "TI103", "degC", (0.0, 120.0))
    sp = Variable("TIC103.SP[k-2]", "SP", "degC", (0.0, 120.0))
    rb = RuleBase.new("loop", out, [sp], method="track", period="180s")
    X, y = _loop(3000, 3, [80.0, 85.0, 90.0], offset=-0.1)
    rb.apply_training(rb.new_model().fit(X, y), {"source": "test"})
    path = rb.save(tmp_path / "loop.toml")
    text = path.read_text()
    assert 'term = "TIC103.SP[k-2]", coef = 1.0' in text
    back = RuleBase.load(path)
    assert back.to_model().predict(np.array([[100.0]]))[0] == pytest.approx(
        100.0 + np.mean(y - X[:, 0])
    )
    assert path.read_text() == back.dumps()  # loading and saving gives the same bytes
    bad = text.replace('term = "TIC103.SP[k-2]"', 'term = "TIC103.SP[k-2]^2"')
    (tmp_path / "bad.toml").write_text(bad)
    line = next(i for i, ln in enumerate(bad.splitlines(), 1) if "^2" in ln)
    with pytest.raises(RuleBaseError) as e:
        RuleBase.load(tmp_path / "bad.toml")
    assert f"bad.toml:{line}:" in str(e.value) and "a track model has only" in str(e.value)
