"""Diagnostic matrix: file format, isolability, exact / nearest / fuzzy reasoning.

Tables transcribed from the seeds: Kościelny, Syfert, Bartyś (seed 001) Tables 1–4 and
isolation rules (10)–(14); Laukonen et al. (seed 000) Table II.
"""

import math

import numpy as np
import pytest
from helpers import VALVE_TABLE4

from diag_plugin.diagnose.matrix import DiagnosticMatrix, MatrixError, load_matrix, parse_matrix

# ---------------------------------------------------------------- seed 001
TESTS_001 = ["r1", "r2", "r3", "r4"]  # F−F̂(CV), P0−P̂0(CV), X−X̂(P0), F−F̂(X)
FAULTS_001 = ["f_EP", "f_P0", "f_S", "f_X", "f_V"]  # e1 … e5

# Table 4 as printed (blank cells are empty strings; d1/e4 is an explicit 0).
TABLE_4 = [
    ["1", "", "1", "0", "1"],
    ["1", "1", "", "", ""],
    ["", "1", "1", "1", ""],
    ["", "", "", "1", "1"],
]

# Rules (10)–(14): premises per fault e1..e5 over r1..r4, B = big, S = small.
RULES_10_14 = {
    "f_EP": "BBSS",  # (10)
    "f_P0": "SBBS",  # (11)
    "f_S": "BSBS",  # (12)
    "f_X": "SSBB",  # (13)
    "f_V": "BSSB",  # (14)
}


def _blank0(table):
    return [[e if e else "0" for e in row] for row in table]


def table4() -> DiagnosticMatrix:
    return DiagnosticMatrix(TESTS_001, FAULTS_001, _blank0(TABLE_4))


# Table 1, d1..d9 × e1..e9: the row lists the faults marked 1.
TABLE_1 = {
    1: [1, 4, 5],
    2: [1, 2, 4, 6, 9],
    3: [3, 5, 7],
    4: [4, 6, 8],
    5: [1, 2, 3, 4, 8, 9],
    6: [3, 6, 7],
    7: [2, 4, 7],
    8: [5, 8],
    9: [3, 4, 5, 9],
}
TABLE_3 = {
    1: [1, 3],
    2: [2],
    3: [2, 3],
    4: [4, 5],
    5: [5, 6],
    6: [4, 6],
    7: [7, 8],
    8: [8, 9],
    9: [7, 9],
}


def from_sets(rows: dict[int, list[int]]) -> DiagnosticMatrix:
    tests = [f"d{i}" for i in range(1, 10)]
    faults = [f"e{k}" for k in range(1, 10)]
    return DiagnosticMatrix(
        tests, faults, [[int(k in rows[i]) for k in range(1, 10)] for i in range(1, 10)]
    )


def test_table4_is_rules_10_to_14():
    m = table4()
    for f, premises in RULES_10_14.items():
        col = m.entries[:, FAULTS_001.index(f)]
        assert list(col) == ["1" if p == "B" else "0" for p in premises], f


def test_table4_every_fault_isolable_and_accuracy_one():
    m = table4()
    assert m.detectable.all()
    assert m.isolability_groups() == [[f] for f in FAULTS_001]
    assert m.mean_diagnosis_accuracy() == 1.0


@pytest.mark.parametrize("sign", [1, -1])
def test_table4_single_fault_signature_isolates_that_fault(sign):
    m = table4()
    for k, f in enumerate(FAULTS_001):
        s = np.array([[sign if p == "B" else 0 for p in RULES_10_14[f]]], dtype=float)
        res = m.match(s)
        assert res.matched[0].tolist() == [j == k for j in range(5)], f
        assert not res.undecidable[0]


def test_table4_without_r3_r4_groups_and_accuracy():
    # Drop d3, d4: e4 (X) sees nothing, e3 (S) and e5 (V) both read (1, 0).
    m = DiagnosticMatrix(TESTS_001[:2], FAULTS_001, _blank0(TABLE_4)[:2])
    assert m.undetectable == ["f_X"]
    assert m.isolability_groups() == [["f_EP"], ["f_P0"], ["f_S", "f_V"]]
    acc = m.diagnosis_accuracy()
    assert acc == {"f_EP": 1.0, "f_P0": 1.0, "f_S": 0.5, "f_X": 0.0, "f_V": 0.5}
    assert math.isclose(m.mean_diagnosis_accuracy(), 3.0 / 5.0)
    # the shared signature matches both, and only those
    assert m.match([[1, 0]]).matched[0].tolist() == [False, False, True, False, True]


