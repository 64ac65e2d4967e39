"""An envelope's bound per test and age bin and which of its two bounds decided it, from one
computation (issue 34 items 5/6; unitbuild/loops.py ``envelope_bound_fitted``, what
``learn_envelope`` counts in "the larger in N of M").

Each bin's bound is the larger of the widened largest peak and a Gumbel tolerance bound; the
build says in how many cells the tolerance bound was the larger. It counted them by computing
the widened bound a second time; the count now comes from the one computation and must be the
same: the cells where the tolerance bound is above the widened one.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from diag_plugin.unitbuild.loops import (
    envelope_bound,
    envelope_bound_fitted,
    gumbel_bound,
    learn_envelope,
    widened_bound,
)


@pytest.mark.parametrize(
    "peaks",
    [
        [0.4, 0.5, 0.45, 0.6, 0.5, 0.55],  # below the threshold: the widened floor (1) wins
        [1.0, 1.1, 4.0, 1.2, 0.9, 1.0, 6.0, 1.1],  # spread: the tolerance bound wins
        [2.0],  # one peak: no tolerance bound
        [np.nan, 3.0, np.inf, 2.5],  # only the finite peaks count
        [],
    ],
)
@pytest.mark.parametrize("cells", [1, 126])
def test_the_bound_and_which_bound_won_come_from_one_computation(peaks, cells):
    bound, fitted = envelope_bound_fitted(peaks, cells=cells)
    assert bound == envelope_bound(peaks, cells=cells)
    x = np.asarray(peaks, float)
    x = x[np.isfinite(x)]
    want = x.size >= 2 and gumbel_bound(x, cells) > widened_bound(x)
    assert fitted is bool(want)


def test_learn_envelope_counts_the_cells_its_tolerance_bound_decided():
    """Six changes of 40 samples, three tests (one quiet, one with an outlying change, one
    noisy): the count the build says is the number of tests × bins whose tolerance bound is
    above the widened largest peak, as computed here bin by bin."""
    rng = np.random.default_rng(4)
    n_ev, length = 6, 40
    age = np.full(n_ev * (length + 10), -1, np.int64)
    for e in range(n_ev):
        a = e * (length + 10)
        age[a : a + length] = np.arange(1, length + 1)
    a = np.column_stack([0.3 * rng.random(len(age)), rng.random(len(age)) ** 4 * 3.0,
                         np.abs(rng.normal(0, 1.5, len(age)))])  # fmt: skip
    a[:120, 1] *= 3.0  # an outlying change on the second test
    env, how = learn_envelope(a, age, [], 40.0, 1.0, ["Q", "O", "N"])
    assert env is not None and env.starts == n_ev
    got = re.search(r"the larger in (\d+) of (\d+)\)", how)
    assert got, how
    edges = [int(e) for e in env.age_s] + [41]
    cells = int(got.group(2))
    want = 0
    for lo, hi in zip(edges, edges[1:], strict=False):
        for j in range(a.shape[1]):
            peaks = [np.abs(a[(age >= lo) & (age < hi) & (np.arange(len(age)) // 50 == e), j]).max()
                     for e in range(n_ev)]  # fmt: skip
            want += gumbel_bound(np.asarray(peaks), cells) > widened_bound(peaks)
    assert int(got.group(1)) == want
    assert 0 < want < cells  # both bounds decide some cells here
