"""The run condition's tag is found under its plant name and under its models' name (issue 34,
items 5/6; ``Unit.run_column`` / ``Unit.runs_of``, i36-starts).

A unit file whose ``[tags]`` read the run tag ``RUN`` as the plant's ``K1.RUN``: ``diag
diagnose`` hands the unit frames under the plant's names, the build's window (what
:class:`~diag_plugin.unitbuild.loops.HeldOut` filters for the envelopes) is read under the
models' names with the run tag beside. Both must find the run tag, or the build filters the
stopped rows as running ones and learns its envelopes from them.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.unit import Unit
from diag_plugin.examples.coupled import DAY, build, process
from diag_plugin.unitbuild.loops import HeldOut

#: the stopped stretch of the window (samples of 60 s)
STOP = slice(300, 500)


@pytest.fixture(scope="module")
def unit_and_window(tmp_path_factory):
    folder = tmp_path_factory.mktemp("run_column")
    window = process(DAY, 1)
    path = build(folder, window)
    path.write_text(
        path.read_text()
        + '\n[running]\ntag = "RUN"\nrun = 1.0\nstop = 0.0\n\n[tags]\nRUN = "K1.RUN"\n'
    )
    run = np.ones(len(window))
    run[STOP] = 0.0
    return Unit.load(path), window, run


def test_the_run_tag_is_found_by_its_plant_name_and_by_its_models_name(unit_and_window):
    unit, window, run = unit_and_window
    plant_named = window.assign(**{"K1.RUN": run})
    models_named = window.assign(RUN=run)
    assert unit.run_column(plant_named) == "K1.RUN"
    assert unit.run_column(models_named) == "RUN"
    for frame in (plant_named, models_named):
        assert unit.runs_of(frame).tolist() == (run == 1.0).tolist()
    # the plant name first where both are there
    assert unit.run_column(window.assign(**{"K1.RUN": run, "RUN": 1.0})) == "K1.RUN"
    # without the tag: judged throughout
    assert unit.run_column(window) is None
    assert unit.runs_of(window).all()


def test_held_out_residuals_of_a_window_under_the_models_names_skip_its_stops(unit_and_window):
    """The build's held-out residuals (``HeldOut``) of a window read under the models' names
    are NaN where the run tag says stopped, finite on the running rows around it."""
    unit, window, run = unit_and_window
    rng = np.random.default_rng(7)
    scaled = pd.DataFrame(rng.normal(size=(len(window), len(unit.tests))),
                          index=window.index, columns=unit.tests)  # fmt: skip
    held = HeldOut(unit, window.assign(RUN=run), scaled)
    held()
    assert np.isnan(held.raw[STOP]).all()
    after = held.raw[STOP.stop + 60 : STOP.stop + 120]
    assert np.isfinite(after).all()