@pytest.mark.parametrize("table", [TABLE_1, TABLE_3])
def test_tables_1_and_3_single_faults_isolable(table):
    m = from_sets(table)
    assert len(m.isolability_groups()) == 9
    sig = np.array([[int(k in table[i]) for i in range(1, 10)] for k in range(1, 10)], float)
    assert (m.match(sig).matched == np.eye(9, dtype=bool)).all()


def test_table2_diagonal_and_table3_block_structure():
    diag = DiagnosticMatrix(
        [f"d{i}" for i in range(9)], [f"e{i}" for i in range(9)], np.eye(9, dtype=int).tolist()
    )
    assert diag.mean_diagnosis_accuracy() == 1.0
    # Table 3: tests d1–d3 only see e1–e3, d4–d6 e4–e6, d7–d9 e7–e9 (one unit each)
    m = from_sets(TABLE_3)
    ones = m.entries == "1"
    for b in range(3):
        blk = slice(3 * b, 3 * b + 3)
        outside = np.ones(9, dtype=bool)
        outside[blk] = False
        assert not ones[blk][:, outside].any()
        assert ones[blk][:, blk].any(axis=0).all()


# ---------------------------------------------------------------- seed 000
TESTS_000 = ["w", "ma", "alpha", "mf"]  # ω̂−ω, m̂a−ma, α̂−α, m̂f−mf
FAULTS_000 = ["ma_sensor", "w_sensor", "alpha_input", "mf_input"]
# Table II, one row per fault as printed ("-" don't care → "x"), transposed below.
TABLE_II = {
    "ma_sensor": ["x", "1", "1", "1"],
    "w_sensor": ["1", "0", "1", "1"],
    "alpha_input": ["1", "1", "1", "0"],
    "mf_input": ["1", "1", "0", "1"],
}


def table2() -> DiagnosticMatrix:
    rows = [[TABLE_II[f][t] for f in FAULTS_000] for t in range(4)]
    return DiagnosticMatrix(TESTS_000, FAULTS_000, rows)


@pytest.mark.parametrize(
    "pattern, fault",
    [
        ((1, 1, 1, 0), "alpha_input"),  # Fig. 9: all exceed but the m_f residual
        ((0, 1, 1, 1), "ma_sensor"),  # Fig. 10: all but the engine speed residual
        ((1, 1, 0, 1), "mf_input"),  # Fig. 11: all but the throttle residual
        ((1, 0, 1, 1), "w_sensor"),  # Fig. 12: all but the mass-air residual
        ((1, 1, 1, 1), "ma_sensor"),  # don't care on ω̂−ω: nonzero also fits
        ((-1, 1, -1, 1), "ma_sensor"),  # "non-zero" = either sign
        ((0, 0, 0, 0), None),  # Fig. 8: no fault
        ((0, 1, 0, 0), None),  # no signature fits
    ],
)
def test_table_ii_patterns(pattern, fault):
    m = table2()
    res = m.match(np.array([pattern], dtype=float))
    expected = [f == fault for f in FAULTS_000]
    assert res.matched[0].tolist() == expected
    assert not res.undecidable[0]


def test_table_ii_isolable_despite_dont_care():
    m = table2()
    assert m.isolability_groups() == [[f] for f in FAULTS_000]
    comp = m.compatible()
    assert (comp == np.eye(4, dtype=bool)).all()


