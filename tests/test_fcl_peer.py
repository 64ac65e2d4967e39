"""FCL/FLL export checked against independent fuzzy engines (peers).

* The fuzzylite 6 command-line tool (C++, Debian package ``fuzzylite``) imports
  the IEC 61131-7 FCL text of :func:`to_fcl` and evaluates a data set.
* pyfuzzylite 8 (Python) imports no FCL (only the fuzzylite language), so it
  loads :func:`to_fll` and evaluates the same points, vectorised.

Both must reproduce :meth:`WangMendelRegressor.predict` of the model read back
from the rule-base file within 1e-6 of the output span, at 1,000 random points
in the span (and at points outside it, where the model clips), and give no
value exactly where the model has none.
"""

from __future__ import annotations

import math
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from helpers import require, requires

from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor
from diag_plugin.rulebase.document import RuleBase, Variable
from diag_plugin.rulebase.fcl import identifier, to_fcl, to_fll

FUZZYLITE = shutil.which("fuzzylite")
needs_fuzzylite = requires(
    "the fuzzylite command",
    FUZZYLITE is not None,
    "Debian package 'fuzzylite', version 6; .ci/sysdeps installs it",
)
TOL = 1e-6  # of the output span


def _train_data(n_inputs: int, seed: int = 0, n: int = 30_000):
    """Valve-like data over the whole span, with a hole so some rule cells stay empty."""
    rng = np.random.default_rng(seed)
    cv = rng.uniform(0, 100, n)
    if n_inputs == 1:
        keep = (cv < 40) | (cv > 52)
        f = 40 * (cv / 100) ** 2 + rng.normal(0, 0.3, n)
        return cv[keep, None], f[keep]
    p = rng.uniform(200, 800, n)
    keep = ~((cv > 35) & (cv < 60) & (p > 380) & (p < 560))
    f = 40 * (cv / 100) ** 2 * np.sqrt(p / 800) + rng.normal(0, 0.3, n)
    return np.c_[cv, p][keep], f[keep]


INPUTS = [
    Variable("CV[k-1]", "U", "%", (0.0, 100.0), 31),
    Variable("P1[k]", "P1_", "kPa", (200.0, 800.0), 31),
]


def _rulebase(tmp_path, n_inputs: int, shape: str) -> RuleBase:
    """Train, save, lock-delete one rule by hand (as an expert would), reload."""
    path = tmp_path / f"m{n_inputs}_{shape}.toml"
    rb = RuleBase.new(
        f"valve_{n_inputs}_{shape}",
        Variable("F[k]", "F", "t/h", (0.0, 40.0), 31),
        INPUTS[:n_inputs],
        shape=shape,
        path=path,
    )
    X, y = _train_data(n_inputs)
    rb.apply_training(rb.new_model().fit(X, y), {"source": "synthetic"})
    rb.save()
    text = path.read_text(encoding="utf-8")
    pattern = r'(\{ if = \["U20"[^\]]*\], then = )[0-9.]+(, n = \d+, sd = [0-9.]+, lock = )false'
    text, k = re.subn(pattern, r"\1nan\2true", text, count=1)
    assert k == 1
    path.write_text(text, encoding="utf-8")
    return RuleBase.load(path)


def _points(rb: RuleBase, seed: int = 1, n: int = 1000, outside: float = 0.0):
    rng = np.random.default_rng(seed)
    cols = []
    for v in rb.inputs:
        lo, hi = v.span
        pad = outside * (hi - lo)
        cols.append(rng.uniform(lo - pad, hi + pad, n))
    return np.column_stack(cols)


def _trend_move(model: WangMendelRegressor, X: np.ndarray) -> np.ndarray:
    """How far the model's answer moves past its spans along its linear trend (``trend_``,
    at most REACH of a span past its end): FCL has no such thing, the peer clips."""
    from diag_plugin.fuzzy._numpy_kernels import REACH

    move = np.zeros(X.shape[0])
    for k, p in enumerate(model.partitions_):
        lo, hi = p.lo, p.lo + p.step * (p.n - 1)
        reach = REACH * (hi - lo)
        move += model.trend_[k + 1] * (
            np.clip(X[:, k], lo - reach, hi + reach) - np.clip(X[:, k], lo, hi)
        )
    return move


