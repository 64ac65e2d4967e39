"""A reading beyond every answer its test's model can give (issue 34, items 1 and 5).

A test is *unknown* where its model has no rule for the inputs (an input outside what the unit
learned, :mod:`~.operating`): the unit is CHECK_FUNCTION, as at an operating point it never
learned. But a Wang–Mendel model's answer, at any rule level, is a convex combination of the
values of its rules (the modified method's average conclusion, Kościelny et al. eq. 5, and the
multilinear interpolation between rules, whose weights are non-negative and sum to one): it
lies between the least and the greatest of them, whatever inputs it is given. So a reading
``y`` beyond that range ``[a, b]`` has a residual of at least its distance to it,

    ``|r| ≥ (y − clip(y, a, b)) · 100 / span``   (eq. 6 of the same paper),

even where the model cannot say what it would predict. The range is every level's node
values (a coarse level's least-squares nodes may reach past the fine rules) widened to the
output's learned span.

That bound is the test's residual only where the tag went there *on its own*: its reading left
the range while its test was still known (the inputs inside what the unit learned, so they did
not carry it there), and has stayed beyond it since (:func:`own_excursion`). A step of a
measured feed composition leaves its own test's range at once while the reaction's
temperatures that test reads follow it out of theirs later: the test keeps its residual (the
bound) and names the feed, where it was unknown and the step read as an operating point never
learned. Where the plant is moved to a new point by its inputs (a hand valve, a set-point, a
load), a test's inputs leave their range first and its output follows while the test is
unknown: no bound, the unit stays CHECK_FUNCTION and names the input (item 5). Models without
that property (linear, ``track``, NARMAX) get no bound.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["answer_range", "bound_residual", "own_excursion"]


def answer_range(model, out_range: tuple[float, float] | None) -> tuple[float, float, float] | None:
    """``(a, b, spread)``: the least and greatest value ``model`` can answer (module doc),
    widened to ``out_range`` and by the farthest its linear trend carries an answer past the
    inputs' spans (:data:`~diag_plugin.fuzzy._numpy_kernels.REACH` of each span times the
    slope), and the greatest local spread of its nodes (what a ``spread = true`` residual is
    divided by at most); None for a model whose answer is not bounded by its rules (not a
    fitted Wang–Mendel model)."""
    from diag_plugin.fuzzy._numpy_kernels import REACH
    from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor

    if not isinstance(model, WangMendelRegressor) or not model.keys_.size:
        return None
    g = model.inference_grid()
    v = np.concatenate([np.asarray(c, float) for c in g.conclusions])
    v = v[np.isfinite(v)]
    if not v.size:
        return None
    reach = float(np.sum(np.abs(g.trend[1:]) * REACH * g.step * (g.nsets - 1)))
    a, b = float(v.min()) - reach, float(v.max()) + reach
    if out_range is not None and all(np.isfinite(out_range)):
        a, b = min(a, float(out_range[0])), max(b, float(out_range[1]))
    sp = np.concatenate([np.asarray(x, float) for x in g.spreads]) if g.spreads else np.empty(0)
    sp = sp[np.isfinite(sp)]
    return a, b, float(sp.max()) if sp.size else 1.0


@nb.njit(cache=True)
def _own_kernel(outside, known, carry):  # pragma: no cover - numba
    n = outside.size
    own = np.empty(n, np.bool_)
    c = carry
    for k in range(n):
        c = outside[k] and (known[k] or c)
        own[k] = c
    return own, c


def own_excursion(outside: np.ndarray, known: np.ndarray, carry: bool) -> tuple[np.ndarray, bool]:
    """Per sample whether the reading is beyond its test's answer range (``outside``) having
    left it, or been beyond it, while the test was known (``known``) at a sample of the same
    excursion; ``carry``: that state at the end of the previous piece. Returns it and the state
    at this piece's end."""
    outside = np.ascontiguousarray(outside, bool)
    if not outside.any():
        return np.zeros(outside.size, bool), False
    own, c = _own_kernel(outside, np.ascontiguousarray(known, bool), bool(carry))
    return own, bool(c)


def bound_residual(
    r: np.ndarray, y: np.ndarray, rng: tuple[float, ...], scale: float, carry: bool,
    inside: np.ndarray | None = None,
) -> tuple[np.ndarray, bool]:  # fmt: skip
    """``r`` (a test's raw residuals in % of ``scale``, NaN unknown) with the bound
    ``(y − clip(y, a, b)) · 100 / scale`` where the test is unknown and the reading ``y`` is
    beyond ``rng = (a, b)`` on its own (:func:`own_excursion`, ``carry`` its state before the
    piece): it went there while the test was known and, where ``inside`` is given, while
    every input tag was inside what its model learned *at that sample* (an input read a few
    samples back may have left already, the reading following it before the model reads it);
    returns the residuals (a copy where any is filled) and the state after it."""
    a, b = rng[0], rng[1]
    with np.errstate(invalid="ignore"):
        outside = (y < a) | (y > b)  # NaN: not outside
    known = np.isfinite(r)
    own, c = own_excursion(outside, known if inside is None else known & inside, carry)
    fill = own & ~known
    if fill.any():
        r = r.copy()
        r[fill] = (y[fill] - np.clip(y[fill], a, b)) * 100.0 / scale
    return r, c
