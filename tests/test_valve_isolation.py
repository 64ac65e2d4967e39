"""Seed 001 Table 4 and rules (10)–(14) on the simulated servomotor–valve assembly (issue 9).

Four Wang–Mendel models are trained on fault-free simulated data (seed 3), thresholds are
learned on another fault-free run (seed 7), and the five faults of Table 4 are injected one at
a time on seeds never used while developing the models (101, 202). Residuals (seed 001 eq. 6,
% of span):

    r1 = F − F̂(CV[k], P1[k], P2[k])    r2 = P0 − P̂0(CV[k])
    r3 = X − X̂(P0[k])                  r4 = F − F̂(X[k], P1[k], P2[k])

Deviation from the paper: r1 and r4 also take the process pressures P1, P2. In the simulator the
flow depends strongly on the pressure drop, and F̂(CV) / F̂(X) alone leave a fault-free residual
of up to ~50 % of span (0.999 quantile), which no Table-4 fault exceeds. With P1, P2 the learned
thresholds drop to ~10 %. Lags: [k] gave the lowest held-out error for all four models.

A residual counts only where the model's rules carry at least ``MIN_SUPPORT`` of the firing
weight: at the edge of the trained region a prediction leans on neighbouring rules, and on
unseen seeds those samples gave most of the false symptoms (support < 0.9: ~95 % of the raw
threshold crossings of r1 and r4 on seeds 404 and 606). Such samples are *unknown*, never a
symptom.

**Which plant Table 4 describes.** Table 4 and rules (10)–(14) assume the open chain
U → E/P → P0 → servomotor → X → valve → F: a servomotor fault moves X for the same P0 and leaves
P0(U) alone. That is an actuator whose controller output drives the E/P converter directly,
without a positioner closing a loop on X. The simulator builds that actuator with
``ValveParams(positioner_gain=0)``; its friction is set to ``hysteresis=0.03`` (a valve with
low-friction packing: without a positioner the whole friction band shows in X(P0)). On it all
five faults are isolated (``test_table4_*``).

The simulator's default actuator has a P positioner closing its loop on the measured X, like the
Lublin actuators. There the loop changes the signatures, as the physics says it must:

* servomotor (f11): the positioner restores X by changing P0, so F(CV) does not move; the
  signature is (0, 1, 1, 0), the P0 sensor's column: the two faults form one group;
* X transducer (f13 on the positioner's feedback): the positioner follows the wrong reading,
  the true travel moves, and every residual reacts: (1, 1, 1, 1);
* E/P (f12): compensated by the loop until the positioner saturates (not tested for isolation;
  the DAMADICS literature finds it undetectable, docs/explanation/damadics.md);
* P0 sensor (f14) and valve erosion (f3): as in Table 4.

The example unit's matrix (``examples.UNIT_MATRIX``) writes that down; ``test_closed_loop_*``
checks that the observed signatures on the default actuator are these, so an expert knows
which matrix fits which plant.

Simulator faults (DABLib numbering, see diag_plugin/simulate/faults.py):
    e1 E/P transducer      f12 (E/P current i0 (1 − fs)), +0.2
    e2 P0 pressure sensor  f14 (P0 reading (1 + fs)), −0.3
    e3 servomotor          f11 (spring constant ks (1 − fs)), +0.3
    e4 X transducer        f13 (displacement sensor X (1 + 1.25 fs)), −0.3
    e5 valve               f3 (plug / seat erosion: Kv and travel up to +10 %), +1.0
Strengths of 20–30 % follow the paper's Fig. 8 (changes of 10, 20 and 30 %).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from helpers import VALVE_TABLE4

from diag_plugin.diagnose.matrix import parse_matrix
from diag_plugin.diagnose.residuals import LowPass
from diag_plugin.diagnose.symptoms import LearnedThresholds, OnOffDelay
from diag_plugin.examples.build import UNIT_MATRIX
from diag_plugin.metrics import residual_pct
from diag_plugin.regressors import build_design
from diag_plugin.simulate import TAGS, FaultSpec, simulate_valve
from diag_plugin.simulate.valve import ValveParams
from diag_plugin.training.chunked import train
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
MIN_SUPPORT = 0.9  # share of the firing weight carried by trained rules

#: Table 4's plant: no positioner, the controller output drives the E/P converter
OPEN_CHAIN = ValveParams(positioner_gain=0.0, hysteresis=0.03)

TABLE4_CASES = [
    ("f_EP", FaultSpec("f12", 0.2, ONSET)),
    ("f_P0", FaultSpec("f14", -0.3, ONSET)),
    ("f_S", FaultSpec("f11", 0.3, ONSET)),
    ("f_X", FaultSpec("f13", -0.3, ONSET)),
    ("f_V", FaultSpec("f3", 1.0, ONSET)),
]

CLOSED_LOOP_CASES = [
    ({"f_P0", "f_S"}, FaultSpec("f14", -0.3, ONSET)),
    ({"f_P0", "f_S"}, FaultSpec("f11", 0.3, ONSET)),
    ({"f_X"}, FaultSpec("f13", -0.3, ONSET)),
    ({"f_V"}, FaultSpec("f3", 1.0, ONSET)),
]


class Unit:
    """Four trained models, a low-pass, learned thresholds and on/off delays."""

    def __init__(self, tmp_path, params: ValveParams | None, matrix: str):
        self.params = params
        frame = self.simulate(6, seed=TRAIN_SEED)
        a, b = frame.index[0], frame.index[-1] + pd.Timedelta("10s")

        def read(x, y):
            return frame[(frame.index >= x) & (frame.index < y)]

        self.models = {}
        for test, (out, inputs) in MODELS.items():
            rb = new_model(
                tmp_path / f"{test}.toml", test, f"{out}[k]", inputs, frame=frame, tag_info=TAGS
            )
            rb.doc["rules"]["levels"] = 0  # the paper's fine grid alone, as Table 4 was made
            rb.edited()
            rb.apply_training(train(rb, read, a, b).model)
            rb.save()
            self.models[test] = (rb.to_model(), out, inputs)
        ff = self.simulate(2, seed=THRESHOLD_SEED)
        r = self.residuals(ff)
        self.thresholds = LearnedThresholds(quantile=0.999, margin=1.2).fit(r.iloc[500:])
        self.matrix = parse_matrix(matrix, "matrix.toml")

    def simulate(self, days: float, **kw) -> pd.DataFrame:
        return simulate_valve(days, params=self.params, **kw)

    def residuals(self, frame: pd.DataFrame) -> pd.DataFrame:
        cols = {}
        for test, (model, out, inputs) in self.models.items():
            d = build_design(frame, inputs, f"{out}[k]")
            span = TAGS[out].hi - TAGS[out].lo
            p = model.predict_detail(d.X)
            r = residual_pct(d.y, np.where(p.support >= MIN_SUPPORT, p.y, np.nan), span)
            cols[test] = pd.Series(r, index=d.index).reindex(frame.index)
        raw = pd.DataFrame(cols)
        return pd.DataFrame(LowPass(0.01).transform(raw), index=raw.index, columns=raw.columns)

    def symptoms(self, frame: pd.DataFrame) -> pd.DataFrame:
        s = self.thresholds.transform(self.residuals(frame))
        return pd.DataFrame(OnOffDelay(ON_DELAY, OFF_DELAY).transform(s), index=frame.index)

    def isolate(self, s: pd.DataFrame) -> tuple[str | None, dict[str, float]]:
        """Most frequent isolated fault over the samples with a symptom.

        A sample isolates a fault when that fault's column is the only one consistent with it
        (unknown tests fit anything); otherwise, when every test is known, the nearest column
        counts. A sample with a test unknown and several consistent columns is a tie, no
        isolation.
        """
        a = s.to_numpy(dtype=float)
        near = self.matrix.nearest(a)
        m = self.matrix.match(a)
        consistent = m.matched | m.unknown  # no known test contradicts the column
        known = np.isfinite(a).all(axis=1)
        unique = consistent.sum(axis=1) == 1
        picks = np.where(unique, consistent.argmax(axis=1), np.where(known, near.fault, -1))
        picks = picks[picks >= 0]
        if picks.size == 0:
            return None, {}
        counts = np.bincount(picks, minlength=len(self.matrix.faults)) / picks.size
        share = dict(zip(self.matrix.faults, counts.round(3).tolist(), strict=True))
        return self.matrix.faults[int(counts.argmax())], share

    def run(self, spec: FaultSpec | None, seed: int) -> tuple[pd.DataFrame, pd.DataFrame]:
        """Symptoms before the onset (after the filter's start) and once the fault settled."""
        s = self.symptoms(self.simulate(1.5, seed=seed, faults=[spec] if spec else []))
        before = s[(s.index >= s.index[500]) & (s.index < ONSET)]
        return before, s[s.index >= ONSET + SETTLE]


def detected(s: pd.DataFrame) -> float:
    """Share of samples with at least one active symptom (unknown counts as none)."""
    return float((s.fillna(0) != 0).any(axis=1).mean())


@pytest.fixture(scope="module")
def table4_unit(tmp_path_factory):
    return Unit(tmp_path_factory.mktemp("open_chain"), OPEN_CHAIN, VALVE_TABLE4)


@pytest.fixture(scope="module")
def closed_unit(tmp_path_factory):
    return Unit(tmp_path_factory.mktemp("closed_loop"), None, UNIT_MATRIX)


def test_table4_matrix_groups(table4_unit):
    # Table 4 isolates all five faults in principle (all columns differ)
    assert table4_unit.matrix.isolability_groups() == [[f] for f in table4_unit.matrix.faults]


def test_closed_loop_matrix_merges_p0_sensor_and_servomotor():
    # the example unit's matrix (Table 4 for a positioner loop on X): S and P0 are one group
    m = parse_matrix(UNIT_MATRIX, "valve_unit.matrix.toml")
    assert m.isolability_groups() == [["f_EP"], ["f_P0", "f_S"], ["f_X"], ["f_V"]]


@pytest.mark.parametrize("seed", TEST_SEEDS)
@pytest.mark.parametrize("plant", ["table4_unit", "closed_unit"])
def test_fault_free_gives_no_fault(request, plant, seed):
    before, after = request.getfixturevalue(plant).run(None, seed)
    rate = detected(pd.concat([before, after]))
    print(f"{plant}, fault-free seed {seed}: false detection rate {rate:.4f}")
    assert rate < 0.05


@pytest.mark.parametrize("seed", TEST_SEEDS)
@pytest.mark.parametrize("expected, spec", TABLE4_CASES)
def test_table4_fault_is_isolated(table4_unit, expected, spec, seed):
    before, after = table4_unit.run(spec, seed)
    assert detected(before) < 0.05
    assert detected(after) > 0.5, f"{expected} not detected"
    fault, share = table4_unit.isolate(after)
    print(f"open chain {spec.name}:{spec.strength:+} seed {seed}: {fault} {share}")
    assert fault == expected, share
    assert share[expected] > 0.7, share


@pytest.mark.parametrize("seed", TEST_SEEDS)
@pytest.mark.parametrize(
    "spec", [FaultSpec("f12", 0.5, ONSET)] + [spec for _, spec in CLOSED_LOOP_CASES]
)
def test_closed_loop_fault_is_detected_without_false_alarms_before(closed_unit, spec, seed):
    before, after = closed_unit.run(spec, seed)
    assert detected(before) < 0.05
    assert detected(after) > 0.5, f"{spec.name} not detected"


@pytest.mark.parametrize("seed", TEST_SEEDS)
@pytest.mark.parametrize("expected, spec", CLOSED_LOOP_CASES)
def test_closed_loop_signatures(closed_unit, expected, spec, seed):
    """The closed positioner loop gives the signatures the physics predicts, not Table 4's."""
    _, after = closed_unit.run(spec, seed)
    fault, share = closed_unit.isolate(after)
    print(f"closed loop {spec.name}:{spec.strength:+} seed {seed}: {fault} {share}")
    assert fault in expected, share


@pytest.fixture(scope="module")
def shipped_t4_runs():
    """The shipped ``valve_t4`` unit (Table 4 as printed, ``rulebases/``) run through the
    product's Unit on seeds never used while building or checking it (701, 702)."""
    from pathlib import Path

    from diag_plugin.diagnose.unit import Unit

    path = Path(__file__).resolve().parents[1] / "rulebases" / "valve_t4.unit.toml"
    out = {}
    for seed in (701, 702):
        for expected, spec in [(None, None), *TABLE4_CASES]:
            frame = simulate_valve(1.5, seed=seed, params=OPEN_CHAIN, faults=[spec] if spec else [])
            d = Unit.load(path).evaluate(frame)
            out[seed, expected] = (frame.index, np.asarray(d.status), list(d.faults))
    return out


@pytest.mark.parametrize("seed", (701, 702))
def test_the_shipped_table4_unit_isolates_five_singletons_on_unseen_seeds(shipped_t4_runs, seed):
    """Seed 001's Table 4 as a shipped unit on the plant it describes: each of the five faults
    isolated as itself (a singleton) more often than anything else after it settles, and in the
    isolated set mostly; no FAILURE before any onset, nor on the fault-free run."""
    for expected, _ in [(None, None), *TABLE4_CASES]:
        idx, status, faults = shipped_t4_runs[seed, expected]
        before = (idx >= idx[500]) & (idx < ONSET)
        assert not (status[before] == 1).any(), (seed, expected)
        after = np.flatnonzero(idx >= ONSET + SETTLE)
        if expected is None:
            assert not (status[after] == 1).any(), seed
            continue
        failing = [faults[i] for i in after if status[i] == 1]
        assert len(failing) > 0.5 * after.size, (seed, expected, len(failing))
        # the fault itself, alone, is the most frequent isolation, and the isolated set holds
        # it mostly (the unit runs rules (10)-(14); seed 701: E/P FAILURE in 71 % of the
        # samples, alone in all of them; valve 74 %, alone in 67 %)
        assert max(set(failing), key=failing.count) == expected, (seed, expected)
        held = sum(expected in f.split("|") for f in failing) / len(failing)
        assert held > 0.8, (seed, expected, held)
