"""The example rule bases shipped in ``rulebases/`` and how they are made.

* ``valve_a``: Model A of Kościelny et al., eq. 8: ``F_k = f(U_{k-1}, P_k)`` with the
  upstream pressure P1, trained on 60 days of the simulated valve assembly.
* ``valve_b``: Model B, eq. 9: ``F_k = f(U_{k-1})``, the same data (B.1).
* ``valve_b2``: B.2, the expert's edit of ``valve_b`` (:mod:`diag_plugin.examples.expert_b2`).
* ``valve_r1``…``valve_r4`` and ``valve_unit``: the example unit, trained on 180 days of the
  same run, thresholds cross-fitted over them (:func:`build_valve_unit`).
* ``damadics_f``: the real Lublin actuator 3 hour (1 s): ``F = f(X[k])``.

31 uniform trapezoidal sets per variable (Sect. 4.4). Regenerate with
``python -m diag_plugin.examples.build rulebases``; the result is reproducible to the byte.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from diag_plugin.rulebase.document import RuleBase
from diag_plugin.training.chunked import train

SIM_DAYS = 60
SIM_SEED = 1
#: the unit's models: half a year of the same run (the paper's "half a year of 10 s data"; a
#: run of N days is the first N days of a longer one, so valve_a/b see its first 60 days).
#: 60 days left the low-pressure-drop regimes (pump head lost, valve wide open) nearly
#: unseen, and the tour's own 30 days (seed 0) spend 5 % of their time there
UNIT_DAYS = 180
#: the unit's false-alarm budget: alarms per hour of operation, all four tests together
#: (about one in six weeks); thresholds from the training window, cross-fitted
UNIT_FAR = 0.001

#: the unit's tests: r1 = F − F̂(CV), r2 = P0 − P̂0(CV), r3 = X − X̂(P0), r4 = F − F̂(X)
#: (Kościelny et al., Sect. 5, with rules (10)–(14)); r1 and r4 also take P1, P2
#: (docs/explanation/table4.md says why)
UNIT_TESTS = {
    "r1": ("F[k]", ["CV[k]", "P1[k]", "P2[k]"], "r1: F = f(CV, P1, P2)"),
    "r2": ("P0[k]", ["CV[k]"], "r2: P0 = f(CV)"),
    "r3": ("X[k]", ["P0[k]"], "r3: X = f(P0)"),
    "r4": ("F[k]", ["X[k]", "P1[k]", "P2[k]"], "r4: F = f(X, P1, P2)"),
}


#: Kościelny et al. Table 4 as printed (blank entries are 0, as rules (10)–(14) say): the
#: open chain U → P0 → X → F of an actuator without a positioner loop
def _matrix(title: str, rows: str, notes: str) -> str:
    """A matrix file of the valve's four tests and five faults: ``rows`` a line per test,
    ``test: e e e e e`` in the order f_EP f_P0 f_S f_X f_V."""
    lines = [f"# Servomotor–valve unit{title}", "[matrix]", 'name = "valve_unit"']
    lines += ['tests = ["r1", "r2", "r3", "r4"]', 'faults = ["f_EP", "f_P0", "f_S", "f_X", "f_V"]']
    lines += ["rows = [", "  #                   f_EP f_P0 f_S  f_X  f_V"]
    for row in rows.strip().splitlines():
        test, entries = row.split(":")
        cells = ", ".join(f'"{e}"' for e in entries.split())
        lines.append(f'  {{ test = "{test}", row = [{cells}] }},')
    legend = "f_EP E/P transducer, f_P0 P0 pressure sensor, f_S servomotor, f_X X transducer"
    lines += ["]", f"# {legend}, f_V valve{notes}"]
    return "\n".join(lines) + "\n"


TABLE4_MATRIX = _matrix(
    ", Kościelny et al. Table 4 (blank entries are 0, as rules (10)–(14) say)",
    """
