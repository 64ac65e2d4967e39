"""A piece's test never reads another piece's tags (issue 34, items 4-5;
docs/reference/units.md, "A piece's tests read its own tags").

The three sand filters of :mod:`tests.filterbank`, washed in a fixed rotation and each
declared a piece (``--running 'Fn:Fn_STATE=0:Fn_FLOW,Fn_HL,Fn_TURB'``), built on 10 days
(seed 1) and judged on seeds never used to build (12, 13). Without the rule a filter's tests
read its neighbours' flows and head losses (``F3_HL = f(F1_FLOW, F1_HL, TOTAL_FLOW)``: the
rotation's coincidence), and filter 1's flow meter reading 10 % high was named on filter 2's
and 3's tags too, which read it; with it each filter's tests read its own tags, the
unit-wide ones (the bank's inflow, the raw water) and whether the others are washed, and the
bias is filter 1's alone.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.unit import Unit
from diag_plugin.status import NE107
from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import parse_running
from tests import filterbank

DAY = 1440
PIECES = {f"F{n}": {f"F{n}_FLOW", f"F{n}_HL", f"F{n}_TURB"} for n in (1, 2, 3)}
UNIT_WIDE = {"TOTAL_FLOW", "RAW_TURB"}
#: whether each filter runs (washed or not): true while it is stopped, never at fault, any
#: test's candidate (a wash moves the others' flows)
RUN_TAGS = {f"F{n}_STATE" for n in (1, 2, 3)}


@pytest.fixture(scope="module")
def bank(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("filterbank")
    pieces = [parse_running(filterbank.running(n)) for n in (1, 2, 3)]
    res = build_unit("filt", filterbank.simulate(10, 1), folder=tmp, period="1min", far=0.01,
                     disturbances=sorted(UNIT_WIDE), equipment=pieces)  # fmt: skip
    return res, Unit.load(res.path, tmp)


def test_a_piece_s_tests_read_its_own_tags_and_the_unit_wide_ones(bank):
    res, unit = bank
    for test, model in unit.models.items():
        piece = next(p for p, tags in PIECES.items() if model.output.split("[")[0] in tags)
        assert set(model.tags) <= PIECES[piece] | UNIT_WIDE | RUN_TAGS, (test, model.inputs)
    # said once per piece, naming what was left out
    for piece in PIECES:
        said = [n for n in res.notes if n.startswith(f"{piece}: its tests read its own tags,")]
        assert len(said) == 1, res.notes
        others = sorted(t for p, tags in PIECES.items() if p != piece for t in tags)
        assert all(t in said[0] for t in others), said[0]
        assert not any(t in said[0] for t in RUN_TAGS), said[0]


@pytest.mark.parametrize("seed", [12, 13])
def test_a_piece_s_fault_is_not_named_on_the_pieces_beside_it(bank, seed):
    _, unit = bank
    f = filterbank.simulate(4, seed, "f1_flow_bias", onset_days=2.0, start="2026-03-16")
    d = unit.reset().evaluate(f)
    after = np.arange(len(f)) >= 2 * DAY
    fail = d.status.to_numpy()[after] == NE107.FAILURE
    assert fail.mean() > 0.5, fail.mean()
    top = d.top[["top1", "top2", "top3"]].to_numpy()[after][fail]
    first = pd.Series(top[:, 0])
    assert (first == "F1_FLOW").mean() > 0.9, first.value_counts()
    beside = np.array([any(str(t).startswith(("F2_", "F3_")) for t in row) for row in top])
    assert beside.mean() < 0.05, pd.Series(top.ravel()).value_counts()
