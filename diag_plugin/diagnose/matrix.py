"""Diagnostic matrix: file format, isolability analysis and fault reasoning.

A diagnostic matrix relates tests (residuals, rows) to faults (columns); the
column of a fault is its *signature* (Kościelny et al., seed 001, Tables 1–4;
Laukonen et al., seed 000, Table II). Entries:

``"1"``  the test reacts to the fault, either sign (seed 001 "B", big);
``"0"``  the test does not react (seed 001 "S", small; seed 000 "zero");
``"+"`` / ``"-"``  the test reacts with that sign;
``"x"`` / ``"*"``  don't care (seed 000 Table II's "-"): the fault may or may not
move the test, so any symptom value is consistent with it.

Each entry is stored as the set of symptom values it allows, ``allowed[t, f, k]``
for ``k`` = 0 (N, −1), 1 (zero, 0), 2 (P, +1). Every rule below is written on
that array, vectorised over samples.

File format (TOML, edited by an expert, ``file:line`` errors like
:mod:`diag_plugin.rulebase.document`)::

    [matrix]
    name = "valve_unit"                      # optional
    tests = ["r1", "r2", "r3", "r4"]
    faults = ["f_EP", "f_P0", "f_S", "f_X", "f_V"]
    rows = [
      { test = "r1", row = ["1", "0", "1", "0", "1"] },
      ...
    ]

One row per test, in any order, each exactly once; the row lists one entry per
fault in ``faults`` order (integers 0 and 1 are accepted for ``"0"``/``"1"``).
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from diag_plugin.tomllines import syntax_error
from historian.errors import ProblemsError

__all__ = [
    "ENTRIES",
    "DiagnosticMatrix",
    "MatchResult",
    "MatrixError",
    "NearestResult",
    "RuleConclusions",
    "load_matrix",
    "parse_matrix",
]

#: Allowed symptom values (N, 0, P) per matrix entry.
ENTRIES: dict[str, tuple[bool, bool, bool]] = {
    "1": (True, False, True),
    "0": (False, True, False),
    "+": (False, False, True),
    "-": (True, False, False),
    "x": (True, True, True),
    "*": (True, True, True),
}


class MatrixError(ProblemsError):
    """A matrix file has problems; ``problems`` lists ``file:line: what``."""


def _canon(entry: object) -> str | None:
    """Canonical entry string, or None when ``entry`` is not a valid entry."""
    if isinstance(entry, bool):
        return None
    if isinstance(entry, int) and entry in (0, 1):
        return str(entry)
    if isinstance(entry, str):
        e = entry.strip().lower()
        if e == "\u2212":  # typographic minus
            e = "-"
        return e if e in ENTRIES else None
    return None


@dataclass(frozen=True)
class MatchResult:
    """Exact-match result: ``matched`` and ``unknown`` are boolean (n_samples × n_faults)."""

    matched: np.ndarray
    unknown: np.ndarray

    @property
    def undecidable(self) -> np.ndarray:
        """Samples (bool, n_samples) where at least one fault could not be decided."""
        return self.unknown.any(axis=1)


@dataclass(frozen=True)
class NearestResult:
    """Nearest-signature result.

    ``fault``: index of the nearest fault per sample (−1: no symptom or no
    relevant decided test); ``certainty``: its certainty (NaN where ``fault`` is
    −1); ``certainties``: every fault's certainty (n_samples × n_faults, NaN
    where the fault has no relevant decided test or is undetectable).
    """

    fault: np.ndarray
    certainty: np.ndarray
    certainties: np.ndarray


@dataclass
class RuleConclusions:
    """Conclusions of the fault rules (seed 001, rules (10)–(14)), per sample.

    ``firing``: each fault rule's premise degree α_f (min t-norm); ``normal``: the degree α_0
    of the fault-free rule (every constrained test small); ``certainty``: the normalised
    certainty factor of ``e_f = N`` (the element faulty), α_f over the sum of α_0 and the
    degrees of the distinct rules; ``correct``: the ELSE branch ``e_f = P`` (the element
    correct), 1 − certainty. All n_samples × n_faults but ``normal`` (n_samples). A rule is
    judged on its known tests (a premise over an unknown test is left out, as the nearest
    signature leaves the test out) and is NaN only when none of its tests is known."""

    firing: np.ndarray
    normal: np.ndarray
    certainty: np.ndarray
    correct: np.ndarray


class DiagnosticMatrix:
    """Tests × faults matrix with entries from :data:`ENTRIES` (seed 001 Table 1 layout).

    ``entries`` is a sequence of rows, one per test, each with one entry per fault.
    Raises ``ValueError`` on an inconsistent shape, duplicate name or bad entry
    (files go through :func:`load_matrix`, which reports ``file:line`` instead).
    """

    def __init__(
        self,
        tests: Sequence[str],
        faults: Sequence[str],
        entries: Sequence[Sequence[str | int]],
        name: str = "",
    ):
        self.tests = [str(t) for t in tests]
        self.faults = [str(f) for f in faults]
        self.name = name
        for kind, names in (("test", self.tests), ("fault", self.faults)):
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise ValueError(f"duplicate {kind} name(s): {', '.join(dup)}")
        if len(entries) != len(self.tests):
            raise ValueError(f"{len(entries)} rows for {len(self.tests)} tests")
        canon: list[list[str]] = []
        for t, row in zip(self.tests, entries, strict=True):
            if len(row) != len(self.faults):
                raise ValueError(f"row {t!r} has {len(row)} entries for {len(self.faults)} faults")
            out = []
            for e in row:
                c = _canon(e)
                if c is None:
                    raise ValueError(f"row {t!r}: bad entry {e!r}")
                out.append("x" if c == "*" else c)
            canon.append(out)
        #: canonical entries, strings, (n_tests × n_faults)
        self.entries = np.array(canon, dtype=object).reshape(len(self.tests), len(self.faults))
        #: allowed symptom values per entry, bool (n_tests × n_faults × 3) for N, 0, P
        self.allowed = np.array([[ENTRIES[e] for e in row] for row in canon], dtype=bool).reshape(
            len(self.tests), len(self.faults), 3
        )
        #: entries that constrain the symptom (not don't-care), bool (n_tests × n_faults)
        self.relevant = ~self.allowed.all(axis=2)

    def __repr__(self) -> str:
        return f"DiagnosticMatrix({len(self.tests)} tests × {len(self.faults)} faults)"

    # ------------------------------------------------------------ analysis
    @property
    def detectable(self) -> np.ndarray:
        """Bool per fault: its column has at least one ``1`` or sign entry, so every
        occurrence of the fault moves at least one test (seed 001 Table 1)."""
        return (~self.allowed[:, :, 1]).any(axis=0)

    def compatible(self) -> np.ndarray:
        """Bool (n_faults × n_faults): signatures ``a`` and ``b`` are *compatible* when
        one symptom pattern matches both, i.e. on every test their allowed value sets
        intersect. A don't-care is compatible with everything, ``1`` with ``+`` and
        ``-``, ``0`` only with ``0`` and don't-care. Compatible faults cannot be told
        apart by the exact match for that pattern."""
        inter = self.allowed[:, :, None, :] & self.allowed[:, None, :, :]
        return inter.any(axis=3).all(axis=0)

    def isolability_groups(self) -> list[list[str]]:
        """Groups of detectable faults that are not isolable from each other.

        Seed 001 (Section 2): faults are differentiated when their signatures differ.
        With don't-cares "differ" means *incompatible* (see :meth:`compatible`); a
        group is a connected component of the compatibility graph, so a fault is
        alone in its group exactly when no symptom pattern that fits its signature
        fits any other fault's. Undetectable faults are left out (see
        :attr:`undetectable`). Groups follow the order of ``faults``.
        """
        comp = self.compatible()
        det = self.detectable
        seen = np.zeros(len(self.faults), dtype=bool)
        groups: list[list[str]] = []
        for f in range(len(self.faults)):
            if seen[f] or not det[f]:
                continue
            stack, comp_f = [f], []
            seen[f] = True
            while stack:
                g = stack.pop()
                comp_f.append(g)
                for h in np.flatnonzero(comp[g] & det & ~seen):
                    seen[h] = True
                    stack.append(int(h))
            groups.append([self.faults[i] for i in sorted(comp_f)])
        return groups

    @property
    def undetectable(self) -> list[str]:
        """Faults no test is sure to see (DAMADICS elementary diagnosis DGN0 with OK)."""
        return [f for f, d in zip(self.faults, self.detectable, strict=True) if not d]

    def diagnosis_accuracy(self) -> dict[str, float]:
        """Theoretical diagnosis accuracy per fault, DAMADICS Benchmark Definition v1.0
        App. II: ``dacc_t,i = 1 / L_i`` with ``L_i`` the number of faults in the
        elementary diagnosis (isolability group) fault ``i`` falls into.

        Undetectable faults are in DGN0 together with the fault-free state and are
        never indicated, so their accuracy is 0 here (our choice; the definition
        speaks only of the sets DGNk of unisolable faults).
        """
        acc = dict.fromkeys(self.faults, 0.0)
        for g in self.isolability_groups():
            for f in g:
                acc[f] = 1.0 / len(g)
        return acc

    def mean_diagnosis_accuracy(self) -> float:
        """Theoretical mean diagnosis accuracy ``dacc_tm = (1/N) Σ_i dacc_t,i`` over the
        N faults of the matrix (DAMADICS Benchmark Definition v1.0 App. II); 1.0
        when every fault is detectable and isolable."""
        if not self.faults:
            return math.nan
        return float(np.mean(list(self.diagnosis_accuracy().values())))

    # ----------------------------------------------------------- reasoning
    def _symptoms(self, symptoms: np.ndarray) -> np.ndarray:
        s = np.atleast_2d(np.asarray(symptoms, dtype=float))
        if s.ndim != 2 or s.shape[1] != len(self.tests):
            raise ValueError(f"symptoms must be n_samples × {len(self.tests)}, got {s.shape}")
        ok = np.isnan(s) | np.isin(s, (-1.0, 0.0, 1.0))
        if not ok.all():
            raise ValueError("symptoms must be -1, 0, +1 or NaN (unknown)")
        return s

    def _consistency(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per (sample, test, fault): symptom known, and (if known) allowed by the entry."""
        known = ~np.isnan(s)
        idx = np.where(known, s, 0).astype(np.intp) + 1  # N → 0, zero → 1, P → 2
        # allowed[t, f, idx[n, t]] → (n, t, f)
        fits = np.take_along_axis(
            self.allowed[None, :, :, :],
            idx[:, :, None, None].repeat(len(self.faults), axis=2),
            axis=3,
        )[..., 0]
        return known, fits

    def match(self, symptoms: np.ndarray) -> MatchResult:
        """Exact signature match (seed 001 Table 4 with ``d_j`` from the threshold K;
        seed 000 Table II with its "-" don't-cares), vectorised over samples.

        ``symptoms``: n_samples × n_tests with −1, 0, +1 or NaN (unknown). A fault
        matches a sample when every test its signature constrains shows an allowed
        value (``1`` allows ±1, a sign only that sign, ``0`` only 0; don't-care
        anything, unknown included). Only detectable faults can match, so a sample
        without symptoms matches no fault. A fault is ``unknown`` (and not matched)
        when no decided test contradicts it but a test it constrains is unknown;
        :attr:`MatchResult.undecidable` flags those samples.
        """
        s = self._symptoms(symptoms)
        known, fits = self._consistency(s)
        rel = self.relevant[None, :, :]
        contradicted = (rel & known[:, :, None] & ~fits).any(axis=1)
        missing = (rel & ~known[:, :, None]).any(axis=1)
        det = self.detectable[None, :]
        matched = det & ~contradicted & ~missing
        unknown = det & ~contradicted & missing
        return MatchResult(matched=matched, unknown=unknown)

    def nearest(self, symptoms: np.ndarray) -> NearestResult:
        """Nearest signature with a certainty, for samples without an exact match.

        Over the tests a fault's signature constrains (not don't-care) and whose
        symptom is known, ``d`` counts the tests whose symptom the entry does not
        allow (Hamming distance; a wrong sign counts 1) and ``n_rel`` counts those
        tests; ``certainty = 1 − d / n_rel`` (1 for an exact match, NaN when
        ``n_rel = 0``). Only detectable faults take part. The nearest fault is the
        one with the highest certainty (ties: the first in ``faults`` order);
        samples without any nonzero known symptom get fault −1.
        """
        s = self._symptoms(symptoms)
        known, fits = self._consistency(s)
        rel = self.relevant[None, :, :] & known[:, :, None]
        n_rel = rel.sum(axis=1)
        d = (rel & ~fits).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            cert = np.where(n_rel > 0, 1.0 - d / np.maximum(n_rel, 1), np.nan)
        cert[:, ~self.detectable] = np.nan
        any_symptom = (np.nan_to_num(s, nan=0.0) != 0).any(axis=1)
        has = ~np.isnan(cert).all(axis=1) & any_symptom
        best = np.full(s.shape[0], -1, dtype=np.intp)
        best_c = np.full(s.shape[0], np.nan)
        if has.any():
            b = np.nanargmax(np.where(np.isnan(cert[has]), -np.inf, cert[has]), axis=1)
            best[has] = b
            best_c[has] = cert[has][np.arange(b.size), b]
        return NearestResult(fault=best, certainty=best_c, certainties=cert)

    def fuzzy(self, memberships: np.ndarray) -> np.ndarray:
        """Fuzzy isolation, seed 001 eqs. (10)–(14), vectorised over samples.

        ``memberships``: n_samples × n_tests × 3, the degrees of each test's symptom
        in N, 0, P (three-valued fuzzy residual evaluation). Each fault has one rule
        ``IF r_1 = A_1 AND … AND r_J = A_J THEN fault``; its certainty is the rule's
        firing degree with the min t-norm for AND, as in the seed's rules: the
        degree of ``A_j`` is max(N, P) for ``1`` (the seed's "big" B), P for ``+``,
        N for ``-``, the 0 membership for ``0`` (the seed's "small" S), and 1 for a
        don't-care. The seed evaluates one rule per fault and does not normalise
        across faults, so neither do we (certainties need not sum to 1).
        Undetectable faults get 0. NaN memberships in a test a fault constrains
        make that fault's certainty NaN. Returns n_samples × n_faults in [0, 1].
        """
        m = np.asarray(memberships, dtype=float)
        if m.ndim == 2:
            m = m[None]
        if m.ndim != 3 or m.shape[1:] != (len(self.tests), 3):
            raise ValueError(
                f"memberships must be n_samples × {len(self.tests)} × 3, got {m.shape}"
            )
        # degree[n, t, f] = max over allowed k of m[n, t, k]
        masked = np.where(self.allowed[None], m[:, :, None, :], -np.inf)
        deg = masked.max(axis=3)
        deg = np.where(self.relevant[None], deg, 1.0)
        nan_rel = (np.isnan(m).any(axis=2)[:, :, None] & self.relevant[None]).any(axis=1)
        cert = np.clip(deg.min(axis=1), 0.0, 1.0)
        cert[nan_rel] = np.nan
        cert[:, ~self.detectable] = 0.0
        return cert

    def rules(self, memberships: np.ndarray) -> RuleConclusions:
        """Fuzzy diagnosis by seed 001's rules (10)–(14), one rule per fault column::

            IF (r_1 = A_1f) AND … AND (r_J = A_Jf) THEN e_f = N ELSE e_f = P

        with ``A = B`` (big: max(μN, μP), or the sign's membership) where the column has a
        1 or a sign, ``A = S`` (small: μ0) where it has a 0, and no premise for a
        don't-care; AND is the min t-norm (:meth:`fuzzy` gives these firing degrees α_f).
        The seed reads N as the element's faulty state and P as its correct one; we do too.

        Aggregation and normalisation (the seed gives none): beside the fault rules the
        unit has the fault-free rule ``IF every r_j = S THEN every e = P`` with degree α_0.
        A sample's evidence is shared among the distinct hypotheses — fault-free and each
        distinct rule premise (faults with identical columns are one hypothesis, the seed's
        indistinguishable faults; each of them gets the hypothesis' certainty) — so the
        certainty factor of ``e_f = N`` is ``c_f = α_f / (α_0 + Σ_g α_g)`` over the distinct
        rules ``g``, and the ELSE branch holds to ``1 − c_f``. Hence ``c_f ≥ 0.5`` exactly when
        ``e_f = N`` outweighs ``e_f = P``, the unit's default isolation rule. With crisp
        memberships this is the exact match of the matrix, split evenly among compatible
        distinct signatures. A pattern no rule covers (all α ≈ 0) gives certainty 0 to every
        fault: an unknown fault, not a guess.
        """
        m = np.asarray(memberships, dtype=float)
        if m.ndim == 2:
            m = m[None]
        unknown = np.isnan(m).any(axis=2)  # n × tests
        # a premise over an unknown test is left out, as the nearest signature leaves the
        # test out: each rule is judged on its known tests, unknown when it has none
        firing = self.fuzzy(np.where(unknown[:, :, None], 1.0, m))
        none_known = ~(self.relevant[None] & ~unknown[:, :, None]).any(axis=1)
        firing[none_known & self.detectable[None]] = np.nan
        constrained = self.relevant.any(axis=1)
        z = np.where(unknown, np.nan, m[:, :, 1])[:, constrained]
        normal = np.full(m.shape[0], np.nan) if not constrained.any() else z.min(axis=1)
        some = ~np.isnan(z).all(axis=1) if constrained.any() else np.zeros(m.shape[0], bool)
        if some.any():
            normal[some] = np.nanmin(z[some], axis=1)
        # one hypothesis per distinct rule premise
        keys = [self.allowed[:, f, :].tobytes() for f in range(len(self.faults))]
        first = np.array([keys.index(k) for k in keys])
        distinct = np.unique(first[self.detectable]) if self.detectable.any() else first[:0]
        total = np.nansum(firing[:, distinct], axis=1) + np.nan_to_num(normal)
        with np.errstate(invalid="ignore", divide="ignore"):
            cert = np.where(total[:, None] > 1e-12, firing / total[:, None], 0.0)
        cert = np.where(np.isnan(firing), np.nan, np.clip(cert, 0.0, 1.0))
        return RuleConclusions(firing=firing, normal=normal, certainty=cert, correct=1.0 - cert)