def _compare(
    rb: RuleBase, X: np.ndarray, y_peer: np.ndarray, min_finite: int, mixed: bool = True
) -> None:
    # FCL holds the fine rule grid (IEC 61131-7 has no coarser levels behind it): the peer
    # reproduces the model's fine grid alone; past an input's span the model's answer moves
    # along its trend, the peer's holds at the edge: the peer plus that move is the model
    state = rb.to_model().to_state()
    state["params"]["levels"] = 0
    model = WangMendelRegressor.from_state(state)
    pred = model.predict_detail(X)
    y = pred.y
    y_peer = y_peer + _trend_move(model, X)
    finite = np.isfinite(y)
    assert finite.sum() >= min_finite, f"only {finite.sum()} supported points"
    if mixed:  # points where no rule fires, and where only some of the fired rules exist
        assert (~finite).sum() >= 20
        assert (finite & (pred.support < 1 - 1e-9)).sum() >= 10
    span = rb.output.span[1] - rb.output.span[0]
    err = np.abs(y_peer[finite] - y[finite]) / span
    assert err.max() <= TOL, f"max error {err.max():.3g} of span at {X[finite][err.argmax()]}"
    # the peer has no value exactly where the model has none (no rule fires)
    assert np.isnan(y_peer[~finite]).all()


def _run_fuzzylite(tmp_path, rb: RuleBase, X: np.ndarray) -> np.ndarray:
    fcl = to_fcl(rb)
    names = [identifier(v.spec) for v in rb.inputs]
    (tmp_path / "model.fcl").write_text(fcl, encoding="utf-8")
    data = " ".join(names) + "\n" + "\n".join(" ".join(repr(float(v)) for v in row) for row in X)
    (tmp_path / "in.fld").write_text(data + "\n", encoding="utf-8")
    cmd = [FUZZYLITE, "-i", "model.fcl", "-if", "fcl", "-o", "out.fld", "-of", "fld"]
    cmd += ["-d", "in.fld", "-decimals", "12", "-dheader", "true", "-dinputs", "true"]
    res = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    out = (tmp_path / "out.fld").read_text().splitlines()
    assert out[0].split() == names + [identifier(rb.output.spec)]
    table = np.array([[float(t) for t in line.split()] for line in out[1:]])
    assert table.shape == (X.shape[0], X.shape[1] + 1)
    np.testing.assert_allclose(table[:, :-1], X, rtol=1e-10, atol=1e-10)
    return table[:, -1]


PEER_PYTHON = Path(__file__).resolve().parents[1] / ".venv-peers" / "bin" / "python"
PYFUZZYLITE = r"""
import sys, numpy as np, fuzzylite as fl
engine = fl.FllImporter().from_string(open(sys.argv[1]).read())
ready = engine.is_ready()  # an output without terms is "not ready" but still evaluates
engine.input_values = np.loadtxt(sys.argv[2], ndmin=2)  # one column per input, all at once
engine.process()
np.savetxt(sys.argv[3], np.asarray(engine.output_values)[:, 0], fmt="%.17g")
print("ready" if ready else "not ready")
"""


