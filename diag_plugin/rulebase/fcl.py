"""Export a rule base to other fuzzy tools: IEC 61131-7 FCL and the fuzzylite language.

Both exports describe exactly the model that :meth:`RuleBase.to_model` builds, so
another tool computes the same output as :meth:`WangMendelRegressor.predict`:

* Each input keeps its uniform partition (trapezoids with shoulders at both ends,
  or triangles), written as membership functions in engineering units.
* Each rule is one line ``IF x1 IS A1 AND … AND xd IS Ad THEN y IS c``, the rule
  form of Kościelny et al., eq. 1 (and eq. 4 for the rules the modified
  Wang–Mendel method generates). Its premise degree is the product of the input
  memberships (``AND : PROD``, product t-norm).
* Each conclusion is a singleton (the rule's ``then`` value) of its own: with one
  singleton per rule the accumulation operator cannot matter, and the centre of
  gravity of singletons (``COGS``, IEC 61131-7) is the weighted average
  ``Σ w_r·c_r / Σ w_r`` that the model computes.
* Locked-deleted rules (``then = nan``) are left out: that cell has no rule.
* Inputs outside their span: the model clips them to the span. The end sets are
  shoulders that keep full membership beyond the span, which gives the same
  output without clipping (at the span's ends only the end set fires).
* Where no rule fires the model has no value (NaN, *unsupported*); no ``DEFAULT``
  is written, so fuzzylite also gives ``nan`` there.

Dialect notes, checked against the peers in ``tests/test_fcl_peer.py``:

* FCL (:func:`to_fcl`) is read by the fuzzylite 6 command-line tool (Debian
  package ``fuzzylite``). Membership functions use the standard point form
  ``(x, μ) (x, μ) …`` (fuzzylite reads it as a piecewise-linear ``Discrete``
  term that keeps the end values beyond the first and last point: shoulders);
  the ``TRAPE``/``TRIAN`` shorthand is not understood by fuzzylite. Rule
  keywords are written in lower case (``if … is … and … then``): IEC 61131-3,
  which FCL builds on, makes keywords case-insensitive, and fuzzylite parses rules
  only in lower case (upper-case rules are silently dropped). Comments are ``//``
  (IEC 61131-3 edition 3; fuzzylite does not read ``(* … *)``).
* FLL (:func:`to_fll`) is for pyfuzzylite, which imports no FCL: Takagi–Sugeno
  ``Constant`` conclusions, ``WeightedAverage`` defuzzifier, ``AlgebraicProduct``
  conjunction, ``Trapezoid``/``Triangle`` terms with infinite shoulders, and
  ``lock-range: true`` on the inputs (clipped to the span, as in the model).
"""

from __future__ import annotations

import math
import re

from diag_plugin.fuzzy.partition import UniformPartition
from diag_plugin.fuzzy.wm_codec import Rule
from diag_plugin.rulebase.document import RuleBase, Variable

#: names a variable or term may not take: FCL block keywords, fuzzylite rule keywords/hedges
RESERVED = frozenset(
    """
    function_block end_function_block var_input var_output var end_var fuzzify
    end_fuzzify defuzzify end_defuzzify ruleblock end_ruleblock term range method
    default accu act and or not if is then with rule real lock enabled nc
    any very somewhat seldom extremely
    """.split()
)

_IDENT = re.compile(r"^[A-Za-z](_?[A-Za-z0-9])*$")


def identifier(text: str, taken: set[str] | None = None) -> str:
    """A valid FCL/FLL identifier for ``text``: ``CV[k-1]`` → ``CV_k_1``,
    ``dir(CV)[k-1]`` → ``dir_CV_k_1``.

    Runs of other characters become one underscore, leading and trailing ones are
    dropped (IEC 61131-3 identifiers: a letter or ``_`` first, no double or
    trailing underscores); a leading digit or a keyword gets a ``v_`` prefix.
    With ``taken`` the name is made unique (``_2``, ``_3``, …) and added to it.
    """
    name = re.sub(r"[^A-Za-z0-9]+", "_", text).strip("_") or "v"
    if name[0].isdigit() or name.lower() in RESERVED:
        name = "v_" + name
    if taken is not None:
        base, k = name, 2
        while name.lower() in taken:
            name, k = f"{base}_{k}", k + 1
        taken.add(name.lower())
    return name


def _num(v: float) -> str:
    """A number as an IEC real literal, 12 significant digits (``7.5``, ``1.0e-05``).

    12 digits keep the breakpoints readable (``7.5``, not ``7.499999999999999``)
    and far finer than any tolerance (1e-12 of the value).
    """
    v = float(v)
    if v == 0.0:
        return "0.0"
    mant, e, exp = f"{v:.12g}".partition("e")
    if "." not in mant:
        mant += ".0"
    return mant + (e + exp if e else "")