# ---------------------------------------------------------------- file I/O
def _lines_matching(lines: list[str], pattern: str) -> list[int]:
    rx = re.compile(pattern)
    return [i + 1 for i, line in enumerate(lines) if rx.search(line.split("#", 1)[0])]


def parse_matrix(text: str, path: str | Path = "<matrix>") -> DiagnosticMatrix:
    """Parse matrix TOML ``text`` (see module doc); problems raise :class:`MatrixError`
    with ``file:line: what``, all problems found at once."""
    lines = text.splitlines()
    problems: list[str] = []

    def err(line: int, msg: str) -> None:
        problems.append(f"{path}:{line}: {msg}")

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise MatrixError([syntax_error(path, exc)]) from None

    def line_of(key: str) -> int:
        hits = _lines_matching(lines, r"^\s*" + re.escape(key) + r"\s*=")
        return hits[0] if hits else (_lines_matching(lines, r"^\s*\[\s*matrix\s*\]") or [1])[0]

    mat = data.get("matrix")
    if not isinstance(mat, dict):
        raise MatrixError([f"{path}:1: missing [matrix] table"])
    for key in sorted(set(mat) - {"name", "description", "tests", "faults", "rows"}):
        err(line_of(key), f"unknown key {key!r} in [matrix]")

    names: dict[str, list[str]] = {}
    for key in ("tests", "faults"):
        val = mat.get(key)
        if not isinstance(val, list) or not val or not all(isinstance(v, str) for v in val):
            err(line_of(key), f"{key} must be a non-empty list of names")
            names[key] = []
            continue
        seen: set[str] = set()
        for v in val:
            if v in seen:
                err(line_of(key), f"duplicate {key[:-1]} {v!r}")
            seen.add(v)
        names[key] = list(dict.fromkeys(val))
    tests, faults = names["tests"], names["faults"]

    rows = mat.get("rows")
    if not isinstance(rows, list):
        err(line_of("rows"), "rows must be a list of { test = ..., row = [...] }")
        raise MatrixError(problems)
    rows_line = line_of("rows")
    by_test: dict[str, list[str | int]] = {}
    occurrences: dict[str, int] = {}  # rows seen per test name, valid or not
    for k, r in enumerate(rows):
        if not isinstance(r, dict) or not isinstance(r.get("test"), str):
            err(rows_line, f'row {k + 1}: needs test = "name" and row = [...]')
            continue
        t = r["test"]
        nth = occurrences.get(t, 0)
        occurrences[t] = nth + 1
        hits = [
            h
            for h in _lines_matching(lines, r"\btest\s*=\s*[\"']" + re.escape(t) + r"[\"']")
            if h >= rows_line
        ]
        ln = hits[nth] if nth < len(hits) else rows_line
        for key in sorted(set(r) - {"test", "row"}):
            err(ln, f"row {t!r}: unknown key {key!r}")
        if tests and t not in tests:
            err(ln, f"unknown test {t!r} (tests are {', '.join(tests)})")
            continue
        if t in by_test:
            err(ln, f"duplicate row for test {t!r}")
            continue
        entries = r.get("row")
        if not isinstance(entries, list):
            err(ln, f"row {t!r}: row must be a list of entries")
            continue
        if faults and len(entries) != len(faults):
            err(ln, f"row {t!r} has {len(entries)} entries, expected {len(faults)} (one per fault)")
            continue
        bad = [(j, e) for j, e in enumerate(entries) if _canon(e) is None]
        for j, e in bad:
            fname = faults[j] if j < len(faults) else str(j + 1)
            err(ln, f"row {t!r}, fault {fname}: bad entry {e!r} (use 1, 0, x, *, +, -)")
        if bad:
            continue
        by_test[t] = entries
    for t in tests:
        if t not in occurrences:
            err(rows_line, f"no row for test {t!r}")
    if problems:
        raise MatrixError(problems)
    name = mat.get("name", "")
    return DiagnosticMatrix(tests, faults, [by_test[t] for t in tests], name=str(name))


def load_matrix(path: str | Path) -> DiagnosticMatrix:
    """Read a matrix file (see module doc); problems raise :class:`MatrixError`."""
    from diag_plugin.tomllines import read_text

    path = Path(path)
    return parse_matrix(read_text(path, MatrixError), path)
