"""The example rule bases shipped in rulebases/ are valid and reproducible to the byte."""

from pathlib import Path

import pytest

from diag_plugin.damadics import find_file
from diag_plugin.examples import build_examples
from diag_plugin.rulebase import RuleBase, check

SHIPPED = Path(__file__).resolve().parents[1] / "rulebases"
NAMES = ["valve_a", "valve_b", "damadics_f"]


@pytest.mark.parametrize("name", NAMES)
def test_shipped_example_is_valid(name):
    path = SHIPPED / f"{name}.toml"
    assert check(path) == []
    rb = RuleBase.load(path)
    assert rb.rules and rb.training["samples"] > 0
    assert rb.to_model().n_rules_ == len(rb.rules)


def test_examples_regenerate_identically(tmp_path):
    made = build_examples(tmp_path)
    names = {p.stem for p in made}
    expected = set(NAMES) if find_file() is not None else {"valve_a", "valve_b"}
    assert names == expected
    for p in made:
        assert p.read_bytes() == (SHIPPED / p.name).read_bytes(), p.name