r1: 1 0 1 0 1
r2: 1 1 0 0 0
r3: 0 1 1 1 0
r4: 0 0 0 1 1
""",
    "",
)

#: the example unit's matrix: Table 4 for the simulated actuator, whose positioner closes its
#: loop on the measured X (docs/explanation/table4.md). The loop restores X after a servomotor fault
#: by changing P0, so f_S shows P0's column (0, 1, 1, 0) and the two are one group; after an
#: X-transducer fault it moves the true travel, so all four residuals react.
UNIT_MATRIX = _matrix(
    " with a positioner: Kościelny et al. Table 4 for a loop closed on X",
    """
r1: 1 0 0 1 1
r2: 1 1 1 1 0
r3: 0 1 1 1 0
r4: 0 0 0 1 1
""",
    ";\n# f_P0 and f_S cannot be told apart by these four tests "
    "(a Pch = f(P0) test would split them)",
)


def _fit(rb: RuleBase, frame: pd.DataFrame, source: str) -> RuleBase:
    a, b = frame.index[0], frame.index[-1] + pd.Timedelta(rb.period)
    res = train(rb, lambda x, y: frame[(frame.index >= x) & (frame.index < y)], a, b)
    rb.apply_training(
        res.model,
        {
            "source": source,
            "from": a.isoformat(),
            "to": b.isoformat(),
            "samples": res.samples,
            "validation_rmse_pct": round(res.validation["rmse_pct"], 3),
        },
    )
    rb.save()
    return RuleBase.load(rb.path)


def build_examples(folder: str | Path, *, damadics: Path | None = None) -> list[Path]:
    from diag_plugin.examples.damadics import TAGS as DTAGS
    from diag_plugin.examples.damadics import find_file, load_hour
    from diag_plugin.examples.expert_b2 import make_b2
    from diag_plugin.simulate.valve import TAGS, simulate_valve
    from diag_plugin.workbench.model_edit import new_model

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    half_year = simulate_valve(UNIT_DAYS, seed=SIM_SEED)
    frame = half_year.iloc[: int(SIM_DAYS * 8640)]
    info = TAGS
    source = f"diag simulate --days {SIM_DAYS} --seed {SIM_SEED}"
    for name, inputs, desc in (
        (
            "valve_a",
            ["CV[k-1]", "P1[k]"],
            "Model A: F_k = f(U_{k-1}, P_k) (Kościelny et al., eq. 8)",
        ),
        ("valve_b", ["CV[k-1]"], "Model B: F_k = f(U_{k-1}) (Kościelny et al., eq. 9)"),
    ):
        path = folder / f"{name}.toml"
        path.unlink(missing_ok=True)
        rb = new_model(
            path, name, "F[k]", inputs, frame=frame, tag_info=info, sets=31, description=desc
        )
        out.append(_fit(rb, frame, source).path)
    out.append(make_b2(folder / "valve_b.toml", folder / "valve_b2.toml"))  # the expert's B.2
    out.extend(
        build_valve_unit(folder, half_year, f"diag simulate --days {UNIT_DAYS} --seed {SIM_SEED}")
    )
    t4 = f"simulate_valve({UNIT_DAYS}, seed={SIM_SEED}, params=ValveParams(**TABLE4_PLANT))"
    out.extend(build_table4_unit(folder, t4))
    real = damadics or find_file()
    if real is not None:
        f = load_hour(real)
        path = folder / "damadics_f.toml"
        path.unlink(missing_ok=True)
        rb = new_model(
            path,
            "damadics_f",
            "F[k]",
            ["X[k]"],
            frame=f,
            tag_info=DTAGS,
            sets=31,
            period="1s",
            description="Lublin sugar factory actuator 3 (real hour, 1 s): F = f(X)",
        )
        out.append(_fit(rb, f, f"DAMADICS {real.name}").path)
    return out


#: the actuator Table 4 and rules (10)–(14) describe: no positioner (the controller output
#: drives the E/P converter: the open chain U → P0 → X → F), low-friction packing
#: (docs/explanation/table4.md, "Which plant Table 4 describes")
TABLE4_PLANT = {"positioner_gain": 0.0, "hysteresis": 0.03}


def build_table4_unit(folder: Path, source: str, days: float = UNIT_DAYS) -> list[Path]:
    """The second example unit: Table 4 as printed (``valve_t4``), on the plant it describes
    (:data:`TABLE4_PLANT`), trained on ``days`` of seed :data:`SIM_SEED` of that plant."""
    from diag_plugin.simulate.valve import ValveParams, simulate_valve

    frame = simulate_valve(days, seed=SIM_SEED, params=ValveParams(**TABLE4_PLANT))
    return build_valve_unit(
        folder,
        frame,
        source,
        name="valve_t4",
        models="valve_t4",
        matrix=TABLE4_MATRIX.replace('name = "valve_unit"', 'name = "valve_t4"'),
        description="E/P + servomotor + valve without positioner (Kościelny et al., Table 4)",
        outputs="VALVE_T4",
        symptoms="fuzzy",
    )


def build_valve_unit(
    folder: Path,
    frame: pd.DataFrame,
    source: str,
    *,
    conclusion: str = "mean",
    name: str = "valve_unit",
    models: str = "valve",
    matrix: str = UNIT_MATRIX,
    description: str = "positioner + servomotor + valve (Kościelny et al., Table 4, loop on X)",
    outputs: str = "VALVE1",
    symptoms: str = "crisp",
) -> list[Path]:
    """The example unit: four models, the Table 4 matrix, the unit file with learned
    thresholds (Kościelny et al., Sect. 5; thresholds held to a false-alarm budget,
    :mod:`diag_plugin.learn.thresholds`).

    Each model input's span is narrowed to the operating range of the training data
    (:func:`operating_span`, what ``diag explain`` proposes): P1 and P2 use a fifth of their
    0–4,000 kPa transducer range, and 31 sets over the whole range left the flow models
    coarse (fault-free thresholds of r1 and r4 ~9 % of span instead of ~4 %). Outputs keep
    their nominal span: it is the unit of the residual (eq. 6). The thresholds come from the
    training window itself, cross-fitted (each of 5 time blocks' residuals from models
    trained on the other four), as a user's ``diag unit learn`` over it would give them.
    ``conclusion="sets"`` trains the models with eq. 5 as printed (``benchmarks/bench_eq5.py``
    compares the two). ``symptoms``: the unit's diagnosis, crisp (nearest signature) or fuzzy
    (rules (10)–(14); ``benchmarks/bench_fuzzy_diagnosis.py`` compares them)."""
    from dataclasses import replace

    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.diagnose.unitfile import UnitFile, new_unit_text
    from diag_plugin.learn.thresholds import learn_thresholds
    from diag_plugin.selection.spans import operating_span
    from diag_plugin.simulate.valve import TAGS
    from diag_plugin.workbench.model_edit import new_model

    out = []
    tests = {}
    unit_name = name
    for test, (output, inputs, desc) in UNIT_TESTS.items():
        name = f"{models}_{test}"
        path = folder / f"{name}.toml"
        path.unlink(missing_ok=True)
        info = dict(TAGS)
        for spec in inputs:
            tag = spec.split("[")[0]
            narrow = operating_span(TAGS[tag].span, frame[tag].to_numpy())
            if narrow is not None:
                info[tag] = replace(TAGS[tag], lo=narrow[0], hi=narrow[1])
        rb = new_model(path, name, output, inputs, frame=frame, tag_info=info, description=desc)
        if conclusion != "mean":
            rb.doc["rules"]["conclusion"] = conclusion
            rb.edited()
            rb.save()
            rb = RuleBase.load(path)
        out.append(_fit(rb, frame, source).path)
        tests[test] = path.name
    matrix_path = folder / f"{unit_name}.matrix.toml"
    matrix_path.write_text(matrix, encoding="utf-8")
    out.append(matrix_path)
    path = folder / f"{unit_name}.unit.toml"
    text = new_unit_text(
        unit_name, tests, matrix=matrix_path.name, description=description, outputs=outputs
    )
    if symptoms != "crisp":
        text = text.replace('symptoms = "crisp"', f'symptoms = "{symptoms}"')
    path.write_text(text, encoding="utf-8")
    unit = Unit.load(path)
    got = learn_thresholds(unit, [frame], far=UNIT_FAR)
    uf = UnitFile.load(path)
    uf.set_learned(got)
    uf.save()
    out.append(path)
    return out


if __name__ == "__main__":  # pragma: no cover
    for p in build_examples(sys.argv[1] if len(sys.argv) > 1 else "rulebases"):
        print(p)
