"""The compiled ``%.6g`` of ``diag diagnose --csv`` (:mod:`diag_plugin.diagnose.csvfast`,
issue 34 round six) is Python's ``"%.6g" % v`` for every value: random magnitudes of every
exponent, decimal values whose sixth digit is followed by an exact or near half, dyadic halves
(exact ties, rounded to even), the edges of the fixed and exponent notations and of the
kernel's own range, zeros of both signs, infinities and NaN (empty)."""

from __future__ import annotations

import numpy as np
import pytest

from diag_plugin.diagnose.csvfast import escaped, format_g6, hard_floats, utc_texts

EDGES = [0.0, -0.0, 1.0, -1.0, 1e22, 1e-17, 1e21, 9.99999e21, 1.7976931348623157e308, 5e-324,
         999999.5, 9999995.0, 1234565.0, 123456.5, 0.1, 0.5, 2.5e-5, 1e-5, 9.999995e-5, 1e-4,
         99999.95, 100000.0, 999999.0, 999999.4999, 1e6, 0.0001234565, np.inf, -np.inf,
         np.nan]  # fmt: skip


def _values(seed: int, n: int = 60_000) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.concatenate(
        [
            rng.standard_normal(n) * 10.0 ** rng.integers(-30, 30, n),
            np.round(rng.standard_normal(n) * 1e7) / 10.0 ** rng.integers(0, 14, n),
            (rng.integers(0, 2**21, n) + 0.5) * 2.0 ** rng.integers(-40, 40, n),
            rng.integers(-(10**12), 10**12, n).astype(float),
            np.array(EDGES),
            -np.array(EDGES),
        ]
    )


@pytest.mark.parametrize("seed", [17, 29])
def test_g6_is_pythons(seed):
    x = _values(seed)
    want = ["" if v != v else "%.6g" % v for v in x.tolist()]  # noqa: UP031
    assert format_g6(x) == want
    # most values are the kernel's own, not handed back to Python
    assert hard_floats(x[np.isfinite(x)]).mean() < 0.2


def test_escaped_is_the_csv_writers():
    import csv
    import io
    import os

    for text in ["", "a", "a,b", 'say "x"', "two\nlines", "cr\r", "ü|ß", " pad "]:
        buf = io.StringIO()
        csv.writer(buf, lineterminator=os.linesep).writerow(["x", text, "y"])  # as to_csv
        assert buf.getvalue() == f"x,{escaped(text)},y{os.linesep}"


def test_utc_texts_are_numpys():
    """The CSV's times (UTC, whole seconds) as ``datetime_as_string`` and ``+0000`` write
    them: any second of the years 1000–9999, leap days and the turns of centuries; None
    outside those years (written as before)."""
    rng = np.random.default_rng(3)
    edges = np.array(["1000-01-01", "1600-02-29", "1900-03-01", "1969-12-31T23:59:59",
                      "1970-01-01", "2000-02-29T12:00:01", "2100-02-28T23:59:59",
                      "9999-12-31T23:59:59"], dtype="datetime64[s]")  # fmt: skip
    secs = np.concatenate([rng.integers(-30610224000, 253402300800, 50_000), edges.astype(int)])
    want = np.char.add(np.datetime_as_string(secs.astype("datetime64[s]"), unit="s"), "+0000")
    assert utc_texts(secs).astype(str).tolist() == want.tolist()
    assert utc_texts(np.array([253402300800])) is None
    assert utc_texts(np.array([-30610224001])) is None
