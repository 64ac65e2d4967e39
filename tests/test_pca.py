"""The PCA T² + Q detector every detection figure is shown beside (diag_plugin.bench.pca)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.bench.pca import PCADetector


def _plant(n: int, seed: int) -> pd.DataFrame:
    """Six tags driven by two latent causes plus independent noise (a correlated plant)."""
    rng = np.random.default_rng(seed)
    w = np.random.default_rng(0).normal(size=(2, 6))  # the same plant for every seed
    x = rng.normal(size=(n, 2)) @ w + 0.3 * rng.normal(size=(n, 6))
    return pd.DataFrame(x, columns=list("abcdef"))


@pytest.mark.parametrize("alpha", [0.01, 0.001])
def test_limits_give_their_false_alarm_probability_on_data_never_seen(alpha):
    d = PCADetector(alpha=alpha).fit(_plant(20_000, 1))
    assert d.n_components_ == 2  # two causes explain 90 % of the variance
    s = d.score(_plant(400_000, 2))
    # T² is F-distributed (exact for Gaussian data); Jackson–Mudholkar's Q limit is an
    # approximation, conservative here by up to 2.5× at 0.001 (Box's χ² one errs the other way)
    for col, lim, tol in (("T2", d.t2_limit_, 1.3), ("Q", d.q_limit_, 2.5)):
        rate = float((s[col] > lim).mean())
        assert alpha / tol < rate < alpha * tol, (col, rate)


def test_a_sensor_bias_breaks_the_correlation_and_q_sees_it():
    d = PCADetector(alpha=0.001).fit(_plant(20_000, 3))
    clean = _plant(5000, 4)
    biased = clean.copy()
    biased["c"] += 3.0  # ten times the tag's own noise, three times its spread
    assert d.decide(clean).mean() < 0.01
    assert d.decide(biased).mean() > 0.8
    assert (d.score(biased)["Q"] > d.q_limit_).mean() > 0.8


@pytest.mark.parametrize("lags", [0, 2])
def test_contributions_add_up_to_the_statistics_and_name_a_biased_tag(lags):
    d = PCADetector(alpha=0.001, lags=lags).fit(_plant(20_000, 5))
    biased = _plant(2000, 6)
    biased["e"] += 3.0
    c = d.contributions(biased)
    assert list(c.columns) == list("abcdef")
    s = d.score(biased)
    whole = s["T2"] / d.t2_limit_ + s["Q"] / d.q_limit_
    ok = whole.notna()
    np.testing.assert_allclose(c[ok].sum(axis=1), whole[ok], rtol=1e-9)
    assert (c[ok].idxmax(axis=1) == "e").mean() > 0.9


def test_missing_tags_are_unknown_and_dynamic_pca_reads_lags():
    d = PCADetector(lags=2).fit(_plant(5000, 5))
    assert d.components_.shape[1] == 18  # six tags, now and two samples back
    f = _plant(100, 6)
    f.iloc[50, 2] = np.nan
    out = d.decide(f)
    # the first two rows lack their lags, row 50 its tag, rows 51-52 that tag's lags
    gaps = [0, 1, 50, 51, 52]
    assert out.iloc[gaps].isna().all() and out.drop(out.index[gaps]).notna().all()
    with pytest.raises(KeyError, match="tag.s. f not in the data"):
        d.score(f.drop(columns="f"))


def test_estimator_conventions():
    d = PCADetector(n_components=3, alpha=0.05)
    assert not hasattr(d, "components_")
    assert d.fit(_plant(2000, 7)) is d and d.n_components_ == 3
    t2, q = d.limits(0.001)
    assert t2 > d.t2_limit_ and q > d.q_limit_  # rarer alarms, higher limits
    d.set_limits(1e9, 1e9)
    assert (d.decide(_plant(100, 8)) == 0).all()
    with pytest.raises(ValueError, match="complete rows"):
        PCADetector().fit(_plant(5, 9))