def _run_pyfuzzylite(fll: str, X: np.ndarray, tmp_path: Path, rules: bool = True) -> np.ndarray:
    """pyfuzzylite in its own venv (it pins numpy<2; ours is numpy 2): FLL in, outputs out."""
    require("pyfuzzylite peer venv .venv-peers", PEER_PYTHON.exists(), "`make test` creates it")
    (tmp_path / "model.fll").write_text(fll, encoding="utf-8")
    np.savetxt(tmp_path / "in.txt", X, fmt="%.17g")
    res = subprocess.run(
        [str(PEER_PYTHON), "-c", PYFUZZYLITE, "model.fll", "in.txt", "out.txt"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ready" or not rules
    return np.loadtxt(tmp_path / "out.txt", ndmin=1)


CASES = [(2, "trapezoidal"), (2, "triangular"), (1, "trapezoidal")]


@needs_fuzzylite
@pytest.mark.parametrize(("n_inputs", "shape"), CASES)
def test_fuzzylite_cli_reads_fcl_and_agrees(tmp_path, n_inputs, shape):
    rb = _rulebase(tmp_path, n_inputs, shape)
    X = _points(rb)
    _compare(rb, X, _run_fuzzylite(tmp_path, rb, X), min_finite=900)
    # beyond the span the model clips the inputs, the shoulders give the same, and the
    # model's answer then moves along its trend (_compare adds that move to the peer's)
    Xo = _points(rb, seed=2, n=300, outside=0.3)
    _compare(rb, Xo, _run_fuzzylite(tmp_path, rb, Xo), min_finite=250, mixed=False)


@pytest.mark.parametrize(("n_inputs", "shape"), CASES)
def test_pyfuzzylite_reads_fll_and_agrees(tmp_path, n_inputs, shape):
    rb = _rulebase(tmp_path, n_inputs, shape)
    X = _points(rb)
    _compare(rb, X, _run_pyfuzzylite(to_fll(rb), X, tmp_path), min_finite=900)
    Xo = _points(rb, seed=2, n=300, outside=0.3)
    _compare(rb, Xo, _run_pyfuzzylite(to_fll(rb), Xo, tmp_path), min_finite=250, mixed=False)


def test_fcl_text_structure(tmp_path):
    rb = _rulebase(tmp_path, 2, "trapezoidal")
    live = [r for r in rb.rules if not math.isnan(r.then)]
    assert len(live) == len(rb.rules) - 1  # the locked-deleted rule is left out
    text = to_fcl(rb)
    lines = [ln.split("//")[0].strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln]
    assert lines[0] == "FUNCTION_BLOCK valve_2_trapezoidal"
    assert lines[-1] == "END_FUNCTION_BLOCK"
    for opening, closing in [
        ("VAR_INPUT", "END_VAR"),
        ("VAR_OUTPUT", "END_VAR"),
        ("FUZZIFY CV_k_1", "END_FUZZIFY"),
        ("FUZZIFY P1_k", "END_FUZZIFY"),
        ("DEFUZZIFY F_k", "END_DEFUZZIFY"),
        ("RULEBLOCK rules", "END_RULEBLOCK"),
    ]:
        i = lines.index(opening)
        assert closing in lines[i + 1 :]
    assert "CV_k_1 : REAL; // CV[k-1] (sets U00..U30, %)" in text
    assert "METHOD : COGS;" in lines and "AND : PROD;" in lines
    assert "RANGE := (200.0 .. 800.0);" in lines
    # 31 sets per input, in point form; shoulders at the span's ends
    fuzz = [ln for ln in lines if ln.startswith("TERM U")]
    assert len(fuzz) == 31
    # h = 100/30, core half-width h/4: U15 centred on 50, U30 a shoulder up to the span's end
    assert fuzz[0] == "TERM U00 := (0.0, 1.0) (0.833333333333, 1.0) (2.5, 0.0);"
    u15 = "(47.5, 0.0) (49.1666666667, 1.0) (50.8333333333, 1.0) (52.5, 0.0)"
    assert fuzz[15] == f"TERM U15 := {u15};"
    assert fuzz[30] == "TERM U30 := (97.5, 0.0) (99.1666666667, 1.0) (100.0, 1.0);"
    rules = [ln for ln in lines if ln.startswith("RULE ")]
    singletons = [ln for ln in lines if re.match(r"TERM R\d+ := ", ln)]
    assert len(rules) == len(singletons) == len(live)
    pat = re.compile(r"RULE (\d+) : if CV_k_1 is U(\d\d) and P1_k is P1_(\d\d) then F_k is R(\d+);")
    for k, (line, r) in enumerate(zip(rules, live, strict=True), 1):
        m = pat.fullmatch(line)
        assert m, line
        assert (int(m[1]), int(m[4])) == (k, k)
        assert (int(m[2]), int(m[3])) == r.premise
        assert float(singletons[k - 1].split(":=")[1].rstrip(";")) == r.then


def test_identifiers():
    assert identifier("CV[k-1]") == "CV_k_1"
    assert identifier("dir(CV)[k-1]") == "dir_CV_k_1"
    assert identifier("diff(P1,P2)[k]") == "diff_P1_P2_k"
    assert identifier("dir(CV,0.5)[k-1]") == "dir_CV_0_5_k_1"
    assert identifier("hour()[k]") == "hour_k"
    assert identifier("2nd") == "v_2nd"
    assert identifier("if") == "v_if"
    taken: set[str] = set()
    assert [identifier(s, taken) for s in ("A[k]", "A(k)", "A k")] == ["A_k", "A_k_2", "A_k_3"]


def test_untrained_rule_base_and_labels_that_are_no_identifiers(tmp_path):
    rb = RuleBase.new(
        "2nd model",
        Variable("F[k]", "F", "t/h", (0.0, 40.0), 5),
        [Variable("dir(CV,0.5)[k-1]", "d-", "", (-1.0, 1.0), 3)],
        shape="triangular",
        path=tmp_path / "m.toml",
    )
    rb.save()
    rb = RuleBase.load(tmp_path / "m.toml")
    text = to_fcl(rb)
    assert "FUNCTION_BLOCK v_2nd_model" in text
    assert "dir_CV_0_5_k_1 : REAL; // dir(CV,0.5)[k-1] (sets d-00..d-02)" in text
    assert "TERM d_00 := (-1.0, 1.0) (0.0, 0.0);" in text
    assert "TERM d_01 := (-1.0, 0.0) (0.0, 1.0) (1.0, 0.0);" in text
    assert "RULE " not in text
    if FUZZYLITE is not None:  # no rule fires anywhere: no value
        y = _run_fuzzylite(tmp_path, rb, np.array([[-2.0], [0.3], [1.0]]))
        assert np.isnan(y).all()
    y = _run_pyfuzzylite(to_fll(rb), np.array([[-2.0], [0.3], [1.0]]), tmp_path, rules=False)
    assert np.isnan(y).all()
