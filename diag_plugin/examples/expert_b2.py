"""The expert's edit of Model B: rule base B.1 → B.2 (Kościelny et al., Sect. 4.4, Fig. 6).

"Version B.1 is the rule base obtained ... after the training process via the modified
algorithm was completed. Then, on the basis of an expert's evaluation, the model was modified
into Model B.2 that was the final product of the identification process." The paper shows
B.1 and B.2 only as a graphic (Fig. 6) and says neither what its expert changed nor why: **the
edit below is the project's own**, what an expert could do to our B.1. The shipped B.1
(``rulebases/valve_b.toml``, ``F_k = f(U_{k-1})``) shows what such an evaluation finds: no
rules below CV10 (the plant never ran under ≈ 32 % CV while the data were logged) and a top
rule below its neighbour (CV30 = 28.8 t/h < CV29 = 31.2 t/h: at a saturated controller the
pressure drop, not the valve, limits the flow — Model B cannot see it). The expert's B.2:

1. **The low rules from the valve's physics.** The valve is equal-percentage with tight
   shut-off, ``F(x) = A (R^(x−1) − (1 − x)/R)`` at a given pressure drop (x the opening,
   0–1; the form :func:`diag_plugin.simulate.physics.kv_relative` uses). ``A`` and the
   rangeability ``R`` are fitted to B.1's own rules where the characteristic is steep and
   well supported (:data:`FIT_SETS`, CV14–CV27: least squares on ln F, weighted by each
   rule's samples) — not taken from the simulator — and the law fills every empty set below
   the lowest rule, kept under it (monotone).
2. **A monotone curve.** The flow does not fall as the valve opens. Where B.1's rules fall
   (its top), the rules that break the order are replaced by the monotone rules nearest B.1
   in the training error (weighted by each rule's samples: isotonic regression, adjacent
   violators pooled) — on the shipped B.1 CV28–CV30 (30.70, 31.17, 28.78 t/h) become 30.63.
   Raising the low rule to its neighbour instead (the smaller edit in values) cost more on
   held-out data (docs/tutorial/first-model.md, step 6).
3. Every edited rule is **locked**, so ``diag train`` keeps it (its n/sd are refreshed).

On the shipped B.1 the fit gives R = 50.2 (the DN50 valve's data sheet: 50) and fills CV00–
CV09 with 0–2.40 t/h; on a week of the simulated plant at low load (flow set-points from
0.5 t/h, seed 43) the measured flow averages 0.51–1.96 t/h over CV 5–32 %
(docs/tutorial/first-model.md, step 6, and docs/explanation/fig8.md give the held-out errors).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from diag_plugin.fuzzy.wm_codec import Rule
from diag_plugin.rulebase.document import RuleBase

__all__ = [
    "FIT_SETS",
    "equal_percentage",
    "expert_edit",
    "fit_equal_percentage",
    "isotonic",
    "make_b2",
]

#: B.1's rules the law is fitted to: the steep, well-supported middle of the characteristic
#: (below CV14 the rules sit at the flow controller's lowest set-point, 4 t/h, whatever the
#: opening; above CV27 the controller saturates)
FIT_SETS = range(14, 28)
#: rangeabilities searched (equal-percentage valves are sold with R of 20-100)
R_GRID = np.linspace(5.0, 200.0, 1951)


def equal_percentage(x: np.ndarray, a: float, r: float) -> np.ndarray:
    """Flow of an equal-percentage valve with tight shut-off at relative opening ``x`` (0–1):
    ``a (r^(x−1) − (1 − x)/r)``; 0 when closed, ``a`` when fully open."""
    x = np.asarray(x, dtype=float)
    return a * (r ** (x - 1.0) - (1.0 - x) / r)


def fit_equal_percentage(x: np.ndarray, f: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    """``(a, r)`` of :func:`equal_percentage` by weighted least squares on ``ln f``: ``ln a``
    in closed form for each ``r`` of :data:`R_GRID`, the ``r`` of the smallest error kept."""
    x, f, w = (np.asarray(v, dtype=float) for v in (x, f, w))
    if np.any(f <= 0) or np.any(x <= 0):
        raise ValueError("the fit needs positive flows at openings above 0")
    best = (math.inf, math.nan, math.nan)
    for r in R_GRID:
        g = np.log(equal_percentage(x, 1.0, r))
        ln_a = float(np.sum(w * (np.log(f) - g)) / w.sum())
        err = float(np.sum(w * (np.log(f) - ln_a - g) ** 2))
        if err < best[0]:
            best = (err, math.exp(ln_a), float(r))
    return best[1], best[2]


def isotonic(values: list[float], weights: list[float]) -> np.ndarray:
    """The non-decreasing sequence nearest ``values`` in weighted least squares (isotonic
    regression by pooling adjacent violators): a run that falls is replaced by its weighted
    mean, repeatedly, so only the rules that break the order change."""
    blocks: list[list[float]] = []  # [mean, weight, length]
    for v, w in zip(values, weights, strict=True):
        blocks.append([float(v), float(w), 1])
        while len(blocks) > 1 and blocks[-2][0] > blocks[-1][0]:
            (m1, w1, n1), (m2, w2, n2) = blocks[-2], blocks.pop()
            blocks[-1] = [(m1 * w1 + m2 * w2) / (w1 + w2), w1 + w2, n1 + n2]
    return np.concatenate([np.full(n, m) for m, _, n in blocks])


def expert_edit(rb: RuleBase, fit_sets: range = FIT_SETS) -> dict[str, float]:
    """Edit a one-input Wang–Mendel rule base of the flow from the valve opening (Model B)
    in place into B.2 (module docstring): fill the empty sets below the lowest rule by the
    fitted equal-percentage law, pool the rules that fall with their neighbours (:func:`isotonic`),
    lock what was edited. Returns the fit, ``{"a", "r"}``."""
    if len(rb.inputs) != 1 or rb.method not in ("wm-avg", "wm"):
        raise ValueError(f"{rb.path}: B.2 edits a one-input Wang–Mendel model (Model B)")
    var = rb.inputs[0]
    lo, hi = var.span
    centre = {k: lo + (hi - lo) * k / (var.sets - 1) for k in range(var.sets)}
    rules = {r.premise[0]: r for r in rb.rules if not math.isnan(r.then)}
    fit = [k for k in fit_sets if k in rules]
    if len(fit) < 3:
        raise ValueError(f"{rb.path}: fewer than 3 rules among sets {fit_sets} to fit the law")
    rel = {k: (centre[k] - lo) / (hi - lo) for k in centre}
    a, r = fit_equal_percentage(
        [rel[k] for k in fit], [rules[k].then for k in fit], [max(rules[k].n, 1) for k in fit]
    )
    lowest = min(rules)
    for k in range(lowest):  # 1. the empty sets below the lowest rule
        value = min(float(equal_percentage(rel[k], a, r)), rules[lowest].then)
        rules[k] = Rule((k,), round(value, 3), 0, 0.0, True)
    if lowest > 0:
        rules[0].comments = [
            f"# B.2: {var.set_label(0)}-{var.set_label(lowest - 1)} filled by the valve's "
            f"equal-percentage law F = {a:.2f} ({r:.1f}^(x-1) - (1-x)/{r:.1f}),",
            f"# x = {var.label} opening 0-1, fitted to {var.set_label(fit[0])}-"
            f"{var.set_label(fit[-1])} (expert edit, locked)",
        ]
    ks = sorted(rules)  # 2. monotone: the nearest monotone rules, weighted by their samples
    mono = isotonic([rules[k].then for k in ks], [max(rules[k].n, 1) for k in ks])
    for k, v in zip(ks, mono, strict=True):
        v = round(float(v), 3)
        if v != rules[k].then and rules[k].n > 0:
            rules[k].comments = [
                *rules[k].comments,
                f"# B.2: was {rules[k].then:g}, pooled with its neighbours (monotone; expert "
                "edit, locked)",
            ]
            rules[k].then, rules[k].lock = v, True
    locked = [r for r in rb.rules if math.isnan(r.then)]  # locked-deleted cells stay
    rb.set_rules(sorted([*rules.values(), *locked], key=lambda q: q.premise))
    return {"a": a, "r": r}


def make_b2(b1: str | Path, out: str | Path) -> Path:
    """Write B.2 (:func:`expert_edit`) of the B.1 file ``b1`` to ``out``, named after it."""
    rb = RuleBase.load(b1)
    fit = expert_edit(rb)
    out = Path(out)
    rb.doc["model"]["name"] = out.stem
    rb.doc["model"]["description"] = (
        f"Model B.2: {rb.name} edited as an expert might (our edit: Kościelny et al. show B.2 "
        "in Fig. 6 but print no edit): empty low sets filled by an equal-percentage law "
        f"fitted to its rules (R = {fit['r']:.1f}), "
        "falling top pooled to keep it monotone, edits locked"
    )
    rb.edited()
    return rb.save(out)