def test_dont_care_and_sign_compatibility():
    m = DiagnosticMatrix(
        ["t1", "t2"],
        ["A", "B", "C", "P", "N", "Q"],
        [["1", "1", "1", "+", "-", "1"], ["x", "0", "1", "0", "0", "0"]],
    )
    comp = m.compatible()
    i = {f: k for k, f in enumerate(m.faults)}
    assert comp[i["A"], i["B"]] and comp[i["A"], i["C"]]  # x fits 0 and 1
    assert not comp[i["B"], i["C"]]
    assert not comp[i["P"], i["N"]]  # opposite signs are told apart
    assert comp[i["Q"], i["P"]] and comp[i["Q"], i["N"]]  # "1" fits either sign
    # connected components: {A, B, C, P, N, Q} all chained through B/Q
    assert m.isolability_groups() == [["A", "B", "C", "P", "N", "Q"]]
    res = m.match([[1, 0], [-1, 0], [1, 1]])
    assert res.matched[0].tolist() == [True, True, False, True, False, True]
    assert res.matched[1].tolist() == [True, True, False, False, True, True]
    assert res.matched[2].tolist() == [True, False, True, False, False, False]


# ---------------------------------------------------------------- unknowns
def test_unknown_symptoms():
    m = table2()
    nan = math.nan
    res = m.match([[nan, 1, 1, 1], [1, nan, 1, 1], [nan, nan, nan, nan]])
    # unknown ω̂−ω is a don't care for ma_sensor; the others are contradicted by m_a, m_f
    assert res.matched[0].tolist() == [True, False, False, False]
    assert res.unknown[0].tolist() == [False] * 4
    # unknown m̂a−ma: ma_sensor and w_sensor need it; alpha/mf are contradicted
    assert res.matched[1].tolist() == [False] * 4
    assert res.unknown[1].tolist() == [True, True, False, False]
    assert res.unknown[2].all() and not res.matched[2].any()
    assert res.undecidable.tolist() == [False, True, True]


def test_bad_symptoms_rejected():
    m = table4()
    with pytest.raises(ValueError, match="-1, 0"):
        m.match([[2, 0, 0, 0]])
    with pytest.raises(ValueError, match="n_samples"):
        m.match([[1, 0, 0]])


# ---------------------------------------------------------------- nearest
def test_nearest_signature_certainty_ordering():
    m = table4()
    res = m.nearest([[1, 1, 0, math.nan], [1, 1, 1, 0], [0, 0, 0, 0]])
    # sample 0 over r1..r3 = (1, 1, 0): EP exact, V one off, P0/S two off, X three off
    assert np.allclose(res.certainties[0], [1.0, 1 / 3, 1 / 3, 0.0, 2 / 3])
    order = np.argsort(-res.certainties[0], kind="stable")
    assert [FAULTS_001[k] for k in order] == ["f_EP", "f_V", "f_P0", "f_S", "f_X"]
    assert res.fault[0] == 0 and res.certainty[0] == 1.0
    # sample 1 (1, 1, 1, 0): three faults one test off, two three tests off
    assert np.allclose(res.certainties[1], [0.75, 0.75, 0.75, 0.25, 0.25])
    assert res.fault[1] == 0 and res.certainty[1] == 0.75
    # no symptom: no fault
    assert res.fault[2] == -1 and math.isnan(res.certainty[2])


def test_nearest_wrong_sign_counts_as_mismatch():
    m = DiagnosticMatrix(["t1", "t2"], ["up", "down"], [["+", "-"], ["1", "1"]])
    res = m.nearest([[-1, 1]])
    assert res.certainties[0].tolist() == [0.5, 1.0]
    assert res.fault[0] == 1


# ---------------------------------------------------------------- fuzzy
def crisp(symptoms: np.ndarray) -> np.ndarray:
    s = np.asarray(symptoms, dtype=int)
    mem = np.zeros(s.shape + (3,))
    np.put_along_axis(mem, (s + 1)[..., None], 1.0, axis=2)
    return mem


def test_fuzzy_with_crisp_memberships_equals_exact_match():
    for m in (table4(), table2()):
        rng = np.random.default_rng(7)
        s = rng.integers(-1, 2, size=(200, len(m.tests)))
        cert = m.fuzzy(crisp(s))
        assert set(np.unique(cert)) <= {0.0, 1.0}
        assert (cert == m.match(s.astype(float)).matched).all()
        assert cert.any()  # some random patterns do match a fault


