"""A loop's set-point moves in the learning window tell how a compensated bias of the loop's
sensor moves the residuals no model reads it into (issue 34 item 4,
:func:`~diag_plugin.learn.thresholds.setpoint_responses`); the ``[combined] responses`` table
round-trips through the unit file and a bad one is a file:line error."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.unitfile import CombinedSpec, UnitError, UnitFile
from diag_plugin.examples.coupled import DAY, TESTS, build, process
from diag_plugin.learn.thresholds import setpoint_responses


def _fake_unit(tests: list[SimpleNamespace]) -> SimpleNamespace:
    by = {t.name: t for t in tests}
    return SimpleNamespace(file=SimpleNamespace(tests=tests, test=by.__getitem__))


def _ar(rng: np.random.Generator, n: int, phi: float = 0.95) -> np.ndarray:
    e = rng.normal(0.0, 1.0, n)
    out = np.empty(n)
    out[0] = e[0]
    for i in range(1, n):
        out[i] = phi * out[i - 1] + np.sqrt(1 - phi**2) * e[i]
    return out


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_response_is_kept_where_the_set_point_moves_the_residual_and_only_there(seed):
    """Ten days at 3 min, the set-point moved to a new value about daily; one test's scaled
    residual follows it (0.8 per unit, under correlated noise), another does not, the loop's
    own test and its spread test are never answered."""
    rng = np.random.default_rng(seed)
    n = 10 * 480
    idx = pd.date_range("2026-01-01", periods=n, freq="180s", tz="UTC")
    steps = np.repeat(rng.uniform(84.0, 86.0, n // 480 + 1), 480)[:n]
    sp = steps - steps.mean()
    body = pd.DataFrame(
        {
            "loop": _ar(rng, n),
            "loop_spread": _ar(rng, n),
            "down": 0.8 * sp + _ar(rng, n),
            "other": _ar(rng, n),
        },
        index=idx,
    )
    frame = pd.DataFrame({"TIC.SP": steps}, index=idx)
    tests = [
        SimpleNamespace(name="loop", set_point="TIC.SP", statistic="level"),
        SimpleNamespace(name="loop_spread", set_point="TIC.SP", statistic="spread"),
        SimpleNamespace(name="down", set_point=None, statistic="level"),
        SimpleNamespace(name="other", set_point=None, statistic="level"),
    ]
    spec = CombinedSpec(list(body.columns), [0.0] * 4, [1.0] * 4, np.eye(4).tolist())
    got = setpoint_responses(_fake_unit(tests), frame, body, spec)
    assert set(got) == {"TIC.SP"}
    assert set(got["TIC.SP"]) == {"down"}
    assert got["TIC.SP"]["down"] == pytest.approx(0.8, abs=0.3)
    # a set-point the window does not hold (a fixed number) has none
    tests[0].set_point = tests[1].set_point = "85.0"
    assert setpoint_responses(_fake_unit(tests), frame, body, spec) == {}


def test_responses_round_trip_through_the_unit_file_and_bad_ones_are_file_line_errors(tmp_path):
    path = build(tmp_path, process(2 * DAY, 1))
    uf = UnitFile.load(path)
    names = list(TESTS)
    spec = CombinedSpec(
        names,
        [0.0] * len(names),
        [1.0] * len(names),
        np.eye(len(names)).tolist(),
        responses={"A": {"rD": -0.52, "rE": 1.25}},
    )
    uf.set_combined(spec)
    uf.save()
    again = UnitFile.load(path)
    assert again.combined.responses == {"A": {"rD": -0.52, "rE": 1.25}}
    text = path.read_text()
    bad = text.replace("rE = 1.25", 'rE = "big"').replace("rD = -0.52", "rX = -0.52")
    path.write_text(bad)
    with pytest.raises(UnitError) as exc:
        UnitFile.load(path)
    got = "\n".join(exc.value.problems)
    n = next(i for i, x in enumerate(bad.splitlines(), 1) if x.startswith("A = {"))
    assert f":{n}: [combined.responses] A: must be" in got
