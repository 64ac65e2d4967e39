"""A tag the unit only ever saw at one value moves: CHECK_FUNCTION naming it (issue 34, item 5).

Acceptance pass on a pumping station (docs/explanation/acceptance-pumps.md): three pumps on one
header, the duty rotating once a day at 06:00 (1 → 2 → 3). A unit built at 1 s on one
fault-free day (pumps 1 and 2 ran) and judged on the next was 74–79 % in alarm from the 06:00
swap on: pump 3's run feedback and current were constant (0) over the build window, so no
test reads them, and when pump 3 takes duty the other pumps' tests alarm. Now the build records
such tags (``[fixed]``, :mod:`diag_plugin.diagnose.fixed`), the unit reads them and is
CHECK_FUNCTION where one moves, naming it, its value and since when; ``diag unit accept`` of a
day where it moved learns it. The station is written for this test, exported with timestamps
off the grid, and imported, built, diagnosed and accepted as a user would (the CLI).
"""

from __future__ import annotations

import contextlib
import json

import numpy as np
import pandas as pd
import pytest

from diag_plugin.simulate import smallplants as sp
from diag_plugin.status import NE107
from tests.test_any_plant_tour import diag, fmt, import_csv

T0 = pd.Timestamp("2026-06-01", tz="UTC")
DAY = pd.Timedelta(days=1)


def station(days: float, seed: int, bias: tuple[str, float] = ("FLOW", 0.0),
            bias_from_h: float = 0.0, schedule: str = "rotate") -> pd.DataFrame:  # fmt: skip
    """1 s samples of a station of three pumps on one header. The duty rotates at 06:00 each
    day (pump 1 until 06:00 of day 0, then 2, from 06:00 of day 1 pump 3, from 06:00 of day 2
    pump 1 again); an assist pump starts above 290 m³/h of draw and stops below 250 (pump 1
    assists pumps 2 and 3, pump 2 assists pump 1; pump 3 never assists, so a day of duties 1
    and 2 never runs it). The draw has a daily cycle, a slow walk and noise; ``SPEED`` the
    pumps' common speed (%, an operator's slow moves); the header pressure the pump curve
    ``a·n² − b·(q/N)²`` (N pumps running); each running motor's current the power of its share
    of the flow (0 when a pump stands); ``RUN1``..``RUN3`` the run feedbacks (0/1). ``bias``:
    a transmitter's (tag, bias), from hour ``bias_from_h`` of the run on. ``schedule``
    ``"night2"``: pump 1 on duty until 12:00 (pump 2 assisting at the peak), pump 3 after
    (pump 1 assisting), but from day 1 on pump 2 on duty from 00:00 to 06:00 (at night's draw
    it runs alone), and each day at 22:00 a 20 s changeover test (pump 2 alone, then pump 3
    back)."""
    rng = np.random.default_rng(seed)
    n = int(days * 86400)
    t = np.arange(n) / 86400.0
    walk = np.cumsum(rng.normal(0, 0.0003, n))
    demand = 240 + 80 * np.sin(2 * np.pi * (t - 0.3)) + 20 * walk + rng.normal(0, 3, n)
    speed = 90 + 6 * np.sin(2 * np.pi * t * 2.3 + rng.uniform(0, 6)) + rng.normal(0, 0.2, n)
    duty = (np.floor((t * 24 - 6) / 24).astype(int) + 1) % 3
    if schedule == "night2":
        sec = np.round((t % 1) * 86400)
        duty = np.where(sec < 12 * 3600, 0, 2)
        night = (t >= 1) & (sec < 6 * 3600)
        duty[night | ((sec >= 22 * 3600) & (sec < 22 * 3600 + 20))] = 1
    assist_of = np.array([1, 0, 0])  # pump 2 assists pump 1; pump 1 assists 2 and 3
    high = np.zeros(n, bool)
    on = False
    for k in range(n):  # the assist's hysteresis
        on = demand[k] > 290 or (on and demand[k] > 250)
        high[k] = on
    runs = np.zeros((3, n))
    runs[duty, np.arange(n)] = 1.0
    runs[assist_of[duty][high], np.flatnonzero(high)] = 1.0
    count = runs.sum(axis=0)
    share = demand / count
    press = 6.5e-4 * speed**2 - 2.0e-5 * share**2 + rng.normal(0, 0.01, n)
    cols = {"FLOW": demand + rng.normal(0, 2, n), "PRESS": press, "SPEED": speed}
    for k in range(3):
        cols[f"I{k + 1}"] = runs[k] * (5 + 0.05 * share * press + rng.normal(0, 0.3, n))
        cols[f"RUN{k + 1}"] = runs[k]
    cols[bias[0]] = cols[bias[0]] + bias[1] * (t * 24 >= bias_from_h)
    idx = pd.date_range(T0, periods=n, freq="1s")
    return pd.DataFrame(cols, index=idx)


