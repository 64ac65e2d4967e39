"""``diag compare-methods NAME``: every registered method trained on the same historian data.

Like Laukonen et al.'s Figs. 3–7 (fuzzy clustering beside NARMAX on the same training and
validation data): for the model file ``NAME`` each method of the registry is trained by
:func:`diag_plugin.training.chunked.train` on the same range, the same held-out validation part
and the same spans, with the method's default options; nothing is saved. Reported per method:
the validation sum of squared errors Σe² (output units²), the RMSE in % of the output span
(seed 001 eq. 6), the coverage and the fit time.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

from diag_plugin.models.registry import METHODS, get_method
from diag_plugin.rulebase.document import RuleBase
from diag_plugin.training.chunked import DEFAULT_CHUNK, train
from diag_plugin.training.jobs import data_window
from historian.access import WindowReader

__all__ = ["AsMethod", "compare_methods"]


class AsMethod:
    """A model file seen as if it named another method (its default options, no locks).

    It holds exactly what :func:`~diag_plugin.training.chunked.train` reads of a model file,
    each named here: no ``__getattr__`` forwards the rest to the file, so an attribute this
    view lacks, or one that fails inside a property, is an ``AttributeError`` at the caller,
    never the file's own value standing in silently (issue 36: a missing
    ``default_options`` made the "wm" row train the file's wm-avg).
    """

    def __init__(self, rb: RuleBase, method: str) -> None:
        self.method = method
        self.codec = get_method(method)
        self.period = rb.period
        self.inputs = rb.inputs
        self.output = rb.output
        self.spec = dataclasses.replace(
            rb.spec, method=method, options=dict(self.codec.default_options())
        )

    def new_model(self) -> Any:
        """An untrained estimator of this method on the file's inputs and spans."""
        return self.codec.new_estimator(self.spec)

    def predictor(self, model: Any) -> Any:
        """The trained model itself (a comparison applies no expert locks)."""
        return model


def _sse(validation: dict[str, Any], span: float) -> float:
    """Σe² in output units from the RMSE in % of span and the sample count."""
    return float(validation["samples"] * (validation["rmse_pct"] * span / 100.0) ** 2)


def compare_methods(
    path: Path,
    url: str,
    *,
    start: str | None = None,
    end: str | None = None,
    holdout: float = 0.2,
    methods: tuple[str, ...] | None = None,
) -> list[dict[str, Any]]:
    """Train each identification method (default: every registered one that identifies) on
    the same data of the model file ``path`` (Figs. 3–7 style)."""
    rb = RuleBase.load(path)
    tags, t0, t1 = data_window(rb, url, start, end)
    span = rb.output.span[1] - rb.output.span[0]
    out = []
    for method in methods or tuple(m.name for m in METHODS.values() if m.identifies):
        reader = WindowReader(url, tuple(tags), rb.period)
        started = time.perf_counter()
        try:
            res = train(AsMethod(rb, method), reader, t0, t1, holdout=holdout, chunk=DEFAULT_CHUNK)
        finally:
            reader.close()
        v = res.validation
        out.append(
            {
                "method": method,
                "sse": _sse(v, span),
                "rmse_pct": v["rmse_pct"],
                "coverage": v["coverage"],
                "samples": v["samples"],
                "fit_s": round(time.perf_counter() - started, 3),
            }
        )
    return out
