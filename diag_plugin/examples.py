"""The example rule bases shipped in ``rulebases/`` and how they are made.

* ``valve_a``: Model A of Kościelny et al., eq. 8: ``F_k = f(U_{k-1}, P_k)`` with the
  upstream pressure P1, trained on 60 days of the simulated valve assembly.
* ``valve_b``: Model B, eq. 9: ``F_k = f(U_{k-1})``, the same data.
* ``damadics_f``: the real Lublin actuator 3 hour (1 s): ``F = f(X[k])``.

31 uniform trapezoidal sets per variable (Sect. 4.4). Regenerate with
``python -m diag_plugin.examples rulebases``; the result is reproducible to the byte.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from diag_plugin.rulebase import RuleBase
from diag_plugin.training import train

SIM_DAYS = 60
SIM_SEED = 1


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
    from diag_plugin.damadics import TAGS as DTAGS
    from diag_plugin.damadics import find_file, load_hour
    from diag_plugin.simulate.valve import TAGS, simulate_valve
    from diag_plugin.workbench.model_edit import new_model

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    frame = simulate_valve(SIM_DAYS, seed=SIM_SEED)
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


if __name__ == "__main__":  # pragma: no cover
    for p in build_examples(sys.argv[1] if len(sys.argv) > 1 else "rulebases"):
        print(p)