def exported(period: float) -> pd.DataFrame:
    """The station's days 0, 1 and 4 (seed 5; from hour 108, day 4 at noon, pump 1's current
    transmitter reads 8 A more) as an export gives them every ``period`` s, timestamps
    jittered off the grid (smallplants.export)."""
    x = sp.export(station(5, 5, bias=("I1", 8.0), bias_from_h=108), period, timing="jitter",
                  offset_s=0.37 * period, seed=5)  # fmt: skip
    day = ((x.index - T0) // DAY).astype(int)
    return x[np.isin(day, [0, 1, 4])]


def _diagnosed(g, a: pd.Timestamp, b: pd.Timestamp, tmp) -> pd.DataFrame:
    csv = tmp / f"d_{a:%m%d%H}.csv"
    rc, text = diag(g, "diagnose", "st", "--from", fmt(a), "--to", fmt(b), "--csv", str(csv))
    assert rc == 0, text
    d = pd.read_csv(csv, index_col="ts", parse_dates=True, low_memory=False)
    d["status"] = d["status"].map(lambda v: NE107(int(v)).name)
    return d


@pytest.fixture(scope="module", params=[1.0, 60.0], ids=["1s", "1min"])
def built(request, tmp_path_factory):
    """Unit ``st`` built as a user would on day 0 (duties 1 then 2; pump 3 never ran)."""
    period = request.param
    return built_on_day_0(period, tmp_path_factory.mktemp(f"newstate{period:g}"), exported(period))


def built_on_day_0(period: float, tmp, x: pd.DataFrame) -> tuple:
    """``x`` imported into a historian in ``tmp`` and unit ``st`` built on day 0 (the CLI):
    ``(period, the CLI's global options, tmp, x, the build's text)``."""
    g = ["--db", f"sqlite:///{tmp / 'h.db'}", "--rulebases", str(tmp / "rb")]
    import_csv(g, x, tmp / "all.csv", "%Y-%m-%dT%H:%M:%S.%f")
    rc, text = diag(g, "unit", "build", "st", "--from", fmt(T0), "--to", fmt(T0 + DAY),
                    "--far", "0.01")  # fmt: skip
    assert rc == 0, text
    return period, g, tmp, x, text


def test_a_pump_never_run_in_the_window_takes_duty(built):
    """Day 1: pump 3 takes duty at 06:00. Its run feedback and current were 0 over the build
    window; the unit names one of them, its value and the swap's time, CHECK_FUNCTION from
    the swap to the end of the day, no alarm there. Fails on main (no tag named; at 1 s 32.7
    % of the day in alarm, at 1 min the models answer there and say NORMAL, unknowing)."""
    period, g, tmp, _, text = built
    assert "recorded in [fixed] (I3 = 0, RUN3 = 0)" in text, text
    from diag_plugin.diagnose.unitfile import UnitFile

    uf = UnitFile.load(tmp / "rb" / "st.unit.toml")
    assert {t: (s.min, s.max) for t, s in uf.fixed.items()} == {"I3": (0, 0), "RUN3": (0, 0)}
    d = _diagnosed(g, T0 + DAY, T0 + 2 * DAY, tmp)
    swap = T0 + DAY + pd.Timedelta(hours=6)
    # the unit's on-delay (30 s at 1 s, 3 samples at 1 min) after the swap
    after = d[d.index >= swap + pd.Timedelta(seconds=3 * max(period, 10))]
    st = after["status"]
    assert (st == "CHECK_FUNCTION").mean() > 0.99, st.value_counts()
    why = after["why"].dropna()
    assert len(why) == len(after)
    assert why.str.match(r"(RUN3|I3) = [\d.]+ outside what the unit learned \(0 over its "
                         r"window\) since 2026-06-02T06:0").all(), why.head()  # fmt: skip
    assert (after["detected"] == 1).sum() == 0
    alarm = d["status"].isin(["FAILURE", "OFF_SPEC"])
    print(f"{period:g} s day 1: {alarm.mean():.3f} in alarm, after the swap "
          f"{(st == 'CHECK_FUNCTION').mean():.3f} CHECK_FUNCTION")  # fmt: skip
    assert alarm.mean() < 0.15


def test_the_live_plant_says_what_the_replay_says(built):
    """The live plug-in's fast path (:class:`Plant`, one cycle a sample, restarted from its
    saved state half-way) gives each sample the status and message of :meth:`Unit.evaluate`
    around the swap."""
    period, _, tmp, x, _ = built
    a, b = T0 + DAY + pd.Timedelta(hours=5), T0 + DAY + pd.Timedelta(hours=7)
    live_equals_replay(period, tmp / "rb", x, a, b, {"RUN3", "I3"})


def live_equals_replay(period, rb, x, a, b, reads) -> np.ndarray:
    """:meth:`Unit.evaluate` of ``x`` in ``a`` … ``b`` on the unit's grid, in two pieces with
    the state carried through JSON, and the live :class:`Plant` one cycle a sample,
    restarted from its saved state half-way: the same status every sample, the same first
    sentence where CHECK_FUNCTION (> 40 % of the samples); the unit reads ``reads``. The
    statuses."""
    from diag_plugin.diagnose.plant import Plant
    from diag_plugin.diagnose.unit import Unit

    p = f"{period:g}s"
    f = x[(x.index >= a) & (x.index < b)]
    f = f.set_axis(f.index.floor(p))
    f = f[~f.index.duplicated()].reindex(pd.date_range(a, b, freq=p, inclusive="left"))
    unit = Unit.load(rb / "st.unit.toml", rb)
    assert set(unit.tags) >= reads  # the unit reads them (diag diagnose, live)
    half = len(f) // 2
    d1 = unit.evaluate(f.iloc[:half])
    state = json.loads(json.dumps(unit.to_state()))
    unit = Unit.load(rb / "st.unit.toml", rb).load_state(state)
    d2 = unit.evaluate(f.iloc[half:])
    status = np.r_[d1.status.to_numpy(), d2.status.to_numpy()]
    assert (status == NE107.CHECK_FUNCTION).sum() > 0.4 * len(f)
    plant = Plant({"st": Unit.load(rb / "st.unit.toml", rb)}, {})
    assert plant.fast == ["st"] and reads <= set(plant.tags)
    got, msgs = [], []
    for i, (ts, row) in enumerate(f.iterrows()):
        if i == half:  # a restart from the saved state
            state = json.loads(json.dumps(plant.to_state()))
            plant = Plant({"st": Unit.load(rb / "st.unit.toml", rb)}, {}).load_state(state)
        s = plant.cycle(ts, row.to_dict())[0]
        got.append(int(s.status))
        msgs.append(s.message)
    assert np.array_equal(np.array(got), status)
    said = [d.at(i).message for d in (d1, d2) for i in range(len(d))]
    held = status == NE107.CHECK_FUNCTION
    assert [m.split(";")[0] for m, h in zip(msgs, held, strict=True) if h] == [
        m.split(";")[0] for m, h in zip(said, held, strict=True) if h
    ]
    return status


def test_accept_learns_the_new_duty_and_a_fault_there_is_detected(built):
    """``diag unit accept`` of day 1 (pump 3 on duty from 06:00): the [fixed] values widen to
    what it showed, and on day 4 (pump 3 on duty again from 06:00, pump 1 assisting at the
    peaks) the unit answers — NORMAL — and pump 1's current transmitter reading 8 A more
    from noon is detected; rollback restores the unit."""
    period = built[0]
    with day_1_accepted(built, lambda w: w.startswith("constant tag RUN3: span 0 … 0")
                        and w.endswith("0 … 1 (margin 1e-09)")) as diagnosed:  # fmt: skip
        d = diagnosed(T0 + 4 * DAY, T0 + 5 * DAY)
        swap, noon = (T0 + 4 * DAY + pd.Timedelta(hours=h) for h in (6, 12))
        duty3 = d[(d.index >= swap) & (d.index < noon)]["status"]
        fault = d[d.index >= noon]["status"]
        print(f"{period:g} s day 4 after accept: pump 3 on duty {duty3.value_counts().to_dict()}, "
              f"the bias {fault.value_counts().to_dict()}")  # fmt: skip
        assert (duty3 == "NORMAL").mean() > 0.9, duty3.value_counts()
        assert (fault.isin(["FAILURE", "OFF_SPEC"])).mean() > 0.5, fault.value_counts()


@contextlib.contextmanager
def day_1_accepted(built, said):
    """``diag unit accept`` of day 1 (one of its warnings ``said(w)``); yields ``diagnosed(a,
    b)`` (``diag diagnose`` of a … b), then ``diag unit rollback``: the unit file byte for
    byte as before."""
    _, g, tmp, _, _ = built
    unit_file = tmp / "rb" / "st.unit.toml"
    before = unit_file.read_bytes()
    rc, text = diag(g, "unit", "accept", "st", "--from", fmt(T0 + DAY), "--to",
                    fmt(T0 + 2 * DAY), "--json")  # fmt: skip
    assert rc == 0, text
    res = json.loads(text)
    assert any(said(w) for w in res["warnings"]), res["warnings"]
    try:
        yield lambda a, b: _diagnosed(g, a, b, tmp)
    finally:
        rc, text = diag(g, "unit", "rollback", "st")
        assert rc == 0, text
    assert unit_file.read_bytes() == before


def _guard(on: int = 3, off: int = 4):
    from diag_plugin.diagnose.fixed import FixedGuard, fixed_span

    return FixedGuard({"P": fixed_span("P", 0.0)}, {"P": "PUMP_ON"}, on, off)


def test_a_blip_a_gap_and_the_return():
    """A move shorter than the on-delay raises nothing; a sample without a value is neither
    a move nor a return; held from the on-delay's last sample, named since the first sample
    outside, until back for the off-delay; the same in pieces with the state carried."""
    x = np.array([0, 0, 1, 1, 0, np.nan, np.nan, 1, np.nan, 1, 1, 0, 0, np.nan, 0, 0, 1, 0])
    idx = pd.date_range("2026-06-02 06:00", periods=x.size, freq="1s", tz="UTC")
    held, why = _guard().transform(idx, x[:, None])
    #            0  0  1  1  0  -  -  1  -  1  1  0  0  -  0  0  1  0
    want = [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 0, 0, 0]
    assert held.astype(int).tolist() == want
    assert why[10] == ("PUMP_ON = 1 outside what the unit learned (0 over its window) since "
                       "2026-06-02T06:00:07+00:00")  # fmt: skip
    assert why[14] == why[10] and why[15] == ""
    same_in_pieces(_guard, idx, x[:, None], (0, 5, 11, 18), held, why)


def same_in_pieces(make, idx, x, cuts, held, why) -> None:
    """The guard ``make()`` over ``x`` in the pieces between ``cuts``, each a new guard
    loaded from the last one's state through JSON: ``held`` and ``why`` as in one piece."""
    g = make()
    parts = []
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        g = make().load_state(json.loads(json.dumps(g.to_state())))
        parts.append(g.transform(idx[a:b], x[a:b]))
    assert np.concatenate([p[0] for p in parts]).tolist() == held.tolist()
    assert np.concatenate([p[1] for p in parts]).tolist() == why.tolist()


def test_accept_says_which_constant_tag_it_learned_without_json(built):
    """``diag unit accept`` without ``--json`` prints the notes of what the unit now answers
    at (the constant tags, the states learned) before the models' notes, and counts those
    it does not print: here 9 notes (``--json``), 4 printed, then ``… 5 more notes``. Main
    printed the first 4 and dropped the rest without a word (on the air-handling unit of
    docs/explanation/acceptance-ahu.md the cooling valve's learned span was the fifth)."""
    _, g, tmp, _, _ = built
    accept = ["unit", "accept", "st", "--from", fmt(T0 + DAY), "--to", fmt(T0 + 2 * DAY)]
    rc, text = diag(g, *accept, "--json")
    assert rc == 0, text
    every = json.loads(text)["warnings"]
    assert diag(g, "unit", "rollback", "st")[0] == 0
    rc, text = diag(g, *accept)
    try:
        assert rc == 0, text
        notes = [
            ln.removeprefix("  note: ") for ln in text.splitlines() if ln.startswith("  note: ")
        ]
        more = [ln for ln in text.splitlines() if ln.startswith("  … ")]
        assert any(n.startswith("constant tag RUN3: span 0 … 0") for n in notes), text
        assert len(every) > 4 and notes == every[:4], (every, text)
        assert more == [f"  … {len(every) - 4} more notes of the same kind (--json lists them all)"]
    finally:
        rc, text = diag(g, "unit", "rollback", "st")
        assert rc == 0, text


def test_the_notes_beyond_the_fourth_are_counted_not_dropped():
    """The five notes of the air-handling unit's accept (docs/explanation/acceptance-ahu.md):
    four printed, then how many more. Main's ``unit accept`` printed the first four and
    dropped the fifth without a word — there, that the cooling valve's span was learned."""
    from diag_plugin.unitbuild.cli import note_lines

    notes = [
        "constant tag CHWV-1: span 0 … 0 (margin 1e-09) → 0 … 24.2 (margin 1e-09)",
        "ahu_DSP_1.toml: output: span 0 … 500 → -50 … 500 (the window reaches -6.87 … 264.3)",
        "ahu_FLT_DP.toml: output: span 0 … 500 → -50 … 500 (the window reaches -3.54 … 127.78)",
        "ahu_HW_VLV.toml: input DSP_1[k]: span 0 … 500 → -16.6667 … 500, 31 → 32 sets",
        "ahu_OutsideRH.toml: input DSP_1[k-4]: span 0 … 500 → -16.6667 … 500, 31 → 32 sets",
    ]
    lines = note_lines(notes)
    assert lines[:4] == [f"  note: {n}" for n in notes[:4]]
    assert lines[4:] == ["  … 1 more notes of the same kind (--json lists them all)"]
    assert note_lines(notes[:4]) == lines[:4]