def test_fuzzy_min_t_norm_on_graded_memberships():
    m = table4()
    #               N    0    P
    mem = np.array(
        [
            [0.0, 0.3, 0.7],  # r1
            [0.6, 0.4, 0.0],  # r2
            [0.0, 0.9, 0.1],  # r3
            [0.2, 0.8, 0.0],  # r4
        ]
    )
    cert = m.fuzzy(mem[None])[0]
    # EP (B B S S): min(.7, .6, .9, .8); P0 (S B B S): min(.3, .6, .1, .8); …
    assert np.allclose(cert, [0.6, 0.1, 0.1, 0.1, 0.2])
    # a don't-care test does not lower the certainty; a sign uses only its membership
    m2 = DiagnosticMatrix(["a", "b"], ["F", "G"], [["x", "+"], ["1", "1"]])
    mem2 = np.array([[[0.0, 1.0, 0.0], [0.7, 0.1, 0.2]]])
    assert np.allclose(m2.fuzzy(mem2)[0], [0.7, 0.0])
    mem2[0, 1, 1] = math.nan
    out = m2.fuzzy(mem2)[0]
    assert math.isnan(out[0]) and math.isnan(out[1])


# ---------------------------------------------------------------- files
# the shared Table-4 file, with one row written with integers (both forms are allowed)
EXAMPLE = VALVE_TABLE4.replace('["0", "0", "0", "1", "1"]', "[0, 0, 0, 1, 1]")
assert EXAMPLE != VALVE_TABLE4


def test_load_example_file(tmp_path):
    p = tmp_path / "valve_unit_matrix.toml"
    p.write_text(EXAMPLE, encoding="utf-8")
    m = load_matrix(p)
    assert m.name == "valve_unit"
    assert m.tests == TESTS_001 and m.faults == FAULTS_001
    assert (m.entries == table4().entries).all()


def _problems(text: str) -> list[str]:
    with pytest.raises(MatrixError) as ei:
        parse_matrix(text, "m.toml")
    return ei.value.problems


@pytest.mark.parametrize(
    "old, new, expected",
    [
        (
            '{ test = "r3"',
            '{ test = "r9"',
            ["m.toml:10: unknown test 'r9'", "no row for test 'r3'"],
        ),
        ('"0", "1", "1", "1", "0"]', '"0", "1", "1", "1"]', ["m.toml:10: row 'r3' has 4 entries"]),
        ('"1", "1", "0", "0", "0"', '"1", "1", "0", "?", "0"', ["m.toml:9: row 'r2', fault f_X"]),
        ("[0, 0, 0, 1, 1]", "[0, 0, 0, 2, 1]", ["m.toml:11: row 'r4', fault f_X: bad entry 2"]),
        ('"f_X", "f_V"]', '"f_X", "f_EP"]', ["m.toml:5: duplicate fault 'f_EP'"]),
        ('"r3", "r4"]', '"r3", "r3"]', ["m.toml:4: duplicate test 'r3'"]),
        ('{ test = "r4"', '{ test = "r2"', ["m.toml:11: duplicate row for test 'r2'"]),
        ('  { test = "r4", row = [0, 0, 0, 1, 1] },\n', "", ["m.toml:6: no row for test 'r4'"]),
        ('name = "valve_unit"', 'name = "valve_unit"\nlabel = 3', ["m.toml:4: unknown key"]),
        ('tests = ["r1"', 'tests = [r1"', ["m.toml:4: TOML syntax error"]),
        ("[matrix]", "[matrx]", ["m.toml:1: missing [matrix] table"]),
    ],
)
def test_file_errors_with_line_numbers(old, new, expected):
    assert old in EXAMPLE
    problems = _problems(EXAMPLE.replace(old, new, 1))
    for e in expected:
        assert any(p.startswith(e) or e in p for p in problems), (e, problems)
    assert all(p.startswith("m.toml:") for p in problems)
    # one line number (issue 37): not the parser's own 'at line L, column C' beside ours
    assert all("line" not in p.split("TOML syntax error")[-1] for p in problems), problems


def test_unreadable_file(tmp_path):
    with pytest.raises(MatrixError, match="cannot read"):
        load_matrix(tmp_path / "absent.toml")
