"""The Wang–Mendel part of a model file: its rules, how they are read, written and locked.

The file's shell (``[model]``, ``[output]``, ``[[inputs]]``, ``[training]``) is
the same for every method (:mod:`diag_plugin.rulebase.document`); this codec gives the
``[rules]`` list its meaning for ``wm-avg`` and ``wm`` (Kościelny et al.,
eqs. 2–5)::

    { if = ["U17", "P04"], then = 63.2, n = 5231, sd = 0.8, lock = false }

``if`` names the premise set of each input (label + set index), ``then`` is the
conclusion in the output's engineering units, ``n``/``sd`` its training
support, ``lock`` keeps ``then`` through retraining. ``then = nan`` with
``lock = true`` is a *locked-deleted* rule: that cell never gets a rule.

The coarser levels behind the fine grid (:mod:`diag_plugin.fuzzy.wang_mendel`) are
*derived* from these rules, not stored: a coarse rule is the ``n``-weighted
mean of the fine rules in its cell (eq. 5 on a bigger cell), so an expert's
edit of a fine rule (a value, a lock) carries into every level at once, there
is one truth to diff and review, and files written before the levels existed
predict with them unchanged. ``diag rules show NAME --level L`` prints a level.
A locked-deleted cell's samples count at no level. The optional ``levels``
key of ``[rules]`` limits the levels (``levels = 0``: the fine grid alone, the
paper's model).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from diag_plugin.fuzzy.wang_mendel import CONCLUSIONS, WangMendelRegressor
from diag_plugin.models.codec import RuleCodec
from diag_plugin.models.spec import ModelSpec

if TYPE_CHECKING:
    from diag_plugin.rulebase.document import RuleBase

RULE_KEYS = {"if", "then", "n", "sd", "lock"}
#: the options a Wang–Mendel file may set in ``[rules]``
OPTIONS = ("levels", "conclusion")


@dataclass
class Rule:
    premise: tuple[int, ...]
    then: float
    n: int = 0
    sd: float = 0.0
    lock: bool = False
    line: int = 0
    comments: list[str] = field(default_factory=list)
    trailing: str = ""


class WangMendelCodec(RuleCodec):
    """Estimator factory and rule I/O of the Wang–Mendel methods (``wm-avg``, ``wm``)."""

    method = "wm-avg"
    estimator = WangMendelRegressor
    #: the fine grid's rules are IEC 61131-7 FCL rules (``diag rules export-fcl``)
    fcl = True

    def default_options(self) -> dict:
        """The options a new file gets in ``[rules]``: none (every level behind the fine grid,
        mean conclusions; ``levels = 0`` is the paper's fine grid alone)."""
        return {}

    # ------------------------------------------------------------ estimators
    def new_estimator(self, spec: ModelSpec) -> WangMendelRegressor:
        """An untrained model with the spec's partitions, method and levels."""
        levels = spec.options.get("levels")
        conclusion = spec.options.get("conclusion", "mean")
        return WangMendelRegressor(
            input_spans=[v.span for v in spec.inputs],
            output_span=spec.output.span,
            n_sets=[v.sets for v in spec.inputs],
            output_sets=spec.output.sets,
            shape=spec.shape,
            method=spec.method,
            levels=levels if _is_levels(levels) else None,
            conclusion=conclusion if conclusion in CONCLUSIONS else "mean",
        )

    def to_model(self, rb: RuleBase) -> WangMendelRegressor:
        """The model the file describes; expert edits are used as written."""
        m = self.new_estimator(rb.spec).init(len(rb.inputs))
        return _with_rules(m, {r.premise: r for r in rb.rules if not math.isnan(r.then)})

    def predictor(self, rb: RuleBase, model: WangMendelRegressor) -> WangMendelRegressor:
        """A copy of a trained model with the experts' locked rules applied.

        The trained model itself keeps its exact statistics (for ``merge``); the
        file applies the locks again when it takes the training.
        """
        locked = [r for r in rb.rules if r.lock]
        if not locked:
            return model
        out = WangMendelRegressor.from_state(model.to_state())
        idx = out.cell_indices()
        rules = {
            tuple(int(v) for v in idx[j]): Rule((), float(c), int(n), float(sd))
            for j, (c, n, sd) in enumerate(zip(out.conclusions_, out.count_, out.sd_, strict=True))
        }
        for r in locked:
            if math.isnan(r.then):
                rules.pop(r.premise, None)
            else:
                rules[r.premise] = r
        return _with_rules(out, rules)

    def apply_training(self, rb: RuleBase, model: WangMendelRegressor) -> list[Rule]:
        """The file's rules after training, keeping the experts' locks.

        A locked rule keeps its conclusion (its support is updated); a
        locked-deleted cell stays empty; a rule without new data is kept as it
        was; every other cell gets the trained average (eq. 5), clipped to the
        output's nominal span.
        """
        old = {r.premise: r for r in rb.rules}
        idx = model.cell_indices()
        # averages of noisy measurements may sit a hair outside the nominal span
        conc = np.clip(model.conclusions_, *rb.output.span)
        sd, cnt = model.sd_, model.count_
        new: dict[tuple[int, ...], Rule] = {}
        for j in range(idx.shape[0]):
            p = tuple(int(v) for v in idx[j])
            prev = old.get(p)
            r = Rule(p, float(conc[j]), int(cnt[j]), float(sd[j]))
            if prev is not None:
                r.comments, r.trailing = prev.comments, prev.trailing
                if prev.lock:
                    r.then, r.lock = prev.then, True
            new[p] = r
        for p, prev in old.items():
            new.setdefault(p, prev)
        return [new[p] for p in sorted(new)]

    def size(self, model: WangMendelRegressor) -> int:
        """Rules of a trained model."""
        return model.n_rules_

    # ------------------------------------------------------------- file I/O
    def read_rules(
        self, rb: RuleBase, items: list, positions: Sequence[tuple[int, list[str], str]]
    ) -> list[Rule]:
        """Rules from the file's ``[rules] list``; each problem goes to ``rb.error(line, …)``."""
        for key, value in rb.options.items():
            line = rb.line_of("rules", key)
            if key not in OPTIONS:
                rb.error(line, f"unknown {rb.method} option {key!r} (known: {', '.join(OPTIONS)})")
            elif key == "levels" and not _is_levels(value):
                rb.error(
                    line,
                    f"levels must be a non-negative integer (coarser levels behind the fine "
                    f"grid; 0 = the fine grid alone), got {value!r}",
                )
            elif key == "conclusion" and value not in CONCLUSIONS:
                rb.error(
                    line,
                    f"conclusion must be {' or '.join(map(repr, CONCLUSIONS))} (what a cell "
                    f"averages: the outputs, or their sets' centres as eq. 5 prints), "
                    f"got {value!r}",
                )
        lo, hi = rb.output.span
        rules: list[Rule] = []
        seen: dict[tuple[int, ...], int] = {}
        for e in self.entries(rb, items, positions, "rule", RULE_KEYS, "if = [...], then = ..."):
            item, line, where = e.item, e.line, e.where
            prem = item.get("if")
            premise: list[int] = []
            if not isinstance(prem, list) or not all(isinstance(p, str) for p in prem):
                rb.error(line, f"{where}: 'if' must be a list of set labels")
            elif len(prem) != len(rb.inputs):
                rb.error(line, f"{where}: 'if' has {len(prem)} labels for {len(rb.inputs)} inputs")
            else:
                for var, lab in zip(rb.inputs, prem, strict=True):
                    idx = var.parse_label(str(lab))
                    if idx is None:
                        rb.error(
                            line,
                            f"{where}: unknown set label {str(lab)!r} for input "
                            f"{var.spec} (expected {var.set_label(0)}…"
                            f"{var.set_label(var.sets - 1)})",
                        )
                    premise.append(-1 if idx is None else idx)
            then = item.get("then")
            lock = item.get("lock", False)
            if not isinstance(lock, bool):
                rb.error(line, f"{where}: lock must be true or false, got {lock!r}")
                lock = False
            typed = not isinstance(then, bool) and isinstance(then, int | float)
            if not typed:  # one message: the nan rule below is about a written nan
                rb.error(
                    line,
                    f"{where}: then must be a number in the output's unit "
                    f"({rb.output.spec} {rb.output.span[0]:g}…{rb.output.span[1]:g}), "
                    + ("but it is missing" if then is None else f"got {then!r}"),
                )
                then = math.nan
            then = float(then)
            if typed and math.isnan(then) and not lock:
                rb.error(
                    line,
                    f"{where}: then = nan is only allowed on a locked rule "
                    "(locked-deleted cell); delete the line to drop the rule",
                )
            elif not math.isnan(then) and not (lo <= then <= hi):
                rb.error(
                    line,
                    f"{where}: then = {then:g} is outside the output span "
                    f"[{lo:g}, {hi:g}] {rb.output.unit}".rstrip(),
                )
            n = item.get("n", 0)
            if isinstance(n, bool) or not isinstance(n, int) or n < 0:
                rb.error(line, f"{where}: n must be a non-negative integer, got {n!r}")
                n = 0
            sd = item.get("sd", 0.0)
            if isinstance(sd, bool) or not isinstance(sd, int | float) or not sd >= 0:
                if not (isinstance(sd, float) and math.isnan(sd)):
                    rb.error(line, f"{where}: sd must be a non-negative number, got {sd!r}")
                sd = 0.0
            if len(rb.problems) > e.problems:
                continue
            key = tuple(premise)
            if key in seen:
                rb.error(
                    line, f"{where}: duplicate premise {list(prem)} (first at line {seen[key]})"
                )
                continue
            seen[key] = line
            rules.append(
                Rule(key, then, int(n), float(sd), bool(lock), line, e.comments, e.trailing)
            )
        return rules

    def format_rules(self, rb: RuleBase) -> str:
        """The ``list = [...]`` text, one rule per line in premise order, comments kept."""
        dec_y = _decimals(rb.output.span)

        def text(r: Rule) -> str:
            labels = ", ".join(
                f'"{v.set_label(i)}"' for v, i in zip(rb.inputs, r.premise, strict=True)
            )
            then = "nan" if math.isnan(r.then) else f"{r.then:.{dec_y}f}"
            sd = "nan" if math.isnan(r.sd) else f"{r.sd:.{dec_y}f}"
            lock = "true" if r.lock else "false"
            return f"{{ if = [{labels}], then = {then}, n = {r.n}, sd = {sd}, lock = {lock} }},"

        return self.format_list(rb.rules, text)


def _with_rules(m: WangMendelRegressor, rules: Mapping[tuple[int, ...], Rule]):
    d = m.n_features_in_
    ps = sorted(rules)
    idx = np.array(ps, np.int64).reshape(-1, d)
    return m.set_rules(
        m.cell_keys(idx),
        [rules[p].then for p in ps],
        counts=[rules[p].n for p in ps],
        sds=[rules[p].sd for p in ps],
    )


def _is_levels(v: object) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


def _decimals(span: tuple[float, float]) -> int:
    """Decimals that resolve 1e-4 of the span."""
    width = span[1] - span[0]
    return max(0, 4 - math.floor(math.log10(width))) if width > 0 else 4
