"""Fuzzy diagnosis by seed 001's rules (10)–(14): conclusions, ELSE branches, certainty
factors normalised over the unit's distinct hypotheses, learned and edited N/0/P sets."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_diagnose_matrix import crisp, table4
from test_diagnosis_guards import diagnose, frame, make_unit

from diag_plugin.diagnose.matrix import DiagnosticMatrix
from diag_plugin.diagnose.symptoms import FuzzyThreeValued, three_valued
from diag_plugin.diagnose.unit import Unit
from diag_plugin.diagnose.unitfile import UnitError
from diag_plugin.learn.thresholds import fuzzy_sets

#               N    0    P
GRADED = np.array(
    [
        [0.0, 0.3, 0.7],  # r1
        [0.6, 0.4, 0.0],  # r2
        [0.0, 0.9, 0.1],  # r3
        [0.2, 0.8, 0.0],  # r4
    ]
)


def test_rule_conclusions_on_table4_share_the_evidence_with_the_fault_free_rule():
    out = table4().rules(GRADED[None])
    # premises (min t-norm): EP (B B S S) .6, P0 (S B B S) .1, S (B S B S) .1, X .1, V .2
    np.testing.assert_allclose(out.firing[0], [0.6, 0.1, 0.1, 0.1, 0.2])
    # the fault-free rule: every test small, min(.3, .4, .9, .8)
    assert out.normal[0] == pytest.approx(0.3)
    total = 0.3 + 0.6 + 0.1 + 0.1 + 0.1 + 0.2
    np.testing.assert_allclose(out.certainty[0], np.array([0.6, 0.1, 0.1, 0.1, 0.2]) / total)
    # ELSE branch: the element correct to 1 − certainty; the hypotheses sum to 1
    np.testing.assert_allclose(out.correct[0], 1 - out.certainty[0])
    assert out.certainty[0].sum() + 0.3 / total == pytest.approx(1.0)


def test_faults_with_identical_rules_are_one_hypothesis():
    m = DiagnosticMatrix(["a", "b"], ["F", "G", "H"], [["1", "1", "0"], ["0", "0", "1"]])
    mem = np.array([[[0.0, 0.2, 0.8], [0.0, 1.0, 0.0]]])  # a big, b small
    out = m.rules(mem)
    # F and G: 0.8 each, counted once beside H (0) and the fault-free rule (0.2)
    np.testing.assert_allclose(out.certainty[0], [0.8, 0.8, 0.0])
    assert out.normal[0] == pytest.approx(0.2)


@pytest.mark.parametrize("seed", [3, 17])
def test_crisp_memberships_give_the_exact_match_split_among_compatible_rules(seed):
    m = table4()
    s = np.random.default_rng(seed).integers(-1, 2, size=(300, 4))
    out = m.rules(crisp(s))
    matched = m.match(s.astype(float)).matched
    n = matched.sum(axis=1)
    want = np.where(n[:, None] > 0, matched / np.maximum(n, 1)[:, None], 0.0)
    np.testing.assert_allclose(out.certainty, want)
    quiet = (s == 0).all(axis=1)
    assert quiet.any() and (out.normal[quiet] == 1).all() and (out.certainty[quiet] == 0).all()
    # a pattern no rule covers: every fault certainty 0 (unknown), not a guess
    lost = ~quiet & (n == 0)
    assert lost.any() and (out.certainty[lost] == 0).all()


def test_a_rule_is_judged_on_its_known_tests():
    m = DiagnosticMatrix(["a", "b"], ["F", "G", "H"], [["1", "x", "0"], ["x", "1", "1"]])
    mem = np.array([[[0.0, 0.1, 0.9], [math.nan, math.nan, math.nan]]])
    out = m.rules(mem)
    # F reads a (big .9); G reads only the unknown b: unknown; H: a small (.1), b left out;
    # the fault-free rule: a small (.1)
    np.testing.assert_allclose(out.firing[0, [0, 2]], [0.9, 0.1])
    assert math.isnan(out.firing[0, 1]) and out.normal[0] == pytest.approx(0.1)
    np.testing.assert_allclose(out.certainty[0, [0, 2]], np.array([0.9, 0.1]) / 1.1)
    assert math.isnan(out.certainty[0, 1]) and math.isnan(out.correct[0, 1])
    # nothing known: every rule unknown
    out = m.rules(np.full((1, 2, 3), math.nan))
    assert np.isnan(out.certainty).all() and np.isnan(out.normal).all()


def test_three_valued_sets_from_breakpoints():
    r = np.array([[-6.0], [-5.0], [-4.0], [-3.0], [0.0], [3.0], [4.0], [5.0], [6.0], [np.nan]])
    n, z, p = three_valued(r, -5.0, -3.0, 3.0, 5.0)
    np.testing.assert_allclose(n[:-1, 0], [1, 1, 0.5, 0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(p[:-1, 0], [0, 0, 0, 0, 0, 0, 0.5, 1, 1])
    np.testing.assert_allclose((n + z + p)[:-1, 0], 1.0)
    assert np.isnan([n[-1, 0], z[-1, 0], p[-1, 0]]).all()
    # the threshold/width form is the same sets
    k = FuzzyThreeValued(4.0, 2.0).transform(r)
    for a, b in zip(k, (n, z, p), strict=True):
        np.testing.assert_allclose(a, b)


def test_fuzzy_sets_learned_from_the_fault_free_spread():
    rng = np.random.default_rng(5)
    x = rng.normal(0.0, 1.0, 200_000)
    n1, n0, p0, p1 = fuzzy_sets(x, -4.0, 4.5)
    assert (n1 + 4.0, n0 + 4.0) == pytest.approx((-1.0, 1.0), abs=0.02)
    assert (p0 - 4.5, p1 - 4.5) == pytest.approx((-1.0, 1.0), abs=0.02)
    # a spread wider than the threshold never takes the ramp past zero
    n1, n0, p0, p1 = fuzzy_sets(3.0 * x, -1.0, 1.0)
    assert n0 < 0 < p0 and p1 == pytest.approx(2 * 1.0 - p0)


def test_edited_sets_in_the_unit_file_drive_the_certainty(tmp_path):
    signed = {"f_low": "-000", "f_high": "+000"}
    path = make_unit(tmp_path, signed, symptoms="fuzzy", high=2.0, certainty=0.5)
    text = path.read_text()
    # r1's P ramp edited by hand to 1 … 3 %: a residual of 2.5 % is P to 0.75
    path.write_text(
        text.replace('r1 = { model = "id_y1.toml", high = 2.0 }',
                     'r1 = { model = "id_y1.toml", high = 2.0, fuzzy = [-3.0, -1.0, 1.0, 3.0] }')
    )  # fmt: skip
    got = diagnose(path, frame(10, r1=2.5))
    np.testing.assert_allclose(got["c_f_high"].iloc[5:], 0.75)
    assert (got["faults"].iloc[5:] == "f_high").all()


@pytest.mark.parametrize(
    "bad", ["[1.0, 2.0, 3.0, 4.0]", "[-1.0, -2.0, 1.0, 2.0]", "[-1.0, 1.0]", '"wide"']
)
def test_a_broken_set_edit_names_its_line(tmp_path, bad):
    path = make_unit(tmp_path, {"f": "1000"}, symptoms="fuzzy", high=2.0)
    lines = path.read_text().splitlines()
    i = next(k for k, line in enumerate(lines) if line.startswith("r2 ="))
    lines[i] = lines[i].replace(" }", f", fuzzy = {bad} }}")
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(UnitError) as e:
        Unit.load(path)
    assert f"{path}:{i + 1}: test 'r2': fuzzy must list" in str(e.value)
