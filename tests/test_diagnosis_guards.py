"""What a unit reports, pinned where a small slip in the run-time diagnosis would change it
(issue 28): the NE 107 status a unit file's ``[faults]`` table declares and the NAMUR priority
between them, the published quality of a symptom held over a gap, the hold itself, the
Butterworth filter across a gap of exactly ``max_gap`` samples, a sign change as new evidence
for a held isolation, the sign of the residual, and isolation of the best signature.

Every check runs on a small unit built here, whose models are exact (``Yi = X``), so the
residual of each test is the offset the test puts on ``Yi`` (% of a 0–100 span), and every
scenario is evaluated the three ways a user runs a unit: one pass over a window
(``diag diagnose``), one row per cycle (the live loop) and :class:`Plant` (many units per
cycle), which must agree. Each was shown to fail on the slip it guards against (see
docs/reference/testing.md).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.unit import Unit, concat
from diag_plugin.diagnose.unitfile import UnitError
from diag_plugin.status import NE107

TESTS = ("r1", "r2", "r3", "r4")
#: NAMUR NE 107: the status shown when several apply, most severe first
NAMUR_ORDER = (
    NE107.FAILURE,
    NE107.CHECK_FUNCTION,
    NE107.OFF_SPEC,
    NE107.MAINTENANCE_REQUIRED,
)
#: f_A and f_B share one signature (one isolability group); f_C is seen by r2 alone
GROUP_MATRIX = {"f_A": "1000", "f_B": "1000", "f_C": "0100"}

_MODEL = """\
[model]
name = "id_y{i}"
description = "Y{i} = X, exact"
method = "wm-avg"
shape = "triangular"
period = "10s"

[output]
spec = "Y{i}[k]"
label = "Y"
unit = "%"
span = [0.0, {span}]
sets = 2

[[inputs]]
spec = "X[k]"
label = "X"
unit = "%"
span = [0.0, {span}]
sets = 2

[training]

