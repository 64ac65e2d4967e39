"""Seed 001 Table 4 and rules (10)–(14) on the simulated servomotor–valve assembly (issue 9).

Four Wang–Mendel models are trained on fault-free simulated data (seed 3), thresholds are
learned on another fault-free run (seed 7), and the five faults of Table 4 are injected one at
a time on seeds never used while developing (101, 202). Residuals (seed 001 eq. 6, % of span):

    r1 = F − F̂(CV[k], P1[k], P2[k])    r2 = P0 − P̂0(CV[k])
    r3 = X − X̂(P0[k])                  r4 = F − F̂(X[k], P1[k], P2[k])

Deviation from the paper: r1 and r4 also take the process pressures P1, P2. In the simulator the
flow depends strongly on the pressure drop, and F̂(CV) / F̂(X) alone leave a fault-free residual
of up to ~50 % of span (0.999 quantile), which no Table-4 fault exceeds. With P1, P2 the learned
thresholds drop to ~10 %. Lags: [k] gave the lowest held-out error for all four models (checked
against [k-1], [k-2] on the training data).

Simulator faults realising Table 4 (DABLib numbering, see diag_plugin/simulate/faults.py):
    e1 E/P transducer      f12 (E/P current i0 (1 − fs)), +0.5
    e2 P0 pressure sensor  f14 (P0 reading (1 + fs)), −0.3
    e3 servomotor          f11 (spring constant ks (1 − fs)), +0.3
    e4 X transducer        f13 (positioner displacement sensor X (1 + 1.25 fs)), −0.3
    e5 valve               f3 (plug / seat erosion: Kv and travel up to +10 %), +1.0

Known limitations (xfail, strict): the simulated positioner closes the loop on the measured X, so
a servomotor fault (f11) does not change F for a given CV but changes the pressure the positioner
needs: its signature is (r1..r4) = (0, 1, 1, 0), the P0 sensor's column, not Table 4's (1, 0, 1,
0). The X transducer fault (f13) moves the true travel away from the measured one, so every
residual that uses CV reacts as well: r1, r2, r3 (and often r4) show it, not only Table 4's r3
and r4, and the nearest column is f_EP or f_P0. The E/P fault (f12) drives the flow loop outside
the training data (CV saturated), so r1 is mostly "unknown" (no rule) and r3 reacts besides r2,
which Table 4 excludes: it is isolated on some seeds (101) and taken for f_P0 on others (202),
hence a non-strict xfail. Valve faults that hit the travel limit (f1, f2) or choke the flow
(f7) also push r1 outside the rules and move r2; f3 (erosion) gives Table 4's (1, 0, 0, 1).
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
import pytest
from helpers import VALVE_TABLE4

from diag_plugin.diagnose.matrix import parse_matrix
from diag_plugin.diagnose.residuals import LowPass
from diag_plugin.diagnose.symptoms import LearnedThresholds, OnOffDelay
from diag_plugin.metrics import residual_pct
from diag_plugin.regressors import build_design
from diag_plugin.simulate import TAGS, FaultSpec, simulate_valve
from diag_plugin.training import train
from diag_plugin.workbench.model_edit import new_model

MODELS = {
    "r1": ("F", ["CV[k]", "P1[k]", "P2[k]"]),
    "r2": ("P0", ["CV[k]"]),
    "r3": ("X", ["P0[k]"]),
    "r4": ("F", ["X[k]", "P1[k]", "P2[k]"]),
}
TRAIN_SEED, THRESHOLD_SEED = 3, 7
TEST_SEEDS = (101, 202)
ONSET = pd.Timestamp("2026-01-02", tz="UTC")
SETTLE = pd.Timedelta("1h")  # the filter and the loops settle after the onset
ON_DELAY, OFF_DELAY = 30, 30  # samples (5 min at 10 s)

LIMIT = "genuine limitation of the four residuals with a closed positioner loop: "
CASES = [
    pytest.param(
        "f_EP",
        FaultSpec("f12", 0.5, ONSET),
        # not strict: the outcome depends on the seed (isolated on 101, f_P0 on 202)
        marks=pytest.mark.xfail(
            strict=False,
            reason=LIMIT + "E/P fault: r1 mostly unknown (no rule), r3 reacts -> looks like f_P0",
        ),
    ),
    pytest.param("f_P0", FaultSpec("f14", -0.3, ONSET)),
    pytest.param(
        "f_S",
        FaultSpec("f11", 0.3, ONSET),
        marks=pytest.mark.xfail(
            strict=True, reason=LIMIT + "spring fault shows (0,1,1,0) = the P0-sensor column"
        ),
    ),
    pytest.param(
        "f_X",
        FaultSpec("f13", -0.3, ONSET),
        marks=pytest.mark.xfail(
            strict=True, reason=LIMIT + "X-sensor fault moves the true travel: r1, r2 react too"
        ),
    ),
    pytest.param("f_V", FaultSpec("f3", 1.0, ONSET)),
]


class Unit:
    """Four trained models, a low-pass, learned thresholds and on/off delays."""

    def __init__(self, tmp_path):
        frame = simulate_valve(6, seed=TRAIN_SEED)
        a, b = frame.index[0], frame.index[-1] + pd.Timedelta("10s")

        def read(x, y):
            return frame[(frame.index >= x) & (frame.index < y)]

        self.models = {}
        for test, (out, inputs) in MODELS.items():
            rb = new_model(
                tmp_path / f"{test}.toml", test, f"{out}[k]", inputs, frame=frame, tag_info=TAGS
            )
            rb.apply_training(train(rb, read, a, b).model)
            rb.save()
            self.models[test] = (rb.to_model(), out, inputs)
        ff = simulate_valve(2, seed=THRESHOLD_SEED)
        r = self.residuals(ff)
        self.thresholds = LearnedThresholds(quantile=0.999, margin=1.2).fit(r.iloc[500:])
        self.matrix = parse_matrix(VALVE_TABLE4, "valve_unit_matrix.toml")

    def residuals(self, frame: pd.DataFrame) -> pd.DataFrame:
        cols = {}
        for test, (model, out, inputs) in self.models.items():
            d = build_design(frame, inputs, f"{out}[k]")
            span = TAGS[out].hi - TAGS[out].lo
            r = residual_pct(d.y, model.predict(d.X), span)
            cols[test] = pd.Series(r, index=d.index).reindex(frame.index)
        raw = pd.DataFrame(cols)
        return pd.DataFrame(LowPass(0.01).transform(raw), index=raw.index, columns=raw.columns)

    def symptoms(self, frame: pd.DataFrame) -> pd.DataFrame:
        s = self.thresholds.transform(self.residuals(frame))
        return pd.DataFrame(OnOffDelay(ON_DELAY, OFF_DELAY).transform(s), index=frame.index)

    def isolate(self, s: pd.DataFrame) -> tuple[str | None, dict[str, float]]:
        """Most frequent nearest fault over the samples with a symptom (exact match first)."""
        a = s.to_numpy(dtype=float)
        near = self.matrix.nearest(a)
        exact = self.matrix.match(a).matched
        picks = np.where(exact.sum(axis=1) == 1, exact.argmax(axis=1), near.fault)
        picks = picks[picks >= 0]
        if picks.size == 0:
            return None, {}
        counts = np.bincount(picks, minlength=len(self.matrix.faults)) / picks.size
        share = dict(zip(self.matrix.faults, counts.round(3).tolist(), strict=True))
        return self.matrix.faults[int(counts.argmax())], share


@pytest.fixture(scope="module")
def unit(tmp_path_factory):
    return Unit(tmp_path_factory.mktemp("valve_unit"))


def test_table4_matrix_groups(unit):
    # Table 4 isolates all five faults in principle (all columns differ)
    assert unit.matrix.isolability_groups() == [[f] for f in unit.matrix.faults]


@pytest.mark.parametrize("seed", TEST_SEEDS)
def test_fault_free_gives_no_fault(unit, seed):
    s = unit.symptoms(simulate_valve(1.5, seed=seed))
    detected = (s.fillna(0) != 0).any(axis=1).iloc[500:]
    print(f"fault-free seed {seed}: false detection rate {detected.mean():.4f}")
    assert detected.mean() < 0.05


@pytest.mark.parametrize("seed", TEST_SEEDS)
@pytest.mark.parametrize("expected, spec", [tuple(c.values) for c in CASES])
def test_every_injected_fault_is_detected_without_false_alarms_before(unit, expected, spec, seed):
    """Detection holds for all five faults (isolation below is where the limits are)."""
    s = unit.symptoms(simulate_valve(1.5, seed=seed, faults=[spec]))
    before = s[(s.index >= s.index[500]) & (s.index < ONSET)]
    after = s[s.index >= ONSET + SETTLE]
    assert (before.fillna(0) != 0).any(axis=1).mean() < 0.05
    assert (after.fillna(0) != 0).any(axis=1).mean() > 0.5, f"{expected} not detected"


@pytest.mark.parametrize("seed", TEST_SEEDS)
@pytest.mark.parametrize("expected, spec", CASES)
def test_injected_fault_is_isolated(unit, expected, spec, seed):
    t0 = time.perf_counter()
    frame = simulate_valve(1.5, seed=seed, faults=[spec])
    s = unit.symptoms(frame)
    before = s[(s.index >= s.index[500]) & (s.index < ONSET)]
    after = s[s.index >= ONSET + SETTLE]
    assert (before.fillna(0) != 0).any(axis=1).mean() < 0.05
    assert (after.fillna(0) != 0).any(axis=1).mean() > 0.5, "fault not detected"
    fault, share = unit.isolate(after)
    print(f"{spec.name}:{spec.strength:+} seed {seed}: {fault} {share}", time.perf_counter() - t0)
    assert fault == expected, share
