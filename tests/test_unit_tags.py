"""The unit-level combined test and isolation to tags (issue 25).

A synthetic coupled process of six tags (two driven inputs A, B; C, D, E, F computed from them
in a chain, each measured with its own noise) and a unit of five wm-avg models trained in the
test on 14 fault-free days (one per tag but B, from the tags the process couples it to). Judged
on seeds never used to build or learn it:

* the derived matrix is the models' structure, exactly;
* fault-free, the combined test's false alarms stay within a factor 3 of its share of the budget;
* a coordinated small shift of two tags that no single test crosses its threshold for is
  detected by the combined test;
* a sensor bias on one tag ranks that tag first;
* units without the new keys behave exactly as before (their own tests, plus the checks here).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.learning import learn_thresholds
from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.status import NE107
from diag_plugin.diagnose.unit import Unit, concat
from diag_plugin.diagnose.unitfile import UnitError, UnitFile, new_unit_text
from diag_plugin.diagnose.unittags import COMBINED_SHARE, derived_matrix
from diag_plugin.training.chunked import train
from diag_plugin.workbench.model_edit import new_model

START = pd.Timestamp("2026-05-04", tz="UTC")
TAGS = {"A": (0, 100), "B": (0, 100), "C": (0, 200), "D": (0, 200), "E": (0, 300), "F": (0, 300)}
#: test → (output, inputs): each tag from the tags the process couples it to
TESTS = {
    "rA": ("A[k]", ["C[k]", "B[k]"]),
    "rC": ("C[k]", ["A[k]", "B[k]"]),
    "rD": ("D[k]", ["C[k]", "B[k]"]),
    "rE": ("E[k]", ["D[k]", "A[k]"]),
    "rF": ("F[k]", ["E[k]", "C[k]"]),
}
FAR = 0.01  # per hour, the unit's budget
DAY = 1440  # samples a day at 60 s


def process(n: int, seed: int, bias: dict[str, float] | None = None, onset: int = 0):
    """``n`` minutes of the process: A, B follow set-points held 30–240 min (5 min lags), the
    others are static couplings (one bilinear); ``bias``: sensor offsets from ``onset`` on."""
    rng = np.random.default_rng([seed, 25])

    def steps(lo: float, hi: float) -> np.ndarray:
        out = np.empty(n)
        i = 0
        while i < n:
            h = int(rng.integers(30, 240))
            out[i : i + h] = rng.uniform(lo, hi)
            i += h
        return out

    def lag(x: np.ndarray, tau: float) -> np.ndarray:
        a = math.exp(-1 / tau)
        y = np.empty_like(x)
        v = x[0]
        for k in range(len(x)):
            v = a * v + (1 - a) * x[k]
            y[k] = v
        return y

    A, B = lag(steps(20, 80), 5), lag(steps(20, 80), 5)
    C = 0.8 * A + 0.6 * B + 0.004 * A * B
    D = 1.1 * C - 0.5 * B + 40
    E = 0.7 * D + 0.9 * A + 20
    F = 0.5 * E + 0.4 * C + 30
    true = {"A": A, "B": B, "C": C, "D": D, "E": E, "F": F}
    noise = {"A": 0.4, "B": 0.4, "C": 0.8, "D": 0.8, "E": 1.0, "F": 1.0}
    idx = pd.date_range(START, periods=n, freq="60s", name="ts")
    f = pd.DataFrame({k: v + noise[k] * rng.standard_normal(n) for k, v in true.items()}, idx)
    for tag, b in (bias or {}).items():
        f.iloc[onset:, f.columns.get_loc(tag)] += b
    return f


def build(folder, frame: pd.DataFrame, evaluation: dict | None = None, matrix=None):
    """The process's models trained on ``frame`` and a unit file (no thresholds yet)."""
    from historian.taginfo import TagInfo

    folder.mkdir(parents=True, exist_ok=True)
    info = {k: TagInfo(k, unit="u", lo=lo, hi=hi, description=k) for k, (lo, hi) in TAGS.items()}
    a, b = frame.index[0], frame.index[-1] + pd.Timedelta("60s")
    names = {}
    for test, (out, ins) in TESTS.items():
        path = folder / f"p_{test}.toml"
        if not path.exists():
            rb = new_model(path, f"p_{test}", out, ins, frame=frame, tag_info=info, period="60s")
            res = train(rb, lambda x, y: frame[(frame.index >= x) & (frame.index < y)], a, b)
            rb.apply_training(res.model, {"from": a.isoformat(), "to": b.isoformat()})
            rb.save()
        names[test] = path.name
    p = folder / "p.unit.toml"
    p.write_text(new_unit_text("p", names, evaluation=evaluation, matrix=matrix))
    return p