[rules]
list = [
    {{ if = ["X0"], then = 0.0, n = 10, sd = 0.0, lock = false }},
    {{ if = ["X1"], then = {span}, n = 10, sd = 0.0, lock = false }},
]
"""


def make_unit(
    folder: Path,
    matrix: dict[str, str] | None = None,
    *,
    faults: dict[str, str] | None = None,
    span: float = 100.0,
    high: float | None = 1.0,
    low: float | None = None,
    **evaluation,
) -> Path:
    """A unit of four tests ``ri: Yi = f(X)`` with thresholds ±``high`` % (None: not learned
    yet), no filter and on/off delays of 3 unless ``evaluation`` says otherwise; ``matrix``:
    fault → one entry per test (``"1"``, ``"0"``, ``"+"``, ``"-"``, ``"x"``); ``faults``: the
    ``[faults]`` table."""
    for i in range(1, 5):
        (folder / f"id_y{i}.toml").write_text(_MODEL.format(i=i, span=span))
    ev = {"lowpass": 0.0, "on_delay": 3, "off_delay": 3} | evaluation
    lines = ["[unit]", 'name = "u"']
    if matrix is not None:
        lines.append('matrix = "u.matrix.toml"')
        rows = ",\n".join(
            f'  {{ test = "{t}", row = [{", ".join(repr(e[k]) for e in matrix.values())}] }}'
            for k, t in enumerate(TESTS)
        )
        (folder / "u.matrix.toml").write_text(
            f"[matrix]\ntests = {list(TESTS)!r}\nfaults = {list(matrix)!r}\nrows = [\n{rows}\n]\n"
        )
    lines.append("[evaluation]")
    lines += [f"{k} = {str(v).lower() if isinstance(v, bool) else repr(v)}" for k, v in ev.items()]
    lines.append("[tests]")
    th = "" if high is None else f", high = {high}"
    th += "" if low is None else f", low = {low}"
    lines += [f'{t} = {{ model = "id_y{i}.toml"{th} }}' for i, t in enumerate(TESTS, 1)]
    if faults:
        lines.append("[faults]")
        lines += [f'{f} = "{s}"' for f, s in faults.items()]
    path = folder / "u.unit.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def frame(n: int, x: float = 40.0, **offsets) -> pd.DataFrame:
    """``n`` samples of X and ``Yi = X + offset`` (scalar or per sample; NaN = missing)."""
    idx = pd.date_range("2026-03-01", periods=n, freq="10s", tz="UTC", name="ts")
    cols = {"X": np.full(n, x)}
    for i, t in enumerate(TESTS, 1):
        cols[f"Y{i}"] = x + np.broadcast_to(np.asarray(offsets.get(t, 0.0), float), (n,))
    return pd.DataFrame(cols, index=idx)


def diagnose(path: Path, data: pd.DataFrame) -> pd.DataFrame:
    """Status, quality, faults and residuals per sample as one pass, one row per cycle and a
    plant give them; asserts the three agree and returns the one-pass table."""
    unit = Unit.load(path)
    one = unit.evaluate(data).to_frame()
    unit.reset()
    cycles = concat([unit.evaluate(data.iloc[i : i + 1]) for i in range(len(data))]).to_frame()
    pd.testing.assert_frame_equal(cycles, one)
    plant = Plant.load([path], path.parent)
    rows = []
    for ts, row in data.iterrows():
        (st,) = plant.cycle(ts, row.to_dict())
        rows.append(
            {
                "status": int(st.status),
                "quality": st.quality.name,
                "faults": "|".join(st.faults),
                **{f"r_{t}": st.residuals[t] for t in TESTS},
            }
        )
    fleet = pd.DataFrame(rows, index=data.index)
    want = one[fleet.columns].astype({"status": int})
    pd.testing.assert_frame_equal(fleet, want, check_names=False, atol=1e-9)
    return one


def statuses(table: pd.DataFrame) -> list[NE107]:
    return [NE107(int(s)) for s in table["status"]]


# ---------------------------------------------------------------- status per fault, priority
@pytest.mark.parametrize(
    "declared",
    [
        {},
        {"f_C": "MAINTENANCE_REQUIRED"},
        {"f_C": "OFF_SPEC"},
        {"f_C": "CHECK_FUNCTION"},
        {"f_C": "FAILURE", "f_A": "MAINTENANCE_REQUIRED"},
    ],
)
def test_an_isolated_fault_reports_the_status_its_unit_file_declares(tmp_path, declared):
    path = make_unit(tmp_path, GROUP_MATRIX, faults=declared)
    got = diagnose(path, frame(20, r2=5.0))  # r2 alone: f_C
    assert (got["faults"].iloc[2:] == "f_C").all()
    want = NE107[declared.get("f_C", "FAILURE")]
    assert statuses(got)[:2] == [NE107.NORMAL] * 2
    assert set(statuses(got)[2:]) == {want}


@pytest.mark.parametrize(
    "a, b",
    [(a, b) for i, a in enumerate(NAMUR_ORDER) for b in NAMUR_ORDER[i + 1 :]],
    ids=lambda s: s.name,
)
def test_faults_isolated_together_report_the_most_severe_status_in_namur_order(tmp_path, a, b):
    """f_A and f_B cannot be told apart: the unit shows the status that comes first in
    NE 107's order (failure, function check, off-spec, maintenance), whichever fault
    declares it."""
    for fa, fb in ((a, b), (b, a)):
        path = make_unit(tmp_path, GROUP_MATRIX, faults={"f_A": fa.name, "f_B": fb.name})
        got = diagnose(path, frame(10, r1=5.0))
        assert (got["faults"].iloc[2:] == "f_A|f_B").all()
        assert set(statuses(got)[2:]) == {a}, (fa.name, fb.name)


def test_an_isolated_fault_with_a_test_unknown_stays_a_failure(tmp_path):
    """A fault isolated while another test cannot be evaluated (its reading lost) is still
    reported as the fault, with Uncertain quality: an unknown test never hides a fault."""
    path = make_unit(tmp_path, GROUP_MATRIX)
    r4 = np.r_[np.zeros(10), np.full(30, np.nan)]
    got = diagnose(path, frame(40, r1=5.0, r4=r4))
    late = got.iloc[20:]
    assert (late["faults"] == "f_A|f_B").all()
    assert set(statuses(late)) == {NE107.FAILURE}
    assert set(late["quality"]) == {"UNCERTAIN"}
    assert set(got["quality"].iloc[:10]) == {"GOOD"}


# ---------------------------------------------------------------- a brief gap
def test_a_symptom_held_over_a_short_gap_is_published_uncertain(tmp_path):
    """A test unknown for fewer samples than the on-delay keeps its last symptom, so the
    status holds; but the diagnosis was not made on those samples: Uncertain, then Good
    again as soon as the test is evaluated."""
    path = make_unit(tmp_path, GROUP_MATRIX, on_delay=5, off_delay=5)
    r1 = np.full(30, 5.0)
    r1[[15, 16]] = np.nan
    got = diagnose(path, frame(30, r1=r1))
    q = list(got["quality"])
    assert q[14] == "GOOD" and q[15:17] == ["UNCERTAIN"] * 2 and q[17] == "GOOD"
    assert set(statuses(got)[4:]) == {NE107.FAILURE}
    assert (got["faults"].iloc[4:] == "f_A|f_B").all()


@pytest.mark.parametrize("level", [5.0, 0.0], ids=["fault", "fault-free"])
def test_a_gap_of_on_delay_minus_one_samples_keeps_the_status(tmp_path, level):
    """The last known symptom is held for up to on_delay − 1 unknown samples (a gap no
    symptom could have turned on in): the unit keeps its status through such a gap and shows
    CHECK_FUNCTION from the on_delay-th unknown sample on."""
    on = 5
    path = make_unit(tmp_path, GROUP_MATRIX, on_delay=on, off_delay=on)
    before = NE107.FAILURE if level else NE107.NORMAL
    for gap, unknown_from in ((on - 1, None), (on, on - 1)):
        r1 = np.full(40, level)
        r1[20 : 20 + gap] = np.nan
        st = statuses(diagnose(path, frame(40, r1=r1)))
        held = st[20 : 20 + gap] if unknown_from is None else st[20 : 20 + unknown_from]
        assert set(st[10:20]) == {before} and set(held) == {before}, (gap, st[18:28])
        if unknown_from is not None:
            assert st[20 + unknown_from] == NE107.CHECK_FUNCTION, (gap, st[18:28])
        assert set(st[20 + gap :]) == {before}, (gap, st[18:28])


# ---------------------------------------------------------------- the filter across a gap
@pytest.mark.parametrize("gap, restarts", [(100, False), (101, True)])
def test_the_filter_restarts_only_after_a_gap_longer_than_its_memory(tmp_path, gap, restarts):
    """The Butterworth filter (π/100) holds its state over a gap of up to 100 unknown samples
    (about its memory) and starts from rest after a longer one. A standing +5 % residual
    therefore comes back at +5 % after a 100-sample gap, the fault still shown, and from
    almost nothing after a 101-sample gap — whether the unit sees the data in one pass, one
    row per cycle, or in pieces cut inside the gap."""
    path = make_unit(tmp_path, GROUP_MATRIX, lowpass=0.01, on_delay=3, off_delay=3)
    n0 = 800  # the filter settles on the +5 % residual (within 3e-5 of it)
    r1 = np.full(n0 + gap + 10, 5.0)
    r1[n0 : n0 + gap] = np.nan
    data = frame(len(r1), r1=r1)
    got = diagnose(path, data)
    back = got["r_r1"].iloc[n0 + gap]
    assert got["r_r1"].iloc[n0 - 1] == pytest.approx(5.0, abs=1e-3)
    assert got["r_r1"].iloc[n0 : n0 + gap].isna().all()
    if restarts:
        assert 0 < back < 1e-3
        assert statuses(got)[n0 + gap + 3] == NE107.NORMAL  # off after the off-delay
    else:
        assert back == pytest.approx(5.0, abs=1e-3)
        assert set(statuses(got)[n0 + gap :]) == {NE107.FAILURE}
    unit = Unit.load(path)
    cut = n0 + gap // 2
    pieces = concat([unit.evaluate(data.iloc[:cut]), unit.evaluate(data.iloc[cut:])])
    pd.testing.assert_frame_equal(pieces.to_frame(), got)


# ---------------------------------------------------------------- isolation
def test_a_sign_change_is_new_evidence_for_a_held_isolation(tmp_path):
    """f_A moves r3 down, f_B up. r3 going from +5 % to −5 % while r2 stays on is new
    evidence: the diagnosis moves from f_B to f_A, it is not widened to both as fading
    symptoms would be."""
    signed = {"f_A": "01-0", "f_B": "01+0"}
    path = make_unit(tmp_path, signed, on_delay=1, off_delay=1)
    r3 = np.r_[np.full(10, 5.0), np.full(10, -5.0)]
    got = diagnose(path, frame(20, r2=5.0, r3=r3))
    assert (got["faults"].iloc[:10] == "f_B").all()
    assert (got["faults"].iloc[10:] == "f_A").all(), list(got["faults"])


def test_the_residual_keeps_its_sign(tmp_path):
    """Residual = (measured − model) / span · 100 % (Kościelny et al., eq. 6): a reading
    above the model is a positive residual and a + symptom, below it a negative one and a −
    symptom, and the isolated fault follows the sign."""
    signed = {"f_low": "-000", "f_high": "+000"}
    path = make_unit(tmp_path, signed, span=200.0)
    r1 = np.r_[np.full(10, 6.0), np.full(10, -6.0)]
    got = diagnose(path, frame(20, x=80.0, r1=r1))
    np.testing.assert_allclose(got["r_r1"], np.r_[np.full(10, 3.0), np.full(10, -3.0)])
    assert list(got["s_r1"].iloc[[5, 19]]) == [1.0, -1.0]
    assert got["faults"].iloc[5] == "f_high" and got["faults"].iloc[19] == "f_low"


def test_the_best_signature_is_isolated_not_a_near_one(tmp_path):
    """r1 and r2 on: f_AB's signature matches exactly; f_A and f_ABC are one test off
    (certainty 0.75, above the unit's 0.5) and f_D three tests off. Only f_AB is isolated;
    with two signatures equally best, both are."""
    mx = {"f_A": "1000", "f_AB": "1100", "f_ABC": "1110", "f_D": "0001"}
    path = make_unit(tmp_path, mx)
    got = diagnose(path, frame(10, r1=5.0, r2=5.0))
    assert (got["faults"].iloc[2:] == "f_AB").all(), got["faults"].value_counts()
    c = got.iloc[-1]
    assert (c["c_f_AB"], c["c_f_A"], c["c_f_ABC"], c["c_f_D"]) == (1.0, 0.75, 0.75, 0.25)
    tie = {"f_A": "1000", "f_ABC": "1110", "f_D": "0001"}
    got = diagnose(make_unit(tmp_path, tie), frame(10, r1=5.0, r2=5.0))
    assert (got["faults"].iloc[2:] == "f_A|f_ABC").all(), got["faults"].value_counts()
    # a certainty exactly at the unit's limit counts ("from this certainty on")
    got = diagnose(make_unit(tmp_path, tie, certainty=0.75), frame(10, r1=5.0, r2=5.0))
    assert (got["faults"].iloc[2:] == "f_A|f_ABC").all(), got["faults"].value_counts()


def test_a_new_episode_is_isolated_afresh_and_fading_to_no_signature_shows_none(tmp_path):
    """f_B (r2 and r3) fades: r3 clears first and r2 alone would point at f_A, so f_B stays
    beside it (the held isolation widens, it does not jump) until no symptom is left. A new
    episode starts afresh: r2 alone is then f_A only. Symptoms no signature explains well
    enough (certainty below the unit's 0.5) isolate nothing, held or not: OFF_SPEC."""
    path = make_unit(
        tmp_path, {"f_A": "0100", "f_B": "0110", "f_C": "1111"}, on_delay=1, off_delay=1
    )
    r2 = np.r_[np.full(5, 5.0), np.full(5, 5.0), np.zeros(5), np.full(5, 5.0)]
    r3 = np.r_[np.full(5, 5.0), np.zeros(15)]
    got = diagnose(path, frame(20, r2=r2, r3=r3))
    assert list(got["faults"].iloc[[0, 5, 10, 15]]) == ["f_B", "f_A|f_B", "", "f_A"]
    assert statuses(got)[10] == NE107.NORMAL
    # all four on: f_C; fading to r1 alone, f_C and f_D are three tests off (0.25)
    path = make_unit(tmp_path, {"f_C": "1111", "f_D": "0011"}, on_delay=1, off_delay=1)
    on = np.r_[np.full(5, 5.0), np.zeros(5)]
    got = diagnose(path, frame(10, r1=5.0, r2=on, r3=on, r4=on))
    assert (got["faults"].iloc[:5] == "f_C").all()
    assert (got["faults"].iloc[5:] == "").all(), list(got["faults"])
    assert set(statuses(got)[5:]) == {NE107.OFF_SPEC}


def test_fuzzy_symptoms_give_the_same_diagnosis_in_a_plant_as_alone(tmp_path):
    """Three-valued fuzzy evaluation (Kościelny et al.): with threshold 2 % and a ramp
    0.5 · 2 % wide, a residual of +2.2 % is P to 0.7 and −2.2 % is N to 0.7, so f_high (resp.
    f_low) has certainty 0.7: below the unit's 0.8, nothing is isolated (OFF_SPEC). The live
    loop evaluates units in a Plant, which must give that too (it isolated by the crisp
    nearest signature, certainty 1, and reported FAILURE)."""
    signed = {"f_low": "-000", "f_high": "+000"}
    fuzzy = {"symptoms": "fuzzy", "fuzzy_width": 0.5, "high": 2.0}
    path = make_unit(tmp_path, signed, certainty=0.8, **fuzzy)
    r1 = np.r_[np.full(10, 2.2), np.full(10, -2.2)]
    got = diagnose(path, frame(20, r1=r1))
    np.testing.assert_allclose(got["c_f_high"].iloc[5:10], 0.7)
    np.testing.assert_allclose(got["c_f_low"].iloc[15:], 0.7)
    st = statuses(got)
    assert set(st[5:10] + st[15:]) == {NE107.OFF_SPEC} and (got["faults"] == "").all()
    got = diagnose(make_unit(tmp_path, signed, certainty=0.6, **fuzzy), frame(20, r1=r1))
    assert list(got["faults"].iloc[[9, 19]]) == ["f_high", "f_low"]
    # asymmetric thresholds: the ramps sit at each threshold (−1 % and +3 %, K = 2 %)
    path = make_unit(tmp_path, signed, certainty=0.8, **(fuzzy | {"high": 3.0, "low": -1.0}))
    got = diagnose(path, frame(20, r1=np.r_[np.full(10, 3.2), np.full(10, -1.2)]))
    np.testing.assert_allclose(got["c_f_high"].iloc[5:10], 0.7)
    np.testing.assert_allclose(got["c_f_low"].iloc[15:], 0.7)
    # a fuzzy unit whose thresholds are not learned yet says so, like a crisp one
    unit = Unit.load(make_unit(tmp_path, signed, symptoms="fuzzy", high=None))
    d = unit.evaluate(frame(5, r1=5.0))
    assert set(d.status) == {NE107.CHECK_FUNCTION} and "diag unit learn u" in d.message
    path = make_unit(tmp_path, signed)
    path.write_text(path.read_text().replace('"id_y2.toml", high = 1.0', '"id_y2.toml"'))
    d = Unit.load(path).evaluate(frame(5, r1=5.0))
    assert d.message.startswith("no thresholds for r2:"), d.message


def test_a_symptom_of_the_other_sign_waits_for_its_on_delay(tmp_path):
    """r1 flips from +5 % to −5 %: the + symptom goes after the off-delay (1 sample) and the
    − symptom comes after its own on-delay (2 samples), not at once."""
    path = make_unit(tmp_path, {"f_low": "-000", "f_high": "+000"}, on_delay=2, off_delay=1)
    r1 = np.r_[np.full(6, 5.0), np.full(6, -5.0)]
    got = diagnose(path, frame(12, r1=r1))
    assert list(got["s_r1"]) == [0, 1, 1, 1, 1, 1, 0, -1, -1, -1, -1, -1]


def test_a_latched_symptom_keeps_the_sign_it_was_raised_with(tmp_path):
    """latch = true (Laukonen et al.: a symptom stays for the rest of the test): r1 raised +,
    then gone, then −: the unit keeps reporting the + symptom and its fault."""
    path = make_unit(tmp_path, {"f_low": "-000", "f_high": "+000"}, latch=True)
    r1 = np.r_[np.zeros(3), np.full(5, 5.0), np.zeros(5), np.full(7, -5.0)]
    got = diagnose(path, frame(20, r1=r1))
    assert (got["s_r1"].iloc[:5] == 0).all()  # on at the third sample over the threshold
    assert (got["s_r1"].iloc[5:] == 1).all() and (got["faults"].iloc[5:] == "f_high").all()


def test_the_timeline_names_each_run_and_the_tests_showing_symptoms(tmp_path):
    """``diag diagnose`` prints runs of equal status and faults, with the tests that had a
    symptom in each run."""
    path = make_unit(tmp_path, GROUP_MATRIX)
    r1 = np.r_[np.zeros(4), np.full(6, 5.0), np.zeros(10)]
    runs = Unit.load(path).evaluate(frame(20, r1=r1)).intervals()
    assert list(runs["status"]) == ["NORMAL", "FAILURE", "NORMAL"]
    assert list(runs["faults"]) == ["", "f_A|f_B", ""]
    assert list(runs["samples"]) == [6, 6, 8]  # on 3 samples late, off 3 samples late
    assert list(runs["tests"]) == ["", "r1", ""]
    assert runs["to"].iloc[0] == runs["from"].iloc[1]


def test_the_published_numbers_are_ne107s_and_the_register_maps(tmp_path):
    """The HMI reads numbers: NE 107 as in the OPC UA device model (DESIGN.md: 0 NORMAL,
    1 FAILURE, 2 CHECK_FUNCTION, 3 OFF_SPEC, 4 MAINTENANCE_REQUIRED) and the quality of the
    diagnosis (docs/reference/connectors.md: 0 Good, 1 Uncertain, 2 Bad)."""
    path = make_unit(tmp_path, GROUP_MATRIX, faults={"f_C": "MAINTENANCE_REQUIRED"})
    nan = np.nan
    r1 = np.r_[np.zeros(5), np.full(10, 5.0), np.zeros(15)]
    r2 = np.r_[np.zeros(20), np.full(10, 5.0)]
    r3 = np.r_[np.zeros(15), np.full(15, nan)]
    r4 = np.r_[np.full(20, 0.0), np.full(10, nan)]
    d = Unit.load(path).evaluate(frame(30, r1=r1, r2=r2, r3=r3, r4=r4))
    published = {(s := d.at(i).to_json())["status_name"]: s["status"] for i in range(30)}
    assert published == {"NORMAL": 0, "FAILURE": 1, "CHECK_FUNCTION": 2, "MAINTENANCE_REQUIRED": 4}
    quality = {d.at(i).quality.name: int(d.at(i).quality) for i in range(30)}
    assert quality == {"GOOD": 0, "UNCERTAIN": 1}
    assert int(d.at(-1).quality) == 1  # r3, r4 unknown, r2's symptom isolated: f_C
    bad = Unit.load(path).evaluate(frame(3, x=nan))
    assert [int(q) for q in bad.quality] == [2, 2, 2] and set(bad.status) == {2}
    js = json.loads(json.dumps(d.at(-1).to_json()))  # NaN is null, numbers stay numbers
    assert js["residuals"] == {"r1": 0.0, "r2": 5.0, "r3": None, "r4": None}
    assert js["symptoms"] == {"r1": 0.0, "r2": 1.0, "r3": None, "r4": None}
    off = Unit.load(make_unit(tmp_path, None)).evaluate(frame(5, r1=5.0))  # no matrix
    assert int(off.at(-1).status) == 3 and off.at(-1).to_json()["status_name"] == "OFF_SPEC"


def test_learning_a_unit_scaled_by_the_signal_maximum(tmp_path, capsys):
    """``diag unit learn`` on a unit with ``scale = "max"`` (Laukonen et al., Sec. IV) writes
    each output's maximum |y| over the window beside its thresholds and reports the window
    it learned over, end exclusive; an output that stays at zero has no maximum to scale by:
    a clear error and a failing exit status."""
    from diag_plugin.cli import main
    from historian.store import Historian

    path = make_unit(tmp_path, GROUP_MATRIX, high=None, scale="max")
    rng = np.random.default_rng(5)
    data = frame(600, x=30.0, **{t: rng.normal(0, 0.5, 600) for t in TESTS})
    data.loc[data.index[100], "Y3"] = -70.0  # the largest |Y3|, negative
    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian.open(url) as h:
        h.write_samples(data)
    args = ["--db", url, "--rulebases", str(tmp_path), "unit", "learn", "u", "--json"]
    args += ["--cross-fit", "no"]  # hand-made identity models: nothing to cross-fit
    window = ["--from", "2026-03-01T00:00", "--to", "2026-03-02T00:00"]
    assert main(args + window) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["window"] == ["2026-03-01T00:00:00+00:00", "2026-03-02T00:00:00+00:00"]
    learned = Unit.load(path).file
    for i, t in enumerate(TESTS, 1):
        want = 70.0 if t == "r3" else data[f"Y{i}"].abs().max()
        assert learned.test(t).ymax == pytest.approx(want, abs=1e-6), t
    got = diagnose(path, data.iloc[:20])  # residuals now in % of each output's maximum
    np.testing.assert_allclose(got["r_r3"], (data["Y3"] - data["X"]).iloc[:20] / 70.0 * 100)
    path = make_unit(tmp_path, GROUP_MATRIX, high=None, scale="max")
    with Historian.open(url) as h:
        h.write_samples(frame(600, x=0.0).shift(1, freq="1D"))
    late = ["--from", "2026-03-02T00:00", "--to", "2026-03-03T00:00"]
    assert main(args + late) != 0
    assert "the maximum of Y1 over the window is not positive" in capsys.readouterr().err


def test_a_held_isolation_narrows_with_fading_evidence(tmp_path):
    """r1, r2, r3 on: f_A and f_B are equally near (one test off each). r3 clears: f_A now
    matches exactly and f_B is two tests off, so the diagnosis narrows to f_A — a fresh
    isolation that shares a fault with the last one is taken as it is, not widened."""
    path = make_unit(tmp_path, {"f_A": "1100", "f_B": "1111"}, on_delay=1, off_delay=1)
    r3 = np.r_[np.full(5, 5.0), np.zeros(5)]
    got = diagnose(path, frame(10, r1=5.0, r2=5.0, r3=r3))
    assert list(got["faults"].iloc[[0, 4, 5, 9]]) == ["f_A|f_B", "f_A|f_B", "f_A", "f_A"]


def test_a_signature_constraining_one_test_has_certainty_zero_when_it_is_contradicted(tmp_path):
    """f_A constrains r1 alone (don't care elsewhere), f_B r2 alone. With r2 on and r1 quiet,
    f_B matches (1) and f_A is contradicted on its only test (0, not ½), so the published
    certainty of f_A is 0."""
    path = make_unit(tmp_path, {"f_A": "1xxx", "f_B": "x1xx"})
    got = diagnose(path, frame(10, r2=5.0))
    assert (got["faults"].iloc[2:] == "f_B").all()
    assert list(got[["c_f_A", "c_f_B"]].iloc[-1]) == [0.0, 1.0]


def test_a_faults_table_takes_names_or_numbers_and_refuses_others_with_a_line(tmp_path):
    """``[faults]`` entries are NE 107 names (any case) or numbers; anything else, NORMAL
    included, is a ``file:line`` problem, never a traceback."""
    path = make_unit(tmp_path, GROUP_MATRIX, faults={"f_C": "maintenance_required"})
    path.write_text(path.read_text() + "f_A = 3\n")
    got = diagnose(path, frame(10, r2=5.0))
    assert set(statuses(got)[2:]) == {NE107.MAINTENANCE_REQUIRED}
    assert set(statuses(diagnose(path, frame(10, r1=5.0)))[2:]) == {NE107.FAILURE}  # f_A|f_B
    for bad in ("7", '"BROKEN"', '"NORMAL"', "0"):
        path.write_text(make_unit(tmp_path, GROUP_MATRIX).read_text() + f"[faults]\nf_A = {bad}\n")
        with pytest.raises(UnitError) as e:
            Unit.load(path)
        line = len(path.read_text().splitlines())
        assert e.value.problems[0].startswith(f"{path}:{line}: fault 'f_A'"), e.value.problems


def test_a_unit_file_without_a_filter_setting_filters_as_seed_000_does(tmp_path):
    """Left out of [evaluation], the filter is Laukonen et al.'s: 4th-order Butterworth at
    π/100 rad/sample (scipy's wn = 0.01). A +5 % step in r1 comes out as that filter's
    step response."""
    from scipy import signal

    path = make_unit(tmp_path, GROUP_MATRIX)
    path.write_text(path.read_text().replace("lowpass = 0.0\n", ""))
    got = Unit.load(path).evaluate(frame(300, r1=5.0)).residuals["r1"].to_numpy()
    want = 5.0 * signal.sosfilt(signal.butter(4, 0.01, output="sos"), np.ones(300))
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)


def test_unit_file_limits_are_checked_and_every_problem_is_reported(tmp_path):
    path = make_unit(tmp_path, GROUP_MATRIX)
    text = path.read_text()
    for ok in ("min_support = 0.0", "min_support = 1.0"):
        path.write_text(text.replace("[evaluation]", f"[evaluation]\n{ok}"))
        Unit.load(path)
    bad = {
        "[evaluation]": "[evaluation]\ncolour = 1\nmin_support = -0.1\norder = 11",
        '"id_y1.toml", high = 1.0': '"id_y1.toml", high = 1.0, ymax = 0.0',
    }
    for old, new in bad.items():
        text = text.replace(old, new)
    path.write_text(text)
    with pytest.raises(UnitError) as e:
        Unit.load(path)
    lines = text.splitlines()

    def at(key: str) -> str:
        return f"{path}:{next(i for i, ln in enumerate(lines, 1) if ln.startswith(key))}: "

    joined = "\n".join(e.value.problems)
    assert at("colour") + "unknown key 'colour'" in joined
    assert at("min_support") + "min_support must be in [0, 1]" in joined
    assert at("order") + "order must be 1..10" in joined
    assert at("r1 =") + "test 'r1': ymax must be > 0" in joined
    # a test without a model does not hide the problems of the tests after it
    text = text.replace('r2 = { model = "id_y2.toml", high = 1.0 }', "r2 = { high = 1.0 }")
    text = text.replace('"id_y3.toml", high = 1.0', '"id_y3.toml", high = -1.0')
    path.write_text(text)
    with pytest.raises(UnitError) as e:
        Unit.load(path)
    joined = "\n".join(e.value.problems)
    assert "test 'r2': model must name a rule-base file" in joined
    assert "test 'r3': high must be > 0" in joined


def test_a_unit_file_error_is_said_once_with_one_line_number(tmp_path):
    """Issue 37: a TOML syntax error in a unit file carried our file:line and the parser's own
    'at line L col C'; a threshold given as text also drew 'low given without high', which
    was not the problem. Each is now one message at one line."""
    path = make_unit(tmp_path, GROUP_MATRIX, high=1.0, low=-1.0)
    good = path.read_text()
    lines = good.splitlines()
    r1, r2 = (next(i for i, ln in enumerate(lines, 1) if ln.startswith(t)) for t in ("r1", "r2"))
    path.write_text(good.replace("high = 1.0, low", "high = 1.0 low", 1))
    with pytest.raises(UnitError) as e:
        Unit.load(path)
    (p,) = e.value.problems
    assert p.startswith(f"{path}:{r1}: TOML syntax error: "), p
    assert "line" not in p.split("TOML syntax error")[1] and p.endswith(")"), p
    path.write_text(good.replace('id_y2.toml", high = 1.0', 'id_y2.toml", high = "high"', 1))
    with pytest.raises(UnitError) as e:
        Unit.load(path)
    assert e.value.problems == [f"{path}:{r2}: test 'r2': high must be a finite number, got 'high'"]
    # a low with no high at all is still refused
    path.write_text(good.replace('id_y2.toml", high = 1.0, ', 'id_y2.toml", ', 1))
    with pytest.raises(UnitError) as e:
        Unit.load(path)
    assert e.value.problems == [f"{path}:{r2}: test 'r2': low given without high"]


def test_diag_unit_new_never_overwrites_unasked_and_show_prints_the_matrix(tmp_path, capsys):
    """A unit file is edited by hand: ``diag unit new`` over an existing one refuses unless
    told ``--force``. ``diag unit show`` of a unit without thresholds yet prints them as
    "—" and prints the matrix row by row."""
    from diag_plugin.cli import main

    path = make_unit(tmp_path, GROUP_MATRIX, high=None)
    edited = path.read_text() + "# the expert's note\n"
    path.write_text(edited)
    base = ["--rulebases", str(tmp_path), "unit"]
    new = ["new", "u", "--matrix", "u.matrix.toml"]
    new += [a for i, t in enumerate(TESTS, 1) for a in ("--model", f"{t}=id_y{i}")]
    assert main(base + new) != 0
    assert "exists (use --force to overwrite)" in capsys.readouterr().err
    assert path.read_text() == edited
    path.write_text(edited)
    assert main(base + ["show", "u"]) == 0
    out = capsys.readouterr().out
    assert "no thresholds learned yet" in out and out.count("—") >= 8  # low, high × 4 tests
    rows = [ln for ln in out.splitlines() if ln.strip(" │|").startswith(TESTS)]
    assert len(rows) >= 8, out  # the tests table and the matrix table
    assert main(base + new + ["--force"]) == 0
    assert "# the expert's note" not in path.read_text()
