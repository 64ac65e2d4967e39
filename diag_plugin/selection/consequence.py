"""Is a candidate input a consequence of the output rather than a cause? (issue 37)

A header pressure that sags with the flow explains the flow model's residual well — but it is
driven by the flow: a model that uses it predicts the output from its own effect, and a fault
that moves the output moves it too, so the residual stays blind to the fault. Two tests, both
on data (held-out where anything is fitted):

* **chain, not collider.** A cause ``c`` of ``y`` that is independent of the model's inputs
  ``x`` becomes dependent on them once ``y`` is known (``x → y ← c``: knowing ``y`` and ``x``
  tells ``c``). A consequence (``x → y → c``) is not: once ``y`` is known, ``x`` tells
  nothing more about ``c``. We fit ``c`` from ``y`` alone and from ``y`` with each model
  input (cell means over uniform sets, fitted before the cut and scored after it) and call
  ``c`` a consequence when ``y`` explains a fair share of it (:data:`MIN_R2`) and the model
  inputs add less than :data:`MAX_GAIN` of what ``y`` leaves unexplained.
* **lag structure.** The changes of ``c`` follow the changes of ``y``: the correlation of
  their first differences peaks with ``c`` lagging ``y`` (by at least one sample), clearly
  above (:data:`LAG_MARGIN`) any peak with ``c`` leading.

The chain test can only tell where what ``y`` leaves of ``c`` varies often enough to be
learned and scored: a manual valve moved a few times in the window leaves a handful of
levels, each new one putting the held-out rows in (output, input) cells the training rows
never visited, and every fit with a model input then scores worse than ``y`` alone — which
read as "the inputs add nothing", a consequence. So the test is judged only where the
training rows' residual of ``c`` from ``y`` holds :data:`MIN_ESS` effective independent values
or more (the effective sample size ``n / τ``, ``τ = 1 + 2 Σ ρ_k`` its integrated
autocorrelation time, summed up to the first lag where ``ρ_k`` is no longer positive — the
estimate the thresholds use, :func:`diag_plugin.models.series.effective_samples`); below it
:attr:`Consequence.unjudged` says so and nothing is flagged by it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from diag_plugin.models.series import effective_samples
from diag_plugin.selection.lags import lag_screen
from diag_plugin.selection.sets import set_index

#: share of the candidate's held-out variance the output must explain
MIN_R2 = 0.2
#: share of what the output leaves unexplained the model's inputs may add for a consequence
#: (a cause gains most of it: knowing the output and the inputs tells the cause)
MAX_GAIN = 0.25
#: a lagging peak must beat every leading one by this factor
LAG_MARGIN = 1.5
#: effective independent values the residual of the candidate from the output must hold in the
#: training part for the chain test to judge: a held-out ratio of errors over ``m`` independent
#: values is uncertain by about ``sqrt(2 / m)``; twice that must stay within :data:`MAX_GAIN`
MIN_ESS = 8.0 / MAX_GAIN**2
#: sets of the output and of a model input in the cell-mean fits (the output finer: what a
#: model input adds within one of the output's sets is what a coarse output grid leaves)
Y_SETS, X_SETS = 40, 8


@dataclass(frozen=True)
class Consequence:
    """The evidence: ``r2_y`` — held-out R² of the candidate from the output alone;
    ``r2_yx`` — with the output and the best model input; ``lag`` — samples by which the
    candidate's changes follow the output's (0: no such lag); ``ess`` — effective independent
    values of what the output leaves of the candidate in the training part
    (:func:`~diag_plugin.models.series.effective_samples`)."""

    r2_y: float
    r2_yx: float
    lag: int
    ess: float = math.inf

    @property
    def _reads_as_chain(self) -> bool:
        room = max(1.0 - self.r2_y, 1e-9)
        return self.r2_y >= MIN_R2 and (self.r2_yx - self.r2_y) / room < MAX_GAIN

    @property
    def judged(self) -> bool:
        """Whether the data can tell a chain from a collider (:data:`MIN_ESS`)."""
        return self.ess >= MIN_ESS

    @property
    def chain(self) -> bool:
        return self.judged and self._reads_as_chain

    @property
    def unjudged(self) -> bool:
        """The chain test would read a consequence, or has no held-out row to score (none at
        an output the training part saw varies the candidate), but the data cannot tell (not
        flagged)."""
        return not self.judged and (self._reads_as_chain or math.isnan(self.r2_y))

    @property
    def likely(self) -> bool:
        return self.chain or self.lag > 0

    def note(self, tag: str, output: str) -> str:
        why = []
        if self.chain:
            why.append(
                f"{output} explains {self.r2_y:.0%} of it and the model's inputs add "
                f"{max(self.r2_yx - self.r2_y, 0.0):.0%} (a cause would gain from them)"
            )
        if self.lag > 0:
            why.append(f"its changes follow {output}'s by {self.lag} samples")
        return (
            f"likely a consequence of {output}, not a cause: {'; '.join(why)}. A model using "
            f"{tag} predicts the output from its own effect, and a fault would move both"
        )

    def unjudged_note(self, tag: str, output: str) -> str:
        """Plain words for :attr:`unjudged`."""
        read = (
            f"the held-out rows at values of {output} the training part saw are too few or "
            f"hold one value of {tag}, and"
            if math.isnan(self.r2_y)
            else f"{output} explains {self.r2_y:.0%} of {tag}, but"
        )
        return (
            f"cause or consequence of {output}? these data cannot tell: {read} what "
            f"{output} leaves of {tag} takes about "
            f"{self.ess:.0f} independent values in the training part (it changes in a few "
            f"steps or slowly; {MIN_ESS:.0f} are needed to tell) — not flagged"
        )


def consequence(
    cand: np.ndarray,
    y: np.ndarray,
    inputs: Sequence[np.ndarray],
    cut: int,
    max_lag: int = 0,
) -> Consequence:
    """Evidence that ``cand`` is driven by ``y`` (see the module doc); rows before ``cut``
    fit, rows after it score."""
    seen = _seen(cand, y, cut)
    r2_y, left = _heldout_r2(cand, [y], [Y_SETS], cut, seen, residual=True)
    r2_yx = max([r2_y, *(_heldout_r2(cand, [y, x], [Y_SETS, X_SETS], cut, seen) for x in inputs)])
    lag = 0
    if max_lag > 0:
        dc, dy = np.diff(cand[:cut]), np.diff(y[:cut])
        lagging = lag_screen(dc, dy, max_lag)  # cand[k] against y[k-L]
        leading = lag_screen(dy, dc, max_lag)  # y[k] against cand[k-L]
        best = int(np.argmax(lagging))
        if best > 0 and lagging[best] > LAG_MARGIN * max(leading.max(), lagging[0], 1e-12):
            lag = best
    return Consequence(r2_y, r2_yx, lag, effective_samples(left))


def _seen(cand: np.ndarray, y: np.ndarray, cut: int) -> np.ndarray:
    """Rows whose output lies in one of its :data:`Y_SETS` sets that training rows (before
    ``cut``, ``cand`` known) visited: where the fit of ``cand`` from ``y`` answers from rows
    with the same output. Elsewhere — an output set the training part never reached, inside
    its range or beyond it — a cell-mean fit answers the training mean or the outer set's,
    which tells nothing of ``cand`` given ``y``, and neither fit is scored there."""
    ix = _index(y, cut, Y_SETS, clip=False)
    rows = np.arange(y.size)
    tr = (ix >= 0) & np.isfinite(cand) & (rows < cut)
    visited = np.bincount(ix[tr], minlength=Y_SETS) > 0
    return (ix >= 0) & visited[np.maximum(ix, 0)]


def _index(col: np.ndarray, cut: int, sets: int, clip: bool = True) -> np.ndarray:
    x = col[:cut][np.isfinite(col[:cut])]
    return set_index(col, x, sets, 0.005, least=10, clip=clip)


def _heldout_r2(
    target: np.ndarray,
    cols: Sequence[np.ndarray],
    sets: Sequence[int],
    cut: int,
    seen: np.ndarray,
    residual: bool = False,
) -> float | tuple[float, np.ndarray]:
    """Held-out R² of ``target`` from the cell means of ``cols`` (fitted before ``cut``),
    scored on the rows after it where ``seen``; with ``residual``, also the training rows'
    residual from those means (NaN where a row is not fitted)."""
    key = np.zeros(target.size, np.int64)
    bad = ~np.isfinite(target)
    for c, n in zip(cols, sets, strict=True):
        ix = _index(c, cut, n)
        key = key * n + ix
        bad |= ix < 0
    rows = np.arange(target.size)
    tr = ~bad & (rows < cut)
    ho = ~bad & (rows >= cut) & seen
    if tr.sum() < 20:
        return (math.nan, np.full(cut, math.nan)) if residual else math.nan
    cells = int(np.prod(sets))
    cnt = np.bincount(key[tr], minlength=cells)
    sm = np.bincount(key[tr], target[tr], minlength=cells)
    mean = float(target[tr].mean())
    fit = np.where(cnt > 0, sm / np.maximum(cnt, 1), mean)
    t = target[ho]
    # too few rows to score, or one value held out (its mean's rounding is no spread)
    r2 = math.nan
    if t.size >= 10 and np.ptp(t) > 0:
        r2 = 1.0 - float(np.sum((t - fit[key[ho]]) ** 2)) / float(np.sum((t - t.mean()) ** 2))
    if not residual:
        return r2
    left = np.where(tr, target - fit[np.where(bad, 0, key)], math.nan)[:cut]
    return r2, left
