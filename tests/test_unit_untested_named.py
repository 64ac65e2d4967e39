"""A tag no test models is not named over a tested tag that explains as much (issue 34, item 4;
docs/explanation/acceptance-compressors.md, "Why T_AMB").

The compressor station's dew-point drift fired only the dew point's test, whose model reads
the declared disturbance ``T_AMB``; the ranking named ``T_AMB`` first on every alarm sample,
since the dew point's own direction also points along quiet tests that read it. On the small
plant of :mod:`tests.distplant` (written once, built on seed 1, run on seeds never used to
build) the humidity and room temperature are declared disturbances read by the dew point's
test alone: a bias of the dew point's transmitter is named on the dew point, not on them; a
bias of the load, a disturbance several tests read, is still named on the load.
"""

from __future__ import annotations

import pandas as pd
import pytest

from diag_plugin.diagnose.unit import Unit
from diag_plugin.status import NE107
from tests import distplant

SEEDS = (101, 102, 103)
ON = int(86400 / distplant.PERIOD_S)


@pytest.fixture(scope="module")
def unit(tmp_path_factory):
    from diag_plugin.unitbuild.build import build_unit

    folder = tmp_path_factory.mktemp("distplant")
    res = build_unit("dist", distplant.simulate(5.0, 1), folder=folder, period="60s",
                     far=0.01, disturbances=["T_AMB", "H_AMB", "F_LOAD"])  # fmt: skip
    return Unit.load(res.path, folder)


def _named(unit, seed: int, fault: str) -> pd.Series:
    d = unit.reset().evaluate(distplant.simulate(2.0, seed, fault))
    st = d.status.to_numpy()[ON:]
    on = (st == NE107.FAILURE) | (st == NE107.OFF_SPEC)
    assert on.mean() > 0.15, (seed, fault, on.mean())
    return pd.Series(d.top["top1"].to_numpy()[ON:][on]).value_counts(normalize=True)


def test_the_plant_is_the_case(unit):
    reads = {t: {i.split("[")[0] for i in unit.models[t].inputs} for t in unit.tests}
    outputs = {unit.models[t].output.split("[")[0] for t in unit.tests}
    assert not {"T_AMB", "H_AMB", "F_LOAD"} & outputs
    assert [t for t, r in reads.items() if "H_AMB" in r] == ["P_DEW"], reads
    assert sum("F_LOAD" in r for r in reads.values()) >= 2, reads
    assert sum("P_DEW" in r for r in reads.values()) >= 2, reads


@pytest.mark.parametrize("seed", SEEDS)
def test_a_bias_of_the_tested_tag_is_named_on_it_not_on_the_disturbance(unit, seed):
    named = _named(unit, seed, "dew_bias")
    assert named.index[0] == "P_DEW" and named.iloc[0] > 0.9, named


@pytest.mark.parametrize("seed", SEEDS)
def test_a_bias_of_a_disturbance_several_tests_read_is_still_named_on_it(unit, seed):
    named = _named(unit, seed, "load_bias")
    assert named.index[0] == "F_LOAD" and named.iloc[0] > 0.85, named
