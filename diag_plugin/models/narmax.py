"""Second-order polynomial (NARMAX) model and its model-file codec (method ``narmax2``).

Laukonen et al., eq. 12: ``ŷ(k) = Σ β_i x_i + Σ Σ β_ij x_i x_j`` over the regression vector
``x`` (here: the model file's inputs, e.g. ``F[k-1]``, ``CV[k-1]``), plus a constant term,
fitted by batch least squares (the parameters enter linearly). Every linear term, every square
and every pairwise product is kept (``1 + d + d(d+1)/2`` terms).

Internally the inputs are scaled to ``[-1, 1]`` over their nominal spans (conditioning); the
least-squares rows are folded chunk by chunk into a QR factor (``RᵀR = XᵀX``, never formed),
which is a sufficient statistic: ``partial_fit`` on consecutive chunks and ``merge`` of models
trained on parts give the model of all rows (up to rounding). The file lists the terms and
their coefficients in engineering units::

    [rules]
    list = [
        { term = "1", coef = 12.5 },
        { term = "CV[k-1]", coef = -0.31 },
        { term = "CV[k-1]^2", coef = 0.0012 },
        { term = "P1[k]*CV[k-1]", coef = -4.1e-05 },
    ]

A term left out of an edited file has coefficient 0 (truncating the expansion, the seed's
hardest design step). Retraining writes every term again.
"""

from __future__ import annotations

import itertools
import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numba as nb
import numpy as np

from diag_plugin.models.codec import RuleCodec
from diag_plugin.models.estimation import (
    CHUNK_ROWS,
    FreeRunCapabilities,
    QRLeastSquares,
    SpanEstimator,
    as_2d,
    as_xy,
    detail,
    finite_rows,
    free_run,
    spans_and_lags,
)
from diag_plugin.models.fedrow import fed_row
from diag_plugin.models.protocol import Capabilities, Prediction
from diag_plugin.models.spec import ModelSpec

if TYPE_CHECKING:
    from diag_plugin.rulebase.document import RuleBase

log = logging.getLogger(__name__)

PARAMS = ("input_spans", "output_span", "output_lags")
HEADER = """\
# Model file (diag-plugin), method narmax2: a second-order polynomial of the inputs
# (Laukonen et al., eq. 12). Edit by hand, then run `diag rules check FILE`.
# One term per line: term = "1" (constant), "SPEC" (linear), "SPEC^2" (square) or
# "SPEC*SPEC" (product), with SPEC an input of [[inputs]]; coef in engineering units
# (output unit per unit of the term). A term left out counts as 0.
"""


def term_pairs(d: int) -> list[tuple[int, ...]]:
    """The terms of eq. 12 (plus constant) as input-index tuples: ``()``, ``(i,)``, ``(i, j)``
    with ``i ≤ j``, in this order."""
    return [(), *((i,) for i in range(d)), *itertools.combinations_with_replacement(range(d), 2)]


def _features(Z: np.ndarray) -> np.ndarray:
    """Rows of eq. 12's regressors (constant, linear, squares and products) of ``Z``."""
    n, d = Z.shape
    iu, ju = np.triu_indices(d)
    return np.hstack([np.ones((n, 1)), Z, Z[:, iu] * Z[:, ju]])


@nb.njit(cache=True, nogil=True)
def _free_run_kernel(X, cols, lags, lo, hi, centre, half, coef):  # pragma: no cover - compiled
    """:func:`~diag_plugin.models.estimation.free_run` of eq. 12 compiled: row by row, each lag
    column ``cols[c]`` gets the estimate ``lags[c]`` rows earlier (the measured value before it
    exists or after a row without one), the row is clipped to its span (``lo``, ``hi``),
    scaled to ``z = (x − centre) / half`` and its output is ``φ(z) · coef`` over the terms of
    :func:`term_pairs` (constant, linear, then ``z_i z_j`` for ``i ≤ j``) — the arithmetic of
    :func:`_features` and ``_predict_rows``."""
    n, d = X.shape
    yhat = np.full(n, np.nan)
    x = np.empty(d)
    z = np.empty(d)
    for k in range(n):
        if not fed_row(X, k, cols, lags, yhat, x):
            continue
        y = coef[0]
        for j in range(d):
            z[j] = (min(max(x[j], lo[j]), hi[j]) - centre[j]) / half[j]
            y += z[j] * coef[1 + j]
        t = 1 + d
        for i in range(d):
            for j in range(i, d):
                y += z[i] * z[j] * coef[t]
                t += 1
        yhat[k] = y
    return yhat


