"""A new unit file keeps every evaluation setting it was asked for (issue 38's mutation check
of ``diagnose/unitfile.py``): ``new_unit_text`` leaves out the newer keys only where they
are at their default (so files written before them regenerate byte for byte), never a key
that follows one of them."""

from __future__ import annotations

import itertools

import pytest

from diag_plugin.diagnose.unitfile import EVALUATION_DEFAULTS, NEW_KEYS, UnitFile, new_unit_text

#: a value other than the default for each newer key
OTHER = {
    "combined": True,
    "isolation": "tags",
    "on_delay_s": 45.0,
    "off_delay_s": 240.0,
    "deadband": 0.1,
    "spread_window_s": 600.0,
    "oscillation_window_s": 2400.0,
    "release_window_s": 7200.0,
    "settle_max_s": 1800.0,
    "manual_settle_max_s": 3600.0,
    "state_settle_max_s": 1800.0,
}


@pytest.mark.parametrize("keys", [*itertools.combinations(NEW_KEYS, 1), NEW_KEYS[2:], NEW_KEYS[4:]])
def test_a_new_unit_file_keeps_each_setting_asked_for(tmp_path, keys):
    assert set(OTHER) == set(NEW_KEYS)
    asked = {k: OTHER[k] for k in keys} | {"on_delay": 5}
    path = tmp_path / "u.unit.toml"
    path.write_text(new_unit_text("u", {"r1": "m.toml"}, evaluation=asked))
    text = path.read_text()
    ev = UnitFile.load(path).evaluation
    for k, v in EVALUATION_DEFAULTS.items():
        assert ev[k] == asked.get(k, v), k
        # the newer keys at their default are not written
        assert (f"\n{k} = " in text) == (k not in NEW_KEYS or k in asked), k


def test_a_unit_file_without_evaluation_settings_gets_the_documented_defaults(tmp_path):
    """The ``[evaluation]`` of the example in the unit file's reference (the module doc of
    :mod:`diag_plugin.diagnose.unitfile`) lists each setting at its default: a unit that
    leaves them all out evaluates with exactly those."""
    import textwrap
    import tomllib

    from diag_plugin.diagnose import unitfile

    doc = unitfile.__doc__
    block = doc[doc.index("    [evaluation]") :].split("\n\n")[0]
    documented = tomllib.loads(textwrap.dedent(block))["evaluation"]
    assert len(documented) >= 12
    path = tmp_path / "u.unit.toml"
    path.write_text('[unit]\nname = "u"\n[tests]\nr1 = { model = "m.toml" }\n')
    ev = UnitFile.load(path).evaluation
    assert {k: ev[k] for k in documented} == documented
