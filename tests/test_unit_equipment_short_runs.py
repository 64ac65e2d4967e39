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

import pytest

from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import Loop, parse_running
from historian.errors import UserError
from tests import twinplant

LOOPS = [Loop("A_T", "A_SP", "A_CAP"), Loop("B_T", "B_SP", "B_CAP")]


def _build(tmp_path, hour_on: float):
    frame = twinplant.simulate(2, 1, stop_days=(0.0, 1.0 + hour_on / 24))
    b = [parse_running("B:B_RUN:B_T,B_CAP,B_KW")]
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