def _partition(rb: RuleBase, v: Variable) -> UniformPartition:
    # the same partition WangMendelRegressor builds from the file (default plateau)
    return UniformPartition(v.span[0], v.span[1], v.sets, rb.shape)


def _points(p: UniformPartition, i: int) -> list[tuple[float, float]]:
    """Membership function of set ``i`` in IEC point form ``(x, μ)``, ascending ``x``.

    The first and last set start/end at the span's ends with μ = 1; beyond the
    first/last point the membership stays at that point's value (shoulders).
    """
    a, b, c, d = p.breakpoints(i)
    if i == 0:
        pts = [(p.lo, 1.0), (c, 1.0), (d, 0.0)]
    elif i == p.n - 1:
        pts = [(a, 0.0), (b, 1.0), (p.hi, 1.0)]
    else:
        pts = [(a, 0.0), (b, 1.0), (c, 1.0), (d, 0.0)]
    out: list[tuple[float, float]] = []
    for x, mu in pts:
        x = float(_num(x))  # as written, so that equal points are dropped once written
        if out and x <= out[-1][0]:
            continue  # triangles: core of one point; shoulder core at the span's end
        out.append((x, mu))
    return out


def _fll_term(p: UniformPartition, i: int) -> str:
    a, b, c, d = p.breakpoints(i)
    if i == 0:
        a = b = -math.inf
    if i == p.n - 1:
        c = d = math.inf
    if b == c and math.isfinite(b):
        return f"Triangle {_fll_num(a)} {_fll_num(b)} {_fll_num(d)}"
    return "Trapezoid " + " ".join(_fll_num(x) for x in (a, b, c, d))


def _fll_num(v: float) -> str:
    return ("-inf" if v < 0 else "inf") if math.isinf(v) else _num(v)


def _live(rb: RuleBase) -> list[Rule]:
    """Rules that exist in the model: all but the locked-deleted ones (``then = nan``)."""
    return [r for r in rb.rules if not math.isnan(r.then)]


def _names(rb: RuleBase) -> tuple[list[str], str]:
    taken: set[str] = set()
    inputs = [identifier(v.spec, taken) for v in rb.inputs]
    return inputs, identifier(rb.output.spec, taken)


def _term_names(v: Variable) -> list[str]:
    """Set names as in the rule-base file (``U17``) when they are identifiers."""
    labels = [v.set_label(i) for i in range(v.sets)]
    if all(_IDENT.match(t) for t in labels):
        return labels
    prefix = identifier(v.label) if v.label else "S"
    return [f"{prefix}_{i:0{v.width}d}" for i in range(v.sets)]


def _describe(v: Variable, sets: bool = True) -> str:
    what = [f"sets {v.set_label(0)}..{v.set_label(v.sets - 1)}"] if sets else []
    what += [v.unit] if v.unit else []
    return _oneline(f"{v.spec} ({', '.join(what)})" if what else v.spec)


def _oneline(text: str) -> str:
    """Text for a one-line comment or description, whatever the file holds."""
    return " ".join(text.split())


def _premise(names: list[str], terms: list[list[str]], r: Rule) -> str:
    """``x1 is A1 and … and xd is Ad`` (premise of Kościelny et al., eq. 1)."""
    sets = (t[i] for t, i in zip(terms, r.premise, strict=True))
    return " and ".join(f"{n} is {t}" for n, t in zip(names, sets, strict=True))


def _rule_note(r: Rule) -> str:
    sd = "nan" if math.isnan(r.sd) else f"{r.sd:.6g}"
    return f"n = {r.n}, sd = {sd}" + (", locked" if r.lock else "")


def _check(rb: RuleBase) -> None:
    if not rb.inputs or rb.output is None:
        raise ValueError(f"{rb.path}: a rule base needs an output and at least one input")