@pytest.fixture(scope="module")
def learned(tmp_path_factory):
    """The unit with ``combined = true`` and ``isolation = "tags"``, models trained and
    thresholds learned on 14 fault-free days of seed 1 (cross-fitted), budget FAR."""
    folder = tmp_path_factory.mktemp("tags")
    window = process(14 * DAY, 1)
    path = build(folder, window, {"combined": True, "isolation": "tags"})
    got = learn_thresholds(Unit.load(path), [window], far=FAR)
    uf = UnitFile.load(path)
    uf.set_learned(got)
    uf.save()
    return Unit.load(path)


# ---------------------------------------------------------------- structure
def test_the_derived_matrix_is_the_models_structure(tmp_path):
    path = build(tmp_path, process(2 * DAY, 1), {"isolation": "tags"})
    unit = Unit.load(path)
    mx = derived_matrix(unit)
    assert unit.derived and unit.matrix.faults == mx.faults
    # outputs first in test order, then the tags only read
    assert mx.faults == ["A", "C", "D", "E", "F", "B"]
    want = {
        "rA": "1 1 0 0 0 1",  # A from C, B
        "rC": "1 1 0 0 0 1",  # C from A, B
        "rD": "0 1 1 0 0 1",  # D from C, B
        "rE": "1 0 1 1 0 0",  # E from D, A
        "rF": "0 1 0 1 1 0",  # F from E, C
    }
    for i, t in enumerate(mx.tests):
        assert " ".join(mx.entries[i]) == want[t], t
    # every column differs: each tag's sensor fault is isolable in principle
    assert mx.isolability_groups() == [[t] for t in mx.faults]


def test_an_expert_matrix_takes_precedence_and_no_keys_change_nothing(tmp_path):
    frame = process(2 * DAY, 1)
    rows = "\n".join(f'  {{ test = "{t}", row = [1, 0] }},' for t in TESTS)
    (tmp_path / "m.matrix.toml").write_text(
        f'[matrix]\ntests = {list(TESTS)}\nfaults = ["f1", "f2"]\nrows = [\n{rows}\n]\n'.replace(
            "'", '"'
        )
    )
    path = build(tmp_path, frame, {"isolation": "tags"}, matrix="m.matrix.toml")
    unit = Unit.load(path)
    assert not unit.derived and unit.faults == ["f1", "f2"]
    plain = Unit.load(build(tmp_path, frame))  # neither key: as before
    assert plain.matrix is None and plain.cmodel is None
    assert "combined" not in plain.file.path.read_text()  # the file written as before
    d = plain.evaluate(frame.iloc[:300])
    assert d.combined is None and d.top is None and d.top_tags.shape[1] == 0
    cols = list(d.to_frame().columns)
    assert not any(c in cols for c in ("T2", "s_T2", "top1")), cols
    assert "tags" not in d.at(-1).to_json()


def test_bad_keys_are_file_line_errors(tmp_path):
    path = build(tmp_path, process(2 * DAY, 1))
    text = path.read_text()
    bad = text.replace("hold_isolation = true", 'hold_isolation = true\ncombined = "yes"')
    bad = bad.replace("certainty = 0.5", 'certainty = 0.5\nisolation = "pca"')
    path.write_text(bad)
    with pytest.raises(UnitError) as exc:
        UnitFile.load(path)
    lines = bad.splitlines()
    got = "\n".join(exc.value.problems)
    at_c = lines.index('combined = "yes"') + 1
    at_i = lines.index('isolation = "pca"') + 1
    assert f":{at_c}: combined must be bool" in got
    assert f":{at_i}: isolation must be one of" in got
    bad = text + '\n[combined]\nhigh = 3.0\ntests = ["rA"]\ncenter = [0.0]\nscale = [-1.0]\n'
    bad += "cov = [[1.0]]\n"
    path.write_text(bad)
    with pytest.raises(UnitError) as exc:
        UnitFile.load(path)
    got = "\n".join(exc.value.problems)
    n = bad.splitlines().index("scale = [-1.0]") + 1
    assert f":{n}: [combined] scale must be > 0" in got
    assert "differ from the unit's tests" in got


# ---------------------------------------------------------------- the combined test
def _episodes(on: np.ndarray) -> int:
    return int(on[0]) + int((~on[:-1] & on[1:]).sum())