def _raw_basis(centre: np.ndarray, half: np.ndarray) -> np.ndarray:
    """``M`` with ``φ(z) = M φ(x)`` for ``z = (x − centre) / half``: coefficients over the scaled
    terms ``b`` are ``Mᵀ b`` over the terms in engineering units."""
    d = centre.size
    terms = term_pairs(d)
    pos = {t: k for k, t in enumerate(terms)}
    M = np.zeros((len(terms), len(terms)))
    M[0, 0] = 1.0
    for i in range(d):
        M[pos[(i,)], 0] = -centre[i] / half[i]
        M[pos[(i,)], pos[(i,)]] = 1.0 / half[i]
    for i, j in itertools.combinations_with_replacement(range(d), 2):
        r, s = pos[(i, j)], 1.0 / (half[i] * half[j])
        M[r, r] = s
        M[r, pos[(i,)]] += -centre[j] * s
        M[r, pos[(j,)]] += -centre[i] * s
        M[r, 0] += centre[i] * centre[j] * s
    return M


class Narmax2Regressor(SpanEstimator):
    """Second-order polynomial model (Laukonen et al., eq. 12) by batch least squares.

    Parameters
    ----------
    input_spans : sequence of (lo, hi), optional
        Nominal span of each input (scaling, and the range beyond which inputs are clipped
        and flagged); by default the range seen in the first ``fit``/``partial_fit``.
    output_span : (lo, hi), optional
        Nominal span of the output.
    output_lags : sequence of int, optional
        Per input, ``d > 0`` if it is the output lagged by ``d`` samples: such inputs are fed
        back by :meth:`simulate` (free run).
    """

    _params = PARAMS

    capabilities = FreeRunCapabilities(
        Capabilities(incremental=True, mergeable=True, rule_regions=False, free_run=True)
    )

    def __init__(
        self,
        input_spans: Sequence[tuple[float, float]] | None = None,
        output_span: tuple[float, float] | None = None,
        output_lags: Sequence[int] | None = None,
    ) -> None:
        self._keep(locals())

    # ------------------------------------------------------------------ set-up
    def _init(self, X: np.ndarray, y: np.ndarray | None = None) -> None:
        d = X.shape[1]
        if self.output_lags is not None and len(self.output_lags) != d:
            raise ValueError(f"output_lags has {len(self.output_lags)} entries for {d} inputs")
        self._set_spans(X, y)
        self.n_features_in_ = d
        self.terms_ = self._term_list(d)
        self.qr_: QRLeastSquares | None = QRLeastSquares(len(self.terms_))
        self.y_sum_ = 0.0
        self.n_samples_seen_ = 0
        self._coef = None

    @property
    def _centre(self) -> np.ndarray:
        return self.spans_.mean(axis=1)

    @property
    def _half(self) -> np.ndarray:
        return (self.spans_[:, 1] - self.spans_[:, 0]) / 2.0

    def _scaled(self, X: np.ndarray) -> np.ndarray:
        return (X - self._centre) / self._half

    # ---------------------------------------------------------------- training
    def partial_fit(self, X: Any, y: Any) -> Narmax2Regressor:
        """Add a chunk of rows; consecutive chunks give the model of one ``fit`` on all."""
        X, y = as_xy(X, y)
        if not hasattr(self, "spans_"):
            self._init(X, y)
        elif X.shape[1] != self.n_features_in_:
            raise ValueError(f"model has {self.n_features_in_} inputs, X has {X.shape[1]}")
        if self.qr_ is None:
            raise ValueError(
                "this model was read from its coefficients and has no training statistics: "
                "fit a new one"
            )
        ok = finite_rows(X, y)
        if not ok.all():
            log.debug("narmax2: %d rows with a missing value skipped", int((~ok).sum()))
        X, y = X[ok], y[ok]
        for s in range(0, X.shape[0], CHUNK_ROWS):
            self.qr_.update(self._phi(self._scaled(X[s : s + CHUNK_ROWS])), y[s : s + CHUNK_ROWS])
        self.n_samples_seen_ += int(y.size)
        self.y_sum_ += float(y.sum())
        self._coef = None
        return self

    def merge(self, other: Narmax2Regressor) -> Narmax2Regressor:
        """Add the rows ``other`` was trained on (same spans): the model of both data sets."""
        if self._merge_empty(other):
            return self
        if not np.array_equal(self.spans_, other.spans_):
            raise ValueError("cannot merge NARMAX models with different input spans")
        if self.qr_ is None or other.qr_ is None:
            raise ValueError("cannot merge a model read from its coefficients")
        self.qr_.merge(other.qr_)
        self.n_samples_seen_ += other.n_samples_seen_
        self.y_sum_ += other.y_sum_
        self._coef = None
        return self

    # ------------------------------------------------------------- parameters
    @property
    def coef_scaled_(self) -> np.ndarray:
        """Coefficients of the terms over inputs scaled to [-1, 1] on their spans."""
        self._check_fitted()
        if self._coef is None:
            self._coef = self.qr_.solve()
        return self._coef

    @property
    def coef_(self) -> np.ndarray:
        """Coefficients of :attr:`terms_` in engineering units (eq. 12 plus constant)."""
        return self._basis().T @ self.coef_scaled_

    def set_coefficients(self, coef: Sequence[float]) -> Narmax2Regressor:
        """Use explicit coefficients in engineering units (a model file); the model then has no
        training statistics."""
        coef = np.asarray(coef, dtype=np.float64)
        if coef.shape != (len(self.terms_),):
            raise ValueError(f"expected {len(self.terms_)} coefficients, got {coef.shape}")
        M = self._basis()
        self._coef = np.linalg.solve(M.T, coef)
        self.qr_ = None
        return self

    @property
    def output_mean_(self) -> float:
        """Mean training output; for a model read from its coefficients, its output at the
        centre of the input spans."""
        if self.n_samples_seen_:
            return self.y_sum_ / self.n_samples_seen_
        if not hasattr(self, "spans_"):
            return math.nan
        return float(self._predict_rows(self._centre[None, :])[0])

    # ------------------------------------------------------------------ state
    def to_state(self) -> dict[str, Any]:
        """Parameters and training state as plain JSON values (no pickle)."""
        params = self._span_params()
        params["output_lags"] = None if self.output_lags is None else list(self.output_lags)
        return {
            "params": params,
            "qr": None if self.qr_ is None else self.qr_.to_state(),
            "coef": None if self.qr_ is not None else self.coef_scaled_.tolist(),
            "n_samples_seen": int(self.n_samples_seen_),
            "y_sum": float(self.y_sum_),
        }

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> Narmax2Regressor:
        """The model a :meth:`to_state` describes."""
        m = cls(**state["params"]).init(len(state["params"]["input_spans"]))
        if state.get("qr") is not None:
            m.qr_ = QRLeastSquares.from_state(state["qr"], len(m.terms_))
        else:
            m.qr_ = None
            m._coef = np.asarray(state["coef"], dtype=np.float64)
        m.n_samples_seen_ = int(state["n_samples_seen"])
        m.y_sum_ = float(state["y_sum"])
        return m

    # --------------------------------------------------------------- inference
    def _predict_rows(self, X: np.ndarray) -> np.ndarray:
        return self._phi(self._scaled(X)) @ self.coef_scaled_

    # the terms, their regressors and the change of basis (a subclass may keep fewer terms)
    @staticmethod
    def _term_list(d: int) -> list[tuple[int, ...]]:
        return term_pairs(d)

    @staticmethod
    def _phi(Z: np.ndarray) -> np.ndarray:
        return _features(Z)

    def _basis(self) -> np.ndarray:
        return _raw_basis(self._centre, self._half)

    def predict_detail(self, X: Any) -> Prediction:
        """Prediction (one step ahead: inputs as measured) with a reason code per sample."""
        self._check_fitted()
        X = self._check_X(X)
        return detail(X, self.spans_, self._predict_rows)

    def predict(self, X: Any) -> np.ndarray:
        """Model output (eq. 12); NaN where an input is missing."""
        return self.predict_detail(X).y

    def simulate(self, X: Any) -> np.ndarray:
        """Free-run (output-error) output over consecutive rows: inputs that are lags of the
        output get the model's own earlier outputs (see
        :func:`~diag_plugin.models.estimation.free_run`)."""
        self._check_fitted()
        X = self._check_X(X)
        lags = np.asarray(self.output_lags or [0] * self.n_features_in_, dtype=np.int64)
        cols = np.flatnonzero(lags > 0)
        if cols.size == 0 or type(self)._phi is not Narmax2Regressor._phi:
            return free_run(X, lags, self.spans_, self._predict_rows)
        return _free_run_kernel(
            np.ascontiguousarray(X, dtype=np.float64),
            cols,
            lags[cols],
            np.ascontiguousarray(self.spans_[:, 0]),
            np.ascontiguousarray(self.spans_[:, 1]),
            np.ascontiguousarray(self._centre),
            np.ascontiguousarray(self._half),
            np.ascontiguousarray(self.coef_scaled_, dtype=np.float64),
        )

    def term_names(self, specs: Sequence[str]) -> list[str]:
        """The terms written with the input specs: ``1``, ``A``, ``A^2``, ``A*B``."""
        return [format_term(t, specs) for t in self.terms_]

    def _check_X(self, X: Any) -> np.ndarray:
        X = as_2d(X)
        if X.shape[1] != self.n_features_in_:
            raise ValueError(f"model has {self.n_features_in_} inputs, X has {X.shape[1]}")
        return X


