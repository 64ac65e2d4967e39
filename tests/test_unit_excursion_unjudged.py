"""A measured input beyond what the unit learned, reaching the tests in alarm through a tag the
unit cannot judge (issue 34 item 4, branch ``i34-feedtemp``). On the chemical plant a step of
the fresh feed's temperature ``TI101`` fired the tests that read the mixed feed ``TI102``
(``TI106 = f(TI102[k-9])``, ``TI109 = f(TI102[k-9])``) while ``TI102`` stayed inside its
learned range and its own test, ``TI102 = f(TI101, TI106[k-9])``, was unknown (its rule grid
has no rule where the feed went): ``Excursions`` had no input beyond its range to start from
and the unit named ``TI106`` and ``TI102``. A test in alarm reading ``X`` is now explained by
an input ``Z`` of ``X``'s own test where that test is unknown at the sample and ``Z`` is
beyond its range: the unit cannot say ``X`` is where its causes put it, and the one cause it
sees outside what it learned is ``Z``. Where ``X``'s own test is known (its model answered),
or ``Z`` is inside its range, nothing changes.

The figures here are written by hand (a feed ``Z`` learned over 10–20, a mixed stream ``X``
over 15–25 read by the tests of ``A`` and ``B``, a tag ``D`` holding the largest share of
``T²``), not read off the plant the rule was chosen on."""

from __future__ import annotations

import numpy as np

from diag_plugin.diagnose.unittags import Excursions

TAGS = ["Z", "X", "A", "B", "D"]
SHARES = [0.05, 0.2, 0.3, 0.05, 0.4]


def _excursions() -> Excursions:
    """Three tests: ``X = f(Z)``, ``A = f(X[k-9])``, ``B = f(X[k-9])`` (gains 0.8: 8 % of
    span per unit of input)."""
    return Excursions(
        reads=[[(("Z", 0), 0, 8.0)], [(("X", 9), 1, 8.0)], [(("X", 9), 1, 8.0)]],
        own=np.array([1, 2, 3]),
        ranges={t: (15.0, 25.0) if t != "Z" else (10.0, 20.0) for t in "ZXAB"},
        keys={0: "Z", 1: "X", 2: "A", 3: "B"},
        up={1: [(("Z", 0), 0)], 2: [(("X", 9), 1)], 3: [(("X", 9), 1)]},
        center=np.zeros(3),
        via=[[], [(("Z", 0), 0, 0)], [(("Z", 0), 0, 0)]],
    )


def _name(z: float, x_known: bool = False) -> np.ndarray:
    """The shares of three alarm samples named: the tests of ``A`` and ``B`` on (a residual of
    90 % of span, far more than any gain explains), ``X``'s own test unknown (or known and
    quiet), the feed at ``z``, ``X``, ``A``, ``B`` inside their ranges."""
    n = 3
    share = np.tile(SHARES, (n, 1))
    s = np.tile([0.0 if x_known else np.nan, 1.0, 1.0], (n, 1))
    r = np.tile([0.0 if x_known else np.nan, 90.0, 90.0], (n, 1))
    cols = {"Z": np.full(n, z), "X": np.full(n, 20.0), "A": np.full(n, 20.0), "B": np.full(n, 20.0)}
    return _excursions().name(share, r, s, cols.__getitem__, np.ones(n, bool))


def test_a_feed_beyond_its_range_is_named_through_a_stream_its_unit_cannot_judge():
    """The feed 2 above its range (a fifth of it), the mixed stream's test unknown: the feed
    named at ``1 +`` its excess as a share of its range, first (on main ``D`` kept it)."""
    out = _name(22.0)
    assert np.allclose(out[:, 0], 1.2)
    assert (out.argmax(axis=1) == 0).all()


def test_the_stream_judged_leaves_the_shares():
    """``X``'s own test known and quiet: ``X`` is where its causes put it, the feed does not
    explain the tests reading ``X`` (their residuals are far beyond its gain), nothing named."""
    out = _name(22.0, x_known=True)
    assert np.array_equal(out, np.tile(SHARES, (3, 1)))


def test_a_feed_inside_its_range_names_nothing():
    """The stream's test unknown but the feed inside its range: no excursion to name."""
    out = _name(18.0)
    assert np.array_equal(out, np.tile(SHARES, (3, 1)))
