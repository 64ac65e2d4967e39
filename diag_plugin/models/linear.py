"""A linear model of the inputs (method ``linear``) and its model-file codec.

``ŷ = β₀ + Σ β_i x_i``: the first-order part of Laukonen et al., eq. 12 (the ``narmax2``
polynomial without its squares and products), fitted by the same batch least squares over
inputs scaled to their spans (:class:`~diag_plugin.models.narmax.Narmax2Regressor`: a QR
factor, so ``partial_fit`` on consecutive chunks and ``merge`` of models trained on parts give
the model of all rows). ``diag unit build`` tests with it where a window is too short for a
rule grid: a residual of one tag against a linear combination of others is a PCA-like
parity relation (a residual subspace of one row), which a few hundred samples determine
(``1 + d`` parameters against a grid's ``sets^d``). The file is the ``narmax2`` form with the
constant and one term per input::

    [rules]
    list = [
        { term = "1", coef = 12.5 },
        { term = "FI101[k]", coef = 0.42 },
    ]
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from diag_plugin.models.estimation import spans_and_lags
from diag_plugin.models.narmax import Narmax2Regressor, NarmaxCodec
from diag_plugin.models.protocol import REASON_OUTSIDE, Prediction

if TYPE_CHECKING:
    from diag_plugin.models.spec import ModelSpec
    from diag_plugin.rulebase.document import RuleBase

HEADER = """\
# Model file (diag-plugin), method linear: y = b0 + sum of b_i * input_i (the first-order
# part of Laukonen et al., eq. 12). Edit by hand, then run `diag rules check FILE`.
# One term per line: term = "1" (constant) or "SPEC" (an input of [[inputs]]); coef in
# engineering units (output unit per input unit). A term left out counts as 0.
"""


#: how far past an input's span a linear test still answers: while the line's move beyond the
#: span's edge stays within this share of the output's span (the input's margin,
#: :data:`~diag_plugin.unitbuild.short.MARGIN`, in the output's terms)
EDGE_MOVE = 0.25

#: the ``[rules]`` option giving, per input, the variance of its measurement noise (engineering
#: units squared, 0 for none): the fit then corrects the coefficients for it (errors in
#: variables), where least squares would shrink the coefficient of a noisy input towards 0 (a
#: level's rate over a window: its noise 2σ²/n² of the level's σ, :mod:`~diag_plugin.
#: unitbuild.balance`)
INPUT_NOISE = "input_noise"

#: the ``[rules]`` option giving the output's range the test learned (``[lo, hi]``), where the
#: output's span is an instrument's (a tags CSV's ``lo``/``hi``): :data:`EDGE_MOVE` is a share
#: of it, not of all the instrument reads (issue 34, item 3)
LEARNED_OUTPUT = "learned_output"


def linear_terms(d: int) -> list[tuple[int, ...]]:
    """The constant and one term per input, as input-index tuples."""
    return [(), *((i,) for i in range(d))]


class LinearRegressor(Narmax2Regressor):
    """``ŷ = β₀ + Σ β_i x_i`` by batch least squares (see module doc); parameters as
    :class:`~diag_plugin.models.narmax.Narmax2Regressor`.

    Where an input is outside its span a line learned from a few hundred samples says little
    about a range it never saw: the test answers only while the line's own move past the
    span's edge stays within :data:`EDGE_MOVE` of the output's span (the prediction then
    follows the line, the reason stays ``outside``, the input is named); beyond that the
    prediction (at the span's edge) has no support, and a unit's test is unknown there (not
    a symptom). A slow input that drifts a little past the range it showed (SKAB's fluid
    temperature, a tenth of a degree) leaves the test answering — and seeing the flow
    collapse it is there for — where a move of a quarter of the output's range would be
    a guess.

    ``learned_output`` (optional ``(lo, hi)``): the output's range the model learned, where
    ``output_span`` is wider (an instrument's range): the allowance is :data:`EDGE_MOVE` of
    it (a pump's line learned at 74-82 % speed, its power's span the meter's 0-60 kW, moved
    15 kW past the edge before it went unknown: the whole night at 57 %)."""

    _params = (*Narmax2Regressor._params, LEARNED_OUTPUT, INPUT_NOISE)

    def __init__(
        self,
        input_spans: Any = None,
        output_span: tuple[float, float] | None = None,
        output_lags: Any = None,
        learned_output: tuple[float, float] | None = None,
        input_noise: Any = None,
    ) -> None:
        self._keep(locals())

    @property
    def coef_scaled_(self) -> np.ndarray:
        """The least-squares coefficients (scaled inputs), corrected for ``input_noise``
        (:data:`INPUT_NOISE`): the normal equations less the rows' expected noise,
        ``(ΦᵀΦ − N·Σ) c = Φᵀy`` (Fuller, *Measurement Error Models*, 1987, §2.2). Where the
        corrected matrix is not positive definite (a noise as large as the input's spread),
        least squares as they are."""
        noise = getattr(self, INPUT_NOISE, None)
        if noise is not None and self.qr_ is not None and self._coef is None:
            self._check_fitted()
            self._coef = self._corrected(np.asarray(noise, float))
        return super().coef_scaled_

    def _corrected(self, noise: np.ndarray) -> np.ndarray:
        """:attr:`coef_scaled_` of a fit with ``input_noise`` (its docstring)."""
        p = len(self.terms_)
        R = self.qr_.R
        if R.shape[0] < p:
            return self.qr_.solve()
        Ra, qb = R[:p, :p], R[:p, p]
        sigma = np.zeros(p)
        sigma[1:] = noise / self._half**2
        A = Ra.T @ Ra - self.qr_.n * np.diag(sigma)
        try:
            np.linalg.cholesky(A)
        except np.linalg.LinAlgError:
            return self.qr_.solve()
        return np.linalg.solve(A, Ra.T @ qb)

    def predict_detail(self, X: Any) -> Prediction:
        p = super().predict_detail(X)
        out = p.reason == REASON_OUTSIDE
        if not out.any():
            return p
        y, support = p.y.copy(), np.where(out, 0.0, p.support)
        # (NaN, NaN) where the output span is unknown
        learned = getattr(self, LEARNED_OUTPUT, None)  # a subclass may not take it
        lo, hi = self.output_span_ if learned is None else learned
        room = EDGE_MOVE * (hi - lo)
        if room > 0:  # NaN (an unknown output span) or a flat output: unknown, as before
            rows = np.flatnonzero(out)
            line = self._predict_rows(self._check_X(X)[rows])
            near = np.abs(line - p.y[rows]) <= room
            y[rows[near]] = line[near]
            support[rows[near]] = 1.0
        return Prediction(y, support, p.reason, p.level, p.spread)

    @staticmethod
    def _term_list(d: int) -> list[tuple[int, ...]]:
        return linear_terms(d)

    @staticmethod
    def _phi(Z: np.ndarray) -> np.ndarray:
        return np.hstack([np.ones((Z.shape[0], 1)), Z])

    def _basis(self) -> np.ndarray:
        """``M`` with ``φ(z) = M φ(x)`` for ``z = (x − centre) / half`` (first order)."""
        d = self._centre.size
        M = np.zeros((d + 1, d + 1))
        M[0, 0] = 1.0
        M[1:, 0] = -self._centre / self._half
        M[1:, 1:] = np.diag(1.0 / self._half)
        return M


def is_line(model) -> bool:
    """A linear test with inputs (not a joint test, not a level test): ``diag unit accept``
    merges its windows with an intercept each where a held set-point moved
    (:func:`within_merge`), and its thresholds are taken at each window's point
    (:func:`~diag_plugin.learn.thresholds.level_points`)."""
    return type(model) is LinearRegressor and getattr(model, "n_features_in_", 0) > 0


def within_merge(models: Sequence[LinearRegressor]) -> LinearRegressor:
    """The model of every row of ``models`` (each trained on one operating point, the same
    spans) with one intercept per point: the *within* (fixed-effects) least squares, its
    coefficients from each point's rows about that point's own means, pooled. ``merge``
    fits one line through every point, and where the points differ by something none of
    the inputs carries (a set-point constant while the inputs were chosen, moved since),
    the coefficients bend to cover the offset between the points: an aeration basin's
    blower test, a day at a new oxygen set-point accepted into 14 days at the old one,
    doubled its band (acceptance pass 11). A point's offset is then its mean residual,
    which the thresholds take per point (:func:`~diag_plugin.learn.thresholds.level_points`).

    Exact on the QR factors (:class:`~diag_plugin.models.estimation.QRLeastSquares`): each
    point's rows shifted to the mean of all rows in every column but the constant is
    ``[Φ | y]·T`` with ``T = I + e₀ δᵀ``, whose factor is ``R·T``: ``R`` with ``R₀₀ · δ``
    added to its first row (the constant's column of ``R`` is ``R₀₀ e₀``), so the first row
    becomes ``R₀₀`` times the grand means. The intercept is then the line's through the
    grand means; the model's rows and their output sum are all the points' (the same
    ``output_mean_``). The first model is changed in place and returned."""
    first, rest = models[0], [m for m in models[1:] if getattr(m, "n_samples_seen_", 0)]
    if not rest:
        return first
    parts = [first, *rest]
    if any(m.qr_ is None or m.qr_.R.shape[0] == 0 for m in parts):
        raise ValueError("cannot merge a model read from its coefficients")
    n = np.array([m.qr_.R[0, 0] ** 2 for m in parts])
    means = np.array([m.qr_.R[0] / m.qr_.R[0, 0] for m in parts])  # Σ column / rows
    grand = (n[:, None] * means).sum(axis=0) / n.sum()
    for m in parts:
        m.qr_.R[0, 1:] = m.qr_.R[0, 0] * grand[1:]
    for m in rest:
        first.merge(m)
    return first


class LinearCodec(NarmaxCodec):
    """Estimator factory and term I/O of ``linear`` (the ``narmax2`` file form, first order)."""

    method = "linear"
    estimator = LinearRegressor
    header = HEADER
    only = 'a linear model has only the constant "1" and its inputs'

    def allows(self, term: tuple[int, ...]) -> bool:
        """The constant and the inputs, no products."""
        return len(term) <= 1

    def new_estimator(self, spec: ModelSpec) -> LinearRegressor:
        """An untrained model with the spec's spans and its ``[rules] learned_output``."""
        opts = dict(spec.options)
        learned = opts.pop(LEARNED_OUTPUT, None)
        noise = opts.pop(INPUT_NOISE, None)
        kw = spans_and_lags(replace(spec, options=opts), self.method)
        return self.estimator(
            **kw,
            learned_output=None if learned is None else tuple(float(v) for v in learned),
            input_noise=None if noise is None else tuple(float(v) for v in noise),
        )

    def check_options(self, rb: RuleBase) -> None:
        """``learned_output`` (``[lo, hi]``, ``lo < hi``) and ``input_noise`` (one variance
        ≥ 0 per input) are the keys ``[rules]`` takes."""
        for key, value in rb.options.items():
            line = rb.line_of("rules", key)
            if key == INPUT_NOISE:
                ok = isinstance(value, list) and len(value) == len(rb.inputs)
                ok = ok and all(isinstance(v, int | float) and v >= 0 for v in value)
                if not ok:
                    rb.error(line, f"{key} must be one variance ≥ 0 per input, got {value!r}")
                continue
            if key != LEARNED_OUTPUT:
                rb.error(line, f"{self.method} takes no option {key!r} in [rules]")
                continue
            ok = isinstance(value, list) and len(value) == 2
            ok = ok and all(isinstance(v, int | float) and np.isfinite(v) for v in value)
            if not (ok and value[0] < value[1]):
                rb.error(line, f"{key} must be [lo, hi] with lo < hi, got {value!r}")