def format_term(t: tuple[int, ...], specs: Sequence[str]) -> str:
    """A term as the file writes it."""
    if not t:
        return "1"
    if len(t) == 1:
        return specs[t[0]]
    i, j = t
    return f"{specs[i]}^2" if i == j else f"{specs[i]}*{specs[j]}"


def parse_term(text: str, specs: Sequence[str]) -> tuple[int, ...]:
    """Input indices of a term written as ``1``, ``A``, ``A^2`` or ``A*B`` (any order of the
    factors; specs compared in their normal form); ``ValueError`` says what is wrong."""
    from diag_plugin.regressors import InputSpec

    norm = {str(InputSpec.parse(s)): k for k, s in enumerate(specs)}
    text = text.strip()
    if text == "1":
        return ()
    factors: list[int] = []
    for part in text.split("*"):
        part = part.strip()
        power = 1
        if part.endswith("^2"):
            part, power = part[:-2].strip(), 2
        try:
            key = str(InputSpec.parse(part))
        except ValueError:
            key = part
        if key not in norm:
            raise ValueError(f"{part!r} is not an input (inputs: {', '.join(specs)})")
        factors += [norm[key]] * power
    if len(factors) > 2:
        raise ValueError(f"term {text!r} is of order {len(factors)}; eq. 12 stops at order 2")
    return tuple(sorted(factors))


