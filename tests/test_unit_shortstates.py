"""Short states the plant returns to: a state settle learned from the changes into them,
censored where a visit ends first, then the states learned (issue 34 item 5, branch
``i34-cip``); and the build's note of the inputs learned over a narrow part of their span.

The pasteuriser's CIP (docs/explanation/acceptance-pasteuriser.md): three rinses of 10 min a
CIP, each shorter than the unit's quiet time, so none was learned and every rinse was
CHECK_FUNCTION (``a combination of states the unit never learned``); learning them without a
state settle raised a FAILURE at the change into one. A gravity filter at 1 min is the same
shape: filtering (0) for 3.5-4.5 h, a backwash (1) of 10 min and a filter-to-waste (2) of
8 min, both shorter than its quiet time (19 min). Built on six days (seed 11) and judged on
two others (seed 12), imported, built and diagnosed as a user would (the CLI).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tests.test_any_plant_tour import diag, fmt, import_csv

T0 = pd.Timestamp("2026-05-04", tz="UTC")
TAGS = (
    "name,unit,lo,hi,role\nF1_STATE,,0,2,state\nINF_FLOW,m3/h,0,600,\nHEADLOSS,m,0,3,\n"
    "BW_FLOW,m3/h,0,800,\nEFF_TURB,NTU,0,5,\nEFF_FLOW,m3/h,0,600,\n"
)


def _ar1(rng, n: int, a: float, sigma: float) -> np.ndarray:
    """An AR(1) walk ``x[k] = a·x[k-1] + e``, ``e ~ N(0, sigma)``."""
    from scipy.signal import lfilter

    return lfilter([1.0], [1.0, -a], rng.normal(0, sigma, n))


def _since(reset: np.ndarray) -> np.ndarray:
    """Samples since the last ``reset`` sample (0 there; counted from the start before it)."""
    k = np.arange(len(reset))
    last = np.maximum.accumulate(np.where(reset, k, 0))
    return (k - last).astype(float)


def filter_bank(days: float, seed: int, start_day: int = 0, turb_bias: tuple = (None, 0.0)):
    """A gravity filter at 1 min: filtering (0) for 3.5-4.5 h, backwash (1) 10 min,
    filter-to-waste (2) 8 min, again. The inflow a daily cycle and a walk (the inlet shut in
    backwash), the head loss growing with the time since the last wash and the flow², the
    backwash flow, the effluent's turbidity high after a wash and falling (4 min), the
    effluent flow to the clear well (none in backwash or to waste). ``turb_bias``: from that
    time on the turbidity meter reads that much high."""
    rng = np.random.default_rng(seed)
    n = int(days * 1440)
    state = np.zeros(n)
    k = int(rng.integers(60, 200))
    while k < n:
        state[k : k + 10] = 1.0
        state[k + 10 : k + 18] = 2.0
        k += 18 + int(rng.integers(210, 270))
    t = np.arange(n) + start_day * 1440
    demand = 400 + 40 * np.sin(2 * np.pi * t / 1440) + _ar1(rng, n, 0.98, 1.5)
    inf = np.where(state == 1, 0.0, demand) + rng.normal(0, 2, n)
    age = _since(state == 1)
    head = np.where(state == 1, 0.05, 0.3 + 0.002 * age * (np.clip(inf, 0, None) / 400) ** 2)
    head = head + rng.normal(0, 0.01, n)
    bw = np.where(state == 1, 600.0, 0.0) + rng.normal(0, 2, n)
    turb = 0.12 + np.where(state == 1, 0.0, 2.5 * np.exp(-age / 4.0)) + rng.normal(0, 0.01, n)
    eff = np.where(state == 0, inf, 0.0) + rng.normal(0, 2, n)
    idx = T0 + pd.to_timedelta(t, unit="min")
    if turb_bias[0] is not None:
        turb = turb + np.where(idx >= turb_bias[0], turb_bias[1], 0.0)
    cols = {"F1_STATE": state, "INF_FLOW": inf.round(1), "HEADLOSS": head.round(3),
            "BW_FLOW": bw.round(1), "EFF_TURB": turb.round(3),
            "EFF_FLOW": eff.round(1)}  # fmt: skip
    return pd.DataFrame(cols, index=idx)


ONSET = T0 + pd.Timedelta(days=8, hours=6)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """The filter built on days 0-5 (seed 11); days 6-7 fault-free (seed 12), days 8-9 with
    the turbidity meter reading 0.4 NTU high from day 8 06:00 (seed 13)."""
    tmp = tmp_path_factory.mktemp("shortstates")
    g = ["--db", f"sqlite:///{tmp / 'h.db'}", "--rulebases", str(tmp / "rb")]
    tags = tmp / "tags.csv"
    tags.write_text(TAGS)
    frames = [filter_bank(6, 11), filter_bank(2, 12, 6), filter_bank(2, 13, 8, (ONSET, 0.4))]
    import_csv(g, pd.concat(frames), tmp / "x.csv", tags=tags)
    end = T0 + pd.Timedelta(days=6)
    rc, text = diag(g, "unit", "build", "fb", "--from", fmt(T0), "--to", fmt(end),
                    "--loops-from", str(tags))  # fmt: skip
    assert rc == 0, text
    return g, tmp, text


def _diagnosed(g, tmp, a: pd.Timestamp, b: pd.Timestamp, name: str) -> pd.DataFrame:
    rc, text = diag(g, "diagnose", "fb", "--from", fmt(a), "--to", fmt(b),
                    "--csv", str(tmp / name))  # fmt: skip
    assert rc == 0, text
    d = pd.read_csv(tmp / name, index_col=0)
    d.index = pd.to_datetime(d.index, utc=True)
    d["why"] = d["why"].fillna("").astype(str) if "why" in d else ""
    return d


def test_short_states_visited_again_are_learned_behind_a_state_settle(built):
    """The backwash and the filter-to-waste (10 and 8 min, 19 min quiet time) are learned:
    the build writes the state settle (33 of its 40 changes settled: their quantile, as
    before) and ``[states] seen`` holds them; two fault-free days are never ``never
    learned`` (on main: every backwash and filter-to-waste, 209 samples) and raise no
    FAILURE after their first
    hour (a diagnosis begun inside a wash's transient may), and a turbidity meter's bias is
    still found."""
    import tomllib

    g, tmp, text = built
    doc = tomllib.loads((tmp / "rb" / "fb.unit.toml").read_text())
    assert doc["evaluation"]["state_settle_max_s"] > 0
    assert set(doc["states"]["seen"]) == {"0", "1", "2"}, doc["states"]
    a = T0 + pd.Timedelta(days=6)
    d = _diagnosed(g, tmp, a, a + pd.Timedelta(days=2), "free.csv")
    never = d["why"].str.contains("never learned")
    assert not never.any(), d.loc[never, "why"].iloc[0]
    later = d.index >= a + pd.Timedelta(hours=1)
    assert (d.loc[later, "status"] != 1).all(), d.loc[later & (d.status == 1), "why"].head()
    assert (d["status"] == 2).mean() < 0.02
    f = _diagnosed(g, tmp, ONSET - pd.Timedelta(hours=6), ONSET + pd.Timedelta(days=1), "f.csv")
    after = f.loc[f.index >= ONSET, "status"]
    assert (after == 1).mean() > 0.5, after.value_counts()


def test_the_narrow_span_note_is_shown_and_written():
    """The pasteuriser's short window (400 samples of 10 s in one production run): its rate's
    set-point and the feed pump's speed held one value, every temperature a fraction of its
    0-100 span. ``diag unit build`` says which inputs were learned over under 5 % of their
    span (the tag's lo … hi), each with the span the window showed, on its own line whatever
    the count of notes (they were cut at four), and the unit file keeps the list."""
    import subprocess
    import sys
    import tempfile
    import tomllib
    from pathlib import Path

    sim = Path(__file__).parents[1] / "benchmarks" / "acceptance" / "pasteuriser_sim.py"
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        subprocess.run([sys.executable, str(sim), str(tmp / "p.csv"), "--seed", "5",
                        "--start", "2026-03-03T00:00:00", "--days", "0.15", "--period", "10"],
                       check=True)  # fmt: skip
        subprocess.run([sys.executable, str(sim), "x", "--tags-csv", str(tmp / "tags.csv")],
                       check=True)  # fmt: skip
        g = ["--db", f"sqlite:///{tmp / 'h.db'}", "--rulebases", str(tmp / "rb")]
        rc, text = diag(g, "import", str(tmp / "p.csv"), "--tags", str(tmp / "tags.csv"))
        assert rc == 0, text
        loops = ["BT_LEVEL=50:BT_INLET_VLV", "FEED_FLOW=FEED_FLOW_SP:FEED_VFD",
                 "HEAT_OUT_TEMP=HEAT_OUT_SP:HW_TEMP_SP", "HW_TEMP=HW_TEMP_SP:STEAM_VLV",
                 "COOL_OUT_TEMP=4:CHW_VLV"]  # fmt: skip
        rc, text = diag(g, "unit", "build", "sw", "--from", "2026-03-03T02:00:00Z",
                        "--to", "2026-03-03T03:06:40Z", "--loops-from", str(tmp / "tags.csv"),
                        *(x for lp in loops for x in ("--loop", lp)))  # fmt: skip
        assert rc == 0, text
        doc = tomllib.loads((tmp / "rb" / "sw.unit.toml").read_text())
    line = next((ln for ln in text.splitlines() if "narrow part of their span" in ln), "")
    assert line.startswith("  ⚠ "), text
    narrow = {s.split(" ")[0]: s for s in doc["build"]["narrow"]}
    # the rate's set-point held one value: its learned span, its span 0 … 20
    assert narrow["FEED_FLOW_SP"].startswith("FEED_FLOW_SP 10.4 … 10.4 (0.0% of its span 0 … 20")
    assert "FEED_VFD" in narrow and "FEED_FLOW_SP 10.4 … 10.4" in line
    # the rule is said: held at one value, or few independent values over under half the span
    assert "held at one value, or at most 7 independent values" in line
    # the slow raw-milk temperature (about 3 independent values in 67 min) is listed; the
    # loops' controlled temperatures (0.2 % of 0 … 100, dozens of values) and the level held
    # at 50 % (3 % of its span, about 25) are not: the window saw their spread (under 5 % of
    # the span, the rule before, listed 11 inputs, these among them)
    assert "about 3.0 independent values" in narrow["RAW_TEMP"], narrow
    assert not {"HOLD_TEMP", "HW_TEMP_SP", "BT_LEVEL", "STEAM_VLV"} & set(narrow), narrow


def test_the_settling_quantile_counts_a_censored_change_until_its_visit_ended():
    """Kaplan and Meier's estimate (1958): settled at 1, 2, 3 and one censored at 2.5 (its
    visit ended first): S = 3/4, then 3/4 · 2/3 = 1/2, then 0 at 3 — the 90 % quantile 3.
    Censored at 3.5 instead, the estimate stops at 1 − 1/2 · 1/2 = 0.75: not known (None),
    where counting only the settled ones would have said 3. With none censored it is the
    settled times' own quantile."""
    from diag_plugin.unitbuild.loops import km_quantile

    assert km_quantile([1.0, 2.0, 3.0], [2.5], 0.9) == 3.0
    assert km_quantile([1.0, 2.0, 3.0], [3.5], 0.9) is None
    assert km_quantile([1.0, 2.0, 3.0], [3.5], 0.75) == 3.0
    assert km_quantile(np.arange(1.0, 11.0), [], 0.9) == 9.0
    assert km_quantile([], [5.0], 0.5) is None


def test_an_input_is_narrow_by_its_own_time_scale_not_a_share_of_its_span():
    """``narrow_spans`` judges an input by the independent values the window holds of it
    (its own time scale against the window's length), not by a fixed share of its span: a
    temperature wandering slowly over 20 % of its span (about 2 independent values: half
    its later values outside) is named; a fast one at 0.3 % of its span (a loop holds it,
    400 independent values) is not, nor one wandering slowly over most of its span; a
    set-point held at one value is, whatever its span."""
    from diag_plugin.unitbuild.build import Step, TestChoice, narrow_spans
    from historian.taginfo import TagInfo

    rng = np.random.default_rng(3)
    n = 400
    frame = pd.DataFrame({
        "SLOW": 40.0 + 20.0 * np.sin(np.linspace(0, np.pi / 2, n)) + rng.normal(0, 0.02, n),
        "FAST": 73.2 + rng.normal(0, 0.05, n),
        "WIDE": 10.0 + 80.0 * np.linspace(0, 1, n) + rng.normal(0, 0.02, n),
        "SP": np.full(n, 10.4),
        "Y": rng.normal(0, 1, n),
    })  # fmt: skip
    info = {t: TagInfo(t, lo=0.0, hi=100.0) for t in frame.columns}
    kept = [TestChoice("Y", "Y", 1.0, steps=[Step(f"{t}[k]", 1.0, 1.0) for t in
                                             ("SLOW", "FAST", "WIDE")])]  # fmt: skip
    got = {s.split(" ")[0]: s for s in narrow_spans(frame, info, kept, {"SP": "a set-point"})}
    assert set(got) == {"SLOW", "SP"}, got
    assert "held at one value" in got["SP"] and "independent values" in got["SLOW"]


def _km_by_hand(times, censored, q):
    """The product-limit quantile as ``km_quantile`` computed it before scipy's
    (``scipy.stats.ecdf``): one factor ``1 − 1/n`` per settled change in time order, a
    censored change at a tied time after the settled ones."""
    t = np.r_[np.asarray(times, float), np.asarray(censored, float)]
    d = np.r_[np.ones(len(times), bool), np.zeros(len(censored), bool)]
    if not d.any():
        return None
    order = np.lexsort((~d, t))
    t, d = t[order], d[order]
    surv = np.cumprod(np.where(d, 1.0 - 1.0 / (len(t) - np.arange(len(t))), 1.0))
    hit = np.flatnonzero(d & (1.0 - surv >= q - 1e-12))
    return float(t[hit[0]]) if hit.size else None


def test_the_settling_quantile_is_scipys_product_limit_estimate():
    """``km_quantile`` is ``scipy.stats.ecdf`` of the censored sample: by hand, settled at 2,
    2, 4, 5, 5, 7 and censored at 2, 3, 5, 6 (ties: a censoring after the settlings), the
    estimate 1 − S is 2/10 at 2, then 1 − 8/10 · 5/6 = 1/3 at 4 (6 at risk), 1 − 2/3 · 3/5 =
    0.6 at 5 (5 at risk), 1 at 7 (1 at risk); the 7 censored at 8 instead, it stops at 0.6.
    And on random censored samples (times rounded to the sample period, so ties occur) it
    agrees with the product computed one settled change at a time."""
    from diag_plugin.unitbuild.loops import km_quantile

    seen, cens = [2.0, 2.0, 4.0, 5.0, 5.0, 7.0], [2.0, 3.0, 5.0, 6.0]
    for q, want in [(0.2, 2.0), (0.3, 4.0), (0.5, 5.0), (0.6, 5.0), (0.61, 7.0), (0.9, 7.0)]:
        assert km_quantile(seen, cens, q) == want, q
    assert km_quantile(seen[:-1], [*cens, 8.0], 0.6) == 5.0
    assert km_quantile(seen[:-1], [*cens, 8.0], 0.61) is None
    rng = np.random.default_rng(34)
    reached = 0
    for _ in range(400):
        n, m = rng.integers(0, 25), rng.integers(0, 25)
        times = np.round(rng.exponential(300.0, n) / 10) * 10
        censored = np.round(rng.exponential(500.0, m) / 10) * 10
        for q in (0.5, 0.9):
            got, want = km_quantile(times, censored, q), _km_by_hand(times, censored, q)
            assert got == want, (times, censored, q)
            reached += want is not None
    assert 200 < reached < 800  # both answers: the quantile reached and not


def test_a_step_inside_a_sequence_is_no_state_and_a_short_mode_is():
    """``[states]`` at 1 min, the dwell 20 min: three starts (the mode 0 → 1, the valve
    forward 3 min later: ``0,1`` a step of the start, entered through the mode's change and
    left through the valve's) and three rinses (the mode 1 → 2 → 1, 10 min, the valve
    forward throughout). The rinse is learned, the start's step is not (learned, its alarm
    showed over the pasteuriser's start at 1 s: FAILURE 0.62 → 0.95 % of a fault-free day)."""
    from diag_plugin.diagnose.combos import held_combos, visited_combos

    mode, valve = [], []
    for _ in range(3):
        mode += [0] * 60 + [1] * 3 + [1] * 60 + [2] * 10 + [1] * 60
        valve += [0] * 60 + [0] * 3 + [1] * 60 + [1] * 10 + [1] * 60
    idx = T0 + pd.to_timedelta(np.arange(len(mode)), unit="min")
    x = pd.DataFrame({"VALVE": valve, "MODE": mode}, index=idx, dtype=float)
    assert held_combos(x, ["VALVE", "MODE"], 1200) == ["0,0", "1,1"]
    assert visited_combos(x, ["VALVE", "MODE"], 1200, 180) == ["1,2"]
    # a switch shorter than the on-delay is no visit
    assert visited_combos(x, ["VALVE", "MODE"], 1200, 660) == []


def test_the_states_table_written_is_the_one_the_build_reads():
    """``put_states`` sets a unit file's ``[states]`` table (what is saved) and its read form
    (what the settle and the combinations guard read during the build) from one triple, at
    both of the build's assignments (the window's held combinations, then those visited
    repeatedly once a state settle is learned): read back, the saved table is the read form."""
    from types import SimpleNamespace

    import tomlkit

    from diag_plugin.diagnose.combos import read_states
    from diag_plugin.unitbuild.build import put_states

    uf = SimpleNamespace(doc=tomlkit.document(), states=None)
    for seen in (["0,0", "1,1"], ["0,0", "1,1", "1,2"]):
        put_states(uf, ["FDV_FORWARD", "MODE"], seen, 760.0)
        back = tomlkit.loads(tomlkit.dumps(uf.doc))["states"]
        assert read_states(back, None, None) == uf.states
        assert uf.states["seen"] == seen
