"""A declared piece of equipment that barely ran in the build window (issue 34, item 5;
acceptance pass 7, the compressed-air station: the standby compressor ran 25 minutes of the
1 s day). Its tests learn from its running rows only; the build said its thresholds could
not be learned "because of an input or the output missing", not that the piece barely ran,
or stopped on a traceback (``min() arg is an empty sequence`` in the loop test's response
time).

Chiller B of :mod:`tests.twinplant` stopped over the first ``days_off`` of two days at 1 min:
it runs on day 2 from ``days_off`` to 19:00 only.
"""

from __future__ import annotations

import json

import pytest

from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import Loop, parse_running
from historian.errors import UserError
from tests import twinplant
from tests.test_any_plant_tour import diag

LOOPS = [Loop("A_T", "A_SP", "A_CAP"), Loop("B_T", "B_SP", "B_CAP")]
B = "B:B_RUN:B_T,B_CAP,B_KW"


def _build(tmp_path, hour_on: float):
    frame = twinplant.simulate(2, 1, stop_days=(0.0, 1.0 + hour_on / 24))
    b = [parse_running(B)]
    with pytest.raises(UserError) as err:
        build_unit("chw", frame, folder=tmp_path, period="1min", far=0.01, loops=LOOPS,
                   disturbances=["LOAD"], equipment=b)  # fmt: skip
    return str(err.value), int(frame["B_RUN"].sum())


@pytest.mark.parametrize("hour_on, n", [(18.5, 29), (17.5, 90)])
def test_a_loop_test_scored_on_no_block_is_an_error_not_a_traceback(tmp_path, hour_on, n):
    msg, ran = _build(tmp_path, hour_on)  # B ran n samples: no held-out block scores its loop
    assert ran == n
    assert msg.startswith(
        f"loop B_T: its test could not be scored on any held-out block of the {n} rows it "
        "learns from (a declared piece's: where it runs)"
    ), msg


def test_thresholds_not_learned_say_how_little_the_piece_ran(tmp_path):
    msg, n = _build(tmp_path, 14.0)  # 299 samples: inputs chosen, thresholds not learned
    assert n == 299
    assert "cannot learn thresholds" in msg and "test B_T:" in msg, msg
    assert "  B ran on 299 of the window's 2880 samples (10.4%) in 1 run(s), the longest 299: " \
        "its tests (B_T) learn from its running rows only" in msg, msg  # fmt: skip


def test_unit_show_says_the_unknown_share_counts_the_stopped_rows(tmp_path):
    """``diag unit show`` said of a piece's test `unknown: an input or the output missing
    (NaN, bad quality, lags not yet filled) 51.0%` (a compressor stopped half the window):
    the rows where it was stopped, learned from by none of its tests by design. A unit learned
    now keeps them apart (``off``); a unit file learned before (its ``[learned]`` without
    ``off``, the stopped rows in its unknown share) says they are counted as missing."""
    import tomlkit

    frame = twinplant.simulate(4, 3)
    build_unit("chw", frame, folder=tmp_path, period="1min", far=0.01, loops=LOOPS[1:],
               equipment=[parse_running(B)])  # fmt: skip
    g = ["--rulebases", str(tmp_path)]
    stopped = float((frame["B_RUN"] == 0).mean())
    said = f"B stopped (B_RUN = 0) on {stopped:.1%} of the window, counted as missing: its " \
        "tests learn and judge only while it runs"  # fmt: skip
    rc, text = diag(g, "unit", "show", "chw")
    assert rc == 0, text
    flat = " ".join(text.split())  # the terminal's line breaks
    assert flat.count(f"off: B stopped {stopped:.1%} (its tests off, not unknown)") >= 2, flat
    assert said not in flat
    path = tmp_path / "chw.unit.toml"
    doc = tomlkit.parse(path.read_text())
    for entry in doc["learned"].values():  # as a file learned before ``off`` was kept
        if "off" in entry:
            entry["unknown_missing"] = entry.get("unknown_missing", 0.0) + entry["off"]
            entry["unknown"] = entry["unknown"] + entry["off"]
            del entry["off"], entry["off_equipment"]
    path.write_text(tomlkit.dumps(doc))
    rc, text = diag(g, "unit", "show", "chw")
    assert rc == 0, text
    flat = " ".join(text.split())
    assert flat.count(said) >= 2, flat  # B_T and B_CAP (B_KW's test too where built)
    assert "A stopped" not in flat
    rc, text = diag(g, "unit", "show", "chw", "--json")
    tests = {t["test"]: t for t in json.loads(text)["tests"]}
    assert tests["B_T"]["stopped"] == {"piece": "B", "tag": "B_RUN", "stop": 0.0,
                                       "share": pytest.approx(stopped, abs=1e-3)}  # fmt: skip
    assert tests["A_T"]["stopped"] is None