# ------------------------------------------------------------------ the file codec
@dataclass
class Term:
    """One line of a NARMAX model file."""

    term: tuple[int, ...]
    coef: float
    line: int = 0
    comments: list[str] = field(default_factory=list)
    trailing: str = ""


TERM_KEYS = {"term", "coef"}


class NarmaxCodec(RuleCodec):
    """Estimator factory and term I/O of ``narmax2`` (a polynomial: no FCL form)."""

    method = "narmax2"
    estimator = Narmax2Regressor
    header = HEADER

    #: what a term the method does not have is told (see :meth:`allows`)
    only = ""

    def default_options(self) -> dict[str, Any]:
        """Method options written into a new file's ``[rules]`` table: none."""
        return {}

    def new_estimator(self, spec: ModelSpec) -> Narmax2Regressor:
        """An untrained model (the codec's :attr:`estimator`) with the spec's spans; lags of
        the output are fed back in free run."""
        return self.estimator(**spans_and_lags(spec, self.method))

    def to_model(self, rb: RuleBase) -> Narmax2Regressor:
        """The model the file describes (terms not listed count 0)."""
        m = self.new_estimator(rb.spec).init(len(rb.inputs))
        coef = np.zeros(len(m.terms_))
        pos = {t: k for k, t in enumerate(m.terms_)}
        for r in rb.rules:
            coef[pos[r.term]] = r.coef
        return m.set_coefficients(coef)

    def apply_training(self, rb: RuleBase, model: Narmax2Regressor) -> list[Term]:
        """Every term with its trained coefficient; comments of terms already there stay."""
        old = {r.term: r for r in rb.rules}
        out = []
        for t, c in zip(model.terms_, model.coef_, strict=True):
            r = Term(t, float(c))
            if t in old:
                r.comments, r.trailing = old[t].comments, old[t].trailing
            out.append(r)
        return out

    def size(self, model: Narmax2Regressor) -> int:
        """Terms of the model."""
        return len(model.terms_)

    def read_rules(
        self, rb: RuleBase, items: list, positions: Sequence[tuple[int, list[str], str]]
    ) -> list[Term]:
        """Terms from the ``[rules] list``; each problem goes to ``rb.error(line, …)``."""
        self.check_options(rb)
        specs = [v.spec for v in rb.inputs]
        out: list[Term] = []
        seen: dict[tuple[int, ...], int] = {}
        for e in self.entries(rb, items, positions, "term", TERM_KEYS, 'term = "...", coef = ...'):
            item, line, where = e.item, e.line, e.where
            text = item.get("term")
            term: tuple[int, ...] = ()
            if not isinstance(text, str):
                rb.error(line, f'{where}: term must be a string like "1", "A", "A^2" or "A*B"')
            else:
                try:
                    term = parse_term(text, specs)
                except ValueError as exc:
                    rb.error(line, f"{where}: {exc}")
            coef = item.get("coef")
            if isinstance(coef, bool) or not isinstance(coef, int | float):
                rb.error(line, f"{where}: coef must be a number, got {coef!r}")
            elif not math.isfinite(coef):
                rb.error(line, f"{where}: coef must be finite, got {coef!r}")
            if len(rb.problems) > e.problems:
                continue
            if term in seen:
                rb.error(line, f"{where}: duplicate term {text!r} (first at line {seen[term]})")
                continue
            seen[term] = line
            out.append(Term(term, float(coef), line, e.comments, e.trailing))
        for t in out:
            if not self.allows(t.term):
                rb.error(t.line, f"term {format_term(t.term, specs)!r}: {self.only}")
        return [t for t in out if self.allows(t.term)]

    def check_options(self, rb: RuleBase) -> None:
        """Each ``[rules]`` key but ``list`` that the method does not take goes to
        ``rb.error`` (``narmax2`` and ``linear`` take none)."""
        _no_options(rb, self.method)

    def allows(self, term: tuple[int, ...]) -> bool:
        """Whether the method's file form has ``term`` (``narmax2``: every term it parses;
        a narrower method says what it has in :attr:`only`)."""
        return True

    def rule_table(self, rb: RuleBase) -> tuple[list[str], list[list[str]]]:
        """Columns and rows for ``diag rules show``: each term and its coefficient."""
        specs = [v.spec for v in rb.inputs]
        return ["term", "coef"], [[format_term(r.term, specs), f"{r.coef:.6g}"] for r in rb.rules]

    def format_rules(self, rb: RuleBase) -> str:
        """The ``list = [...]`` text, one term per line in the model's term order."""
        specs = [v.spec for v in rb.inputs]
        order = {t: k for k, t in enumerate(term_pairs(len(specs)))}
        # a quoted tag name ("Flow rate"[k]) is escaped, as TOML's basic strings are
        return self.format_list(
            sorted(rb.rules, key=lambda r: order.get(r.term, len(order))),
            lambda r: (
                f"{{ term = {json.dumps(format_term(r.term, specs), ensure_ascii=False)}, "
                f"coef = {_num(r.coef)} }},"
            ),
        )


def _no_options(rb: RuleBase, method: str = "narmax2") -> None:
    for key in rb.options:
        rb.error(rb.line_of("rules", key), f"{method} takes no option {key!r} in [rules]")


def _num(v: float) -> str:
    """A float as TOML, 12 significant digits."""
    text = f"{v:.12g}"
    return text if any(c in text for c in ".en") else text + ".0"