def test_learned_file_round_trips_and_splits_the_budget(learned):
    c = learned.file.combined
    assert c is not None and c.high > 0 and c.tests == list(TESTS)
    assert c.notes["far"] == pytest.approx(FAR * COMBINED_SHARE)
    assert all(n["far"] == pytest.approx(FAR * (1 - COMBINED_SHARE) / len(TESTS), rel=0.01)
               for n in learned.file.learned.values())  # fmt: skip
    # the gains are the models' (the rule grid flattens them) of the process's couplings,
    # D = 1.1 C − 0.5 B + 40: the signs and magnitudes
    assert 0.6 < c.gains["rD"]["C"] < 1.3
    assert -0.8 < c.gains["rD"]["B"] < -0.2
    assert learned.has_thresholds


def test_the_combined_test_is_quiet_fault_free_within_its_budget(learned):
    """Three fault-free fortnights of unseen seeds: the combined test's alarm episodes per hour
    within a factor 3 of its share of the budget, the unit's within a factor 3 of the budget."""
    hours = combined = unit = 0
    for seed in (101, 102, 103):
        d = learned.reset().evaluate(process(14 * DAY, seed))
        hours += len(d) / 60
        combined += _episodes(d.combined["s_T2"].fillna(0).to_numpy() != 0)
        alarm = d.status.to_numpy() != NE107.NORMAL
        alarm &= d.status.to_numpy() != NE107.CHECK_FUNCTION
        unit += _episodes(alarm)
    assert combined / hours <= 3 * FAR * COMBINED_SHARE, (combined, hours)
    assert unit / hours <= 3 * FAR, (unit, hours)


@pytest.mark.parametrize("seed", [201, 202])
def test_a_coordinated_small_shift_no_single_test_sees_is_detected(learned, seed):
    """D and E read 2 units high (1 % and 0.7 % of their spans) from day 1 on: no test's
    residual crosses its thresholds, the combined statistic does, and the unit is FAILURE."""
    d = learned.reset().evaluate(process(3 * DAY, seed, {"D": 2.0, "E": 2.0}, DAY))
    after = slice(DAY + 200, None)  # the low-pass settles
    tests_on = (d.symptoms.iloc[after].fillna(0) != 0).any(axis=1)
    assert tests_on.mean() < 0.02
    assert (d.combined["s_T2"].iloc[after] == 1).mean() > 0.6
    assert (d.status.iloc[after] == NE107.FAILURE).mean() > 0.6
    before = d.status.iloc[200:DAY]
    assert (before == NE107.NORMAL).all()


# ---------------------------------------------------------------- ranking
@pytest.mark.parametrize(
    "tag, bias", [("D", 3.0), ("C", 3.0), ("A", 2.0), ("F", 4.0)]
)  # 1.5 %, 1.5 %, 2 %, 1.3 % of span
def test_a_sensor_bias_ranks_its_tag_first(learned, tag, bias):
    for seed in (201, 202):
        d = learned.reset().evaluate(process(3 * DAY, seed, {tag: bias}, DAY))
        top = d.top_tags.iloc[DAY + 200 :]
        alarm = top["top1"] != ""
        assert alarm.mean() > 0.3, (tag, seed)
        assert (top["top1"][alarm] == tag).mean() > 0.8, top["top1"][alarm].value_counts()
        assert (d.faults.iloc[DAY + 200 :][alarm] != "").all()


def test_pieces_and_one_pass_agree_and_the_live_path_names_the_tags(learned):
    f = process(DAY // 2, 211, {"D": 3.0}, 0)
    one = learned.reset().evaluate(f)
    learned.reset()
    parts = concat([learned.evaluate(f.iloc[a : a + 97]) for a in range(0, len(f), 97)])
    pd.testing.assert_frame_equal(one.to_frame(), parts.to_frame())
    assert one.contributions.columns.tolist() == ["A", "C", "D", "E", "F", "B"]
    # the live loop: the unit goes one by one, its status names the top tags
    plant = Plant({"p": learned.reset()})
    assert plant.slow == ["p"]
    for ts, row in f.iloc[:300].iterrows():
        st = plant.cycle(ts, row)[0]
    assert st.status == NE107.FAILURE and st.tags and st.tags[0][0] == "D"
    assert "tags: D" in st.message and st.to_json()["tags"][0][0] == "D"
    assert st.status == one.at(299).status and st.message == one.at(299).message
