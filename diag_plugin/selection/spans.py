"""A variable's nominal span and sets: tag metadata first, then the span a model already
gives the tag, else the data's range; and the operating range an input's span can narrow to."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import pandas as pd

from diag_plugin.regressors import InputSpec, dir_threshold, feature
from diag_plugin.rulebase.document import Variable, default_label
from historian.taginfo import TagInfo, tag_infos


def variable_for(
    spec: str,
    *,
    frame: pd.DataFrame | None,
    tag_info: Mapping[str, TagInfo | Mapping[str, object]],
    sets: int | None = None,
    default_sets: int = 31,
    known_spans: Mapping[str, tuple[float, float]] | None = None,
) -> Variable:
    """A variable with its nominal span and sets: tag metadata first, then the span the model
    already gives the tag (``known_spans``), else the observed range. The one rule for spans
    and sets: ``explain`` scores each candidate on exactly the variable ``add-input`` writes.

    A ``dir()`` input gets its move threshold written into the spec, so training,
    inference and the live plug-in all use the same value.
    """
    s = InputSpec.parse(spec)
    info = tag_infos(tag_info)
    if s.fn == "dir" and s.param is None:
        spans = dict(known_spans or {})
        spans.update({t: i.span for t, i in info.items() if i.span})
        s = InputSpec("dir", s.tags, s.lag, dir_threshold(s.tags[0], spans, frame))
        spec = str(s)
    unit = ""
    span: tuple[float, float] | None = None
    n_sets = sets or default_sets
    if s.fn == "dir":
        span, n_sets = (-1.0, 1.0), 2
    elif s.fn == "hour":
        span, unit, n_sets = (0.0, 24.0), "h", sets or 25
    elif s.fn in ("", "diff", "mean"):  # a mean: the tag's unit and span
        tag = info.get(s.tags[0]) or TagInfo(s.tags[0])
        unit = tag.unit
        if s.fn in ("", "mean"):
            span = tag.span
        if s.fn in ("", "mean") and span is None and s.tags[0] in (known_spans or {}):
            span = tuple(known_spans[s.tags[0]])  # the span the model already uses for it
    if s.fn == "days":
        unit, n_sets = "d", sets or 12
    if span is None:
        if frame is None:
            raise ValueError(f"no nominal range known for {spec}: give the tag a range")
        v = feature(frame, s)
        v = v[np.isfinite(v)]
        if v.size == 0:
            raise ValueError(f"no data for {spec} to take its range from")
        lo, hi = np.quantile(v, [0.001, 0.999]) if s.fn in ("rate", "diff") else (v.min(), v.max())
        lo, hi = float(lo), float(hi)
        if hi <= lo:
            hi = lo + max(abs(lo), 1.0) * 0.01
        pad = 0.02 * (hi - lo)
        span = nice_span(lo - pad, hi + pad)
    return Variable(spec, default_label(spec), unit, span, int(n_sets))


def nice_span(lo: float, hi: float) -> tuple[float, float]:
    """``[lo, hi]`` with each end to 4 significant digits, or finer where the width needs it
    (a day of ``days()`` near 9,500 keeps its width instead of collapsing to one value)."""
    w = math.floor(math.log10(hi - lo))

    def nice(v: float) -> float:
        mag = math.floor(math.log10(abs(v))) if v else w
        return float(f"{v:.{max(4, mag - w + 4)}g}")

    return nice(lo), nice(hi)


#: margin around the operating range when an input's span is narrowed to it
SPAN_MARGIN = 0.1


def operating_span(span: tuple[float, float], values: np.ndarray) -> tuple[float, float] | None:
    """``span`` narrowed to the operating range of ``values`` (0.1–99.9 % quantiles, with a
    margin of :data:`SPAN_MARGIN`, inside the nominal span), or None when that range fills
    70 % of the span or more. The rule ``explain`` proposes and the example unit follows:
    31 sets over a transducer range the process uses a sliver of leave a coarse model."""
    x = values[np.isfinite(values)]
    if x.size < 10:
        return None
    lo, hi = (float(q) for q in np.quantile(x, [0.001, 0.999]))
    pad = SPAN_MARGIN * (hi - lo)
    lo, hi = max(span[0], lo - pad), min(span[1], hi + pad)
    if hi > lo and (hi - lo) < 0.7 * (span[1] - span[0]):
        return nice_span(lo, hi)
    return None