def to_fcl(rb: RuleBase) -> str:
    """The rule base as IEC 61131-7 Fuzzy Control Language text.

    ``FUNCTION_BLOCK`` with ``VAR_INPUT``/``VAR_OUTPUT`` (names from the specs,
    see :func:`identifier`, the spec in a comment), one ``FUZZIFY`` block per input
    (``RANGE`` and each set in point form), one ``DEFUZZIFY`` block with a
    singleton term per rule and ``METHOD : COGS`` (weighted average of singletons),
    and one ``RULEBLOCK`` with ``AND : PROD`` and a rule per line in the form of
    Kościelny et al., eq. 1/4: ``RULE 1 : if CV_k_1 is U17 and P1_k is P1_04 then
    F_k is R1;``. See the module docstring for the dialect and the peer checks.
    """
    _check(rb)
    in_names, out_name = _names(rb)
    rules = _live(rb)
    dropped = len(rb.rules) - len(rules)
    lines = [
        f"// Fuzzy model {_oneline(rb.name)!r} exported by diag-plugin as IEC 61131-7 FCL.",
        f"// method {rb.method}, {rb.shape} sets; {len(rules)} rules"
        + (f" ({dropped} locked-deleted left out)" if dropped else "")
        + ". Conclusions are singletons; COGS gives their weighted average.",
        "// Where no rule fires the model has no value (no DEFAULT).",
        f"FUNCTION_BLOCK {identifier(rb.name)}",
        "",
        "VAR_INPUT",
    ]
    for name, v in zip(in_names, rb.inputs, strict=True):
        lines.append(f"    {name} : REAL; // {_describe(v)}")
    lines += ["END_VAR", "", "VAR_OUTPUT"]
    lines.append(f"    {out_name} : REAL; // {_describe(rb.output, sets=False)}")
    lines += ["END_VAR", ""]
    for name, v in zip(in_names, rb.inputs, strict=True):
        p = _partition(rb, v)
        lines.append(f"FUZZIFY {name}")
        lines.append(f"    RANGE := ({_num(v.span[0])} .. {_num(v.span[1])});")
        for i, term in enumerate(_term_names(v)):
            pts = " ".join(f"({_num(x)}, {_num(mu)})" for x, mu in _points(p, i))
            lines.append(f"    TERM {term} := {pts};")
        lines += ["END_FUZZIFY", ""]
    lines.append(f"DEFUZZIFY {out_name}")
    lines.append(f"    RANGE := ({_num(rb.output.span[0])} .. {_num(rb.output.span[1])});")
    for k, r in enumerate(rules, 1):
        lines.append(f"    TERM R{k} := {_num(r.then)}; // {_rule_note(r)}")
    lines += ["    METHOD : COGS;", "END_DEFUZZIFY", "", "RULEBLOCK rules", "    AND : PROD;"]
    terms = [_term_names(v) for v in rb.inputs]
    for k, r in enumerate(rules, 1):
        lines.append(f"    RULE {k} : if {_premise(in_names, terms, r)} then {out_name} is R{k};")
    lines += ["END_RULEBLOCK", "", "END_FUNCTION_BLOCK", ""]
    return "\n".join(lines)


def to_fll(rb: RuleBase) -> str:
    """The rule base in the fuzzylite language (FLL), for pyfuzzylite.

    A Takagi–Sugeno engine with one ``Constant`` conclusion per rule, the
    ``WeightedAverage`` defuzzifier and ``AlgebraicProduct`` conjunction: the
    weighted average of the fired rules' conclusions with product premise degrees,
    rules in the form of Kościelny et al., eq. 1/4. Input terms are ``Trapezoid``
    (``Triangle``) with ±inf shoulders; ``lock-range: true`` clips inputs to the
    span like the model. Same semantics as :func:`to_fcl` (IEC 61131-7 ``COGS``).
    """
    _check(rb)
    in_names, out_name = _names(rb)
    rules = _live(rb)
    lines = [
        f"# Fuzzy model {_oneline(rb.name)!r} exported by diag-plugin as fuzzylite FLL.",
        f"# method {rb.method}, {rb.shape} sets; {len(rules)} rules.",
        f"Engine: {identifier(rb.name)}",
    ]
    if rb.description:
        lines.append(f"  description: {_oneline(rb.description)}")
    for name, v in zip(in_names, rb.inputs, strict=True):
        p = _partition(rb, v)
        lines += [
            f"InputVariable: {name}",
            f"  description: {_describe(v)}",
            "  enabled: true",
            f"  range: {_num(v.span[0])} {_num(v.span[1])}",
            "  lock-range: true",
        ]
        for i, term in enumerate(_term_names(v)):
            lines.append(f"  term: {term} {_fll_term(p, i)}")
    lines += [
        f"OutputVariable: {out_name}",
        f"  description: {_describe(rb.output, sets=False)}",
        "  enabled: true",
        f"  range: {_num(rb.output.span[0])} {_num(rb.output.span[1])}",
        "  lock-range: false",
        "  aggregation: none",
        "  defuzzifier: WeightedAverage TakagiSugeno",
        "  default: nan",
        "  lock-previous: false",
    ]
    for k, r in enumerate(rules, 1):
        lines.append(f"  term: R{k} Constant {_num(r.then)}  # {_rule_note(r)}")
    lines += [
        "RuleBlock: rules",
        "  enabled: true",
        "  conjunction: AlgebraicProduct",
        "  disjunction: none",
        "  implication: none",
        "  activation: General",
    ]
    terms = [_term_names(v) for v in rb.inputs]
    for k, r in enumerate(rules, 1):
        lines.append(f"  rule: if {_premise(in_names, terms, r)} then {out_name} is R{k}")
    return "\n".join(lines) + "\n"
