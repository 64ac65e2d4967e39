"""The unit's off-delay from its tags and ISA-18.2's rules, not a floor of 240 s (issue 34,
item 6; diag_plugin/unitbuild/alarms.py): 15 s for flows and pressures, 60 s for levels,
temperatures and tags of another kind, at least the grid's own delay (three samples); a
grid of minutes keeps what it had at 3 min (540 s). Fails on main (no such rule: 240 s at
1 s and 15 s, 240 s at 1 min)."""

from __future__ import annotations

import pytest

from diag_plugin.bench.publicplants import SKAB_TAGS
from diag_plugin.unitbuild.alarms import chatter_free, isa_off_delay, measured_kind
from diag_plugin.unitbuild.build import CHATTER_WINDOW_S, alarm_settings
from historian.taginfo import TagInfo


def _info(tags: dict[str, tuple[str, str]]) -> dict[str, TagInfo]:
    return {t: TagInfo(t, u, description=d) for t, (u, d) in tags.items()}


def test_what_a_tag_measures_as_isa_s_delays_tell_kinds_apart():
    info = _info({"Thermocouple": ("°C", "fluid temperature in the loop"),
                  "Pressure": ("bar", "pressure after the pump"),
                  "Current": ("A", "motor current")})  # fmt: skip
    assert measured_kind("TI108", None) == "temperature"
    assert measured_kind("FI101", None) == "flow" and measured_kind("LI102", None) == "level"
    assert measured_kind("TIC107.OUT", None) is None  # a controller's output
    assert measured_kind("Thermocouple", info["Thermocouple"]) == "temperature"
    assert measured_kind("Pressure", info["Pressure"]) == "pressure"
    assert measured_kind("Current", info["Current"]) is None


def test_the_off_delay_is_the_longest_of_the_unit_s_tags():
    assert isa_off_delay(["FI101", "PI102", "FI103"], {})[0] == 15.0
    assert isa_off_delay(["FI101", "LI102"], {})[0] == 60.0  # a level's
    assert isa_off_delay(["FI101", "VIB1"], {})[0] == 60.0  # another kind: the range's top
    info = _info(SKAB_TAGS)
    off, kinds = isa_off_delay(info, info)
    assert off == 60.0 and kinds["temperature"] == ["Temperature", "Thermocouple"]
    assert kinds["flow"] == ["Volume Flow RateRMS"] and kinds["pressure"] == ["Pressure"]


@pytest.mark.parametrize(
    ("period", "isa", "off", "free"),
    [("1s", 60.0, 60.0, False), ("1s", 15.0, 30.0, False), ("15s", 60.0, 60.0, False),
     ("60s", 60.0, 180.0, True), ("180s", 15.0, 540.0, True)],
)  # fmt: skip
def test_the_off_delay_is_isa_s_at_least_the_grid_s(period, isa, off, free):
    """At 1 s a flow-only unit keeps its on-delay's 30 s; at 1 min and 3 min three samples
    (180 s, 540 s: the chemical plant's and TEP's 540 s as before), where two alarm
    episodes begin more than a third of the chatter window apart."""
    got = alarm_settings(period, None, isa)
    assert got["off_delay_s"] == off
    assert chatter_free(got["off_delay_s"], CHATTER_WINDOW_S) is free
    assert alarm_settings(period)["off_delay_s"] == max(off, 60.0)  # no tags: 60 s
