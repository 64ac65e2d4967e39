"""A small SVG line-chart writer for the docs' figures (no plotting library needed).

One figure is a column of panels that share the x axis; each panel has line traces,
horizontal reference lines (thresholds) and vertical markers, its own y axis with "nice"
ticks, and the figure has one legend. The output is plain SVG 1.1 text; every element
carries a ``class`` (``trace``, ``hline``, ``vline``) and ``data-label`` / ``data-value``
attributes so tests can read a figure back with :mod:`xml.etree.ElementTree`.

Used by :func:`diag_plugin.engine.fdi.plot_residuals` for the residual plots like seed 000's
Figs. 8–12.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape, quoteattr

import numpy as np

__all__ = ["HLine", "Panel", "Trace", "VLine", "figure", "nice_ticks", "simplify"]


@dataclass
class Trace:
    """A polyline ``y`` over ``x`` (NaN splits the line)."""

    x: Sequence[float]
    y: Sequence[float]
    label: str
    color: str = "#1f4e9c"
    width: float = 1.2
    dash: str | None = None


@dataclass
class HLine:
    """A horizontal line at ``y`` across the panel (e.g. a threshold). With
    ``autoscale=False`` it does not widen the y range: outside it, the panel names its value
    ("off scale") instead of drawing it."""

    y: float
    label: str
    color: str = "#c0392b"
    dash: str | None = "6 3"
    width: float = 1.0
    autoscale: bool = True


@dataclass
class VLine:
    """A vertical marker at ``x`` (e.g. the instant a residual latched)."""

    x: float
    label: str
    color: str = "#2e7d32"
    dash: str | None = "2 2"
    width: float = 1.0


@dataclass
class Panel:
    """One axis box: its title (left, above the box), y-axis label and contents."""

    title: str
    traces: list[Trace] = field(default_factory=list)
    hlines: list[HLine] = field(default_factory=list)
    vlines: list[VLine] = field(default_factory=list)
    ylabel: str = ""


def nice_ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    """About ``n`` round tick values (steps 1, 2, 2.5 or 5 × 10^k) covering [lo, hi]."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError("tick range must be finite")
    if hi <= lo:
        lo, hi = lo - 0.5, lo + 0.5
    raw = (hi - lo) / max(n - 1, 1)
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(s * mag for s in (1.0, 2.0, 2.5, 5.0, 10.0) if s * mag >= raw * 0.999)
    first = math.floor(lo / step + 1e-9) * step
    ticks, t = [], first
    while t <= hi + step * 1e-9:
        ticks.append(round(t, 12))
        t += step
    if ticks[-1] < hi - step * 1e-9:
        ticks.append(round(t, 12))
    return ticks


def _fmt(v: float) -> str:
    return f"{v:.4g}" if abs(v) >= 1e-12 else "0"


def simplify(xs: np.ndarray, ys: np.ndarray, tol: float = 0.25) -> np.ndarray:
    """Indices of the points Ramer–Douglas–Peucker keeps: every dropped point lies within
    ``tol`` (pixels) of the kept polyline, so the drawing does not change visibly."""
    n = len(xs)
    if n <= 2:
        return np.arange(n)
    keep = np.zeros(n, dtype=bool)
    keep[[0, -1]] = True
    stack = [(0, n - 1)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        dx, dy = xs[b] - xs[a], ys[b] - ys[a]
        seg = np.hypot(dx, dy)
        px, py = xs[a + 1 : b] - xs[a], ys[a + 1 : b] - ys[a]
        d = np.abs(dx * py - dy * px) / seg if seg > 0 else np.hypot(px, py)
        i = int(np.argmax(d))
        if d[i] > tol:
            keep[a + 1 + i] = True
            stack += [(a, a + 1 + i), (a + 1 + i, b)]
    return np.flatnonzero(keep)


def _polyline_points(xs: np.ndarray, ys: np.ndarray) -> list[str]:
    """Point lists of the finite runs (a NaN breaks the line), simplified (:func:`simplify`)."""
    ok = np.r_[False, np.isfinite(xs) & np.isfinite(ys), False].astype(np.int8)
    edges = np.flatnonzero(np.diff(ok))
    runs = []
    for a, b in zip(edges[0::2], edges[1::2], strict=True):
        x, y = xs[a:b], ys[a:b]
        idx = simplify(x, y)
        runs.append(" ".join(f"{x[i]:.1f},{y[i]:.1f}" for i in idx))
    return runs


def _dash(d: str | None) -> str:
    return f' stroke-dasharray="{d}"' if d else ""


def figure(
    panels: Sequence[Panel],
    *,
    title: str,
    xlabel: str,
    width: int = 900,
    panel_height: int = 130,
    xlim: tuple[float, float] | None = None,
    note: str = "",
) -> str:
    """The SVG text of a column of ``panels`` sharing the x axis (ticks on every panel,
    the x label under the last); one legend under the title lists each distinct label."""
    left, right, gap = 70, 20, 34
    # legend: one entry per distinct label, in first-seen order, wrapped into rows
    seen: dict[str, str] = {}
    for p in panels:
        for item in [*p.traces, *p.hlines, *p.vlines]:
            if item.label not in seen:
                seen[item.label] = (
                    f'stroke="{item.color}" stroke-width="{max(item.width, 1.5)}"{_dash(item.dash)}'
                )
    legend, lx, ly = [], left, 36
    for label, style in seen.items():
        step = 40 + 6.2 * len(label)
        if lx > left and lx + step > width - right:
            lx, ly = left, ly + 16
        legend.append(f'<line x1="{lx}" y1="{ly}" x2="{lx + 24}" y2="{ly}" {style}/>')
        legend.append(f'<text x="{lx + 29}" y="{ly + 4}">{escape(label)}</text>')
        lx += step
    top_pad = ly + 26
    bottom = 48 + (16 if note else 0)
    height = top_pad + len(panels) * (panel_height + gap) - gap + bottom
    plot_w = width - left - right
    xs_all = [np.asarray(t.x, float) for p in panels for t in p.traces]
    if xlim is None:
        finite = np.concatenate([x[np.isfinite(x)] for x in xs_all]) if xs_all else np.zeros(1)
        xlim = (float(finite.min()), float(finite.max()))
    x0, x1 = xlim
    xt = [t for t in nice_ticks(x0, x1, 8) if x0 - 1e-9 <= t <= x1 + 1e-9]

    def sx(v: np.ndarray | float) -> np.ndarray | float:
        return left + (np.asarray(v, float) - x0) / (x1 - x0 or 1.0) * plot_w

    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'viewBox="0 0 {width} {height}" font-family="Helvetica, Arial, sans-serif" '
        'font-size="11">',
        f'<rect width="{width}" height="{height}" fill="white"/>',
        f'<text x="{width / 2:.0f}" y="18" text-anchor="middle" font-size="14" '
        f'font-weight="bold">{escape(title)}</text>',
        *legend,
    ]
    for i, p in enumerate(panels):
        top = top_pad + i * (panel_height + gap)
        ys = [np.asarray(t.y, float) for t in p.traces]
        ys.append(np.array([h.y for h in p.hlines if h.autoscale]))
        finite = np.concatenate([y[np.isfinite(y)] for y in ys])
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (-1.0, 1.0)
        yt = nice_ticks(lo, hi, 5)
        y0, y1 = yt[0], yt[-1]

        def sy(v: np.ndarray | float, top: float = top, y0: float = y0, y1: float = y1) -> Any:
            return top + panel_height - (np.asarray(v, float) - y0) / (y1 - y0) * panel_height

        out.append(f'<g class="panel" data-title={quoteattr(p.title)}>')
        out.append(
            f'<rect x="{left}" y="{top}" width="{plot_w}" height="{panel_height}" '
            'fill="none" stroke="#444"/>'
        )
        out.append(f'<text x="{left}" y="{top - 6}" font-weight="bold">{escape(p.title)}</text>')
        for t in yt:
            y = sy(t)
            line = (left, f"{y:.1f}", left + plot_w, f"{y:.1f}")
            out += _grid_line(line, (left - 5, f"{y + 4:.1f}"), "end", _fmt(t))
        for t in xt:
            x = sx(t)
            line = (f"{x:.1f}", top, f"{x:.1f}", top + panel_height)
            out += _grid_line(line, (f"{x:.1f}", top + panel_height + 13), "middle", _fmt(t))
        if p.ylabel:
            cy = top + panel_height / 2
            out.append(
                f'<text x="14" y="{cy:.1f}" text-anchor="middle" '
                f'transform="rotate(-90 14 {cy:.1f})">{escape(p.ylabel)}</text>'
            )
        inside = [y0 <= h.y <= y1 for h in p.hlines]
        if not all(inside):
            off: dict[str, list[float]] = {}
            for h, ok in zip(p.hlines, inside, strict=True):
                if not ok:
                    off.setdefault(h.label, []).append(h.y)
            text = ", ".join(
                f"{lab} ±{_fmt(abs(v[0]))}"
                if len(v) == 2 and v[0] == -v[1]
                else f"{lab} {', '.join(map(_fmt, v))}"
                for lab, v in off.items()
            )
            out.append(
                f'<text x="{left + plot_w}" y="{top - 6}" text-anchor="end" '
                f'fill="#777">off scale: {escape(text)}</text>'
            )
        for h, ok in zip(p.hlines, inside, strict=True):
            if not ok:
                continue
            y = sy(h.y)
            out.append(_marker("hline", h, h.y, (left, f"{y:.1f}", left + plot_w, f"{y:.1f}")))
        for v in p.vlines:
            x = sx(v.x)
            out.append(_marker("vline", v, v.x, (f"{x:.1f}", top, f"{x:.1f}", top + panel_height)))
        for t in p.traces:
            pts = _polyline_points(sx(np.asarray(t.x, float)), sy(np.asarray(t.y, float)))
            out.append(f'<g class="trace" data-label={quoteattr(t.label)}>')
            out.extend(
                f'<polyline points="{pts_}" fill="none" stroke="{t.color}" '
                f'stroke-width="{t.width}"{_dash(t.dash)}/>'
                for pts_ in pts
            )
            out.append("</g>")
        out.append("</g>")
    last_bottom = top_pad + len(panels) * (panel_height + gap) - gap
    out.append(
        f'<text x="{left + plot_w / 2:.0f}" y="{last_bottom + 32}" '
        f'text-anchor="middle">{escape(xlabel)}</text>'
    )
    if note:
        out.append(f'<text x="{left}" y="{last_bottom + 50}" fill="#555">{escape(note)}</text>')
    out.append("</svg>")
    return "\n".join(out) + "\n"


def write(svg: str, path: str | Path) -> Path:
    """Write ``svg`` to ``path`` (folders made); the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(svg, encoding="utf-8")
    return path


def _grid_line(line: tuple, at: tuple, anchor: str, label: str) -> list[str]:
    """A grey grid line from (x1, y1) to (x2, y2) and its tick label at (x, y)."""
    x1, y1, x2, y2 = line
    return [
        f'<line x1="{x1}" y1="{y1}" x2="{x2}" y2="{y2}" stroke="#e4e4e4"/>',
        f'<text x="{at[0]}" y="{at[1]}" text-anchor="{anchor}">{label}</text>',
    ]


def _marker(kind: str, m: HLine | VLine, value: float, line: tuple) -> str:
    """An :class:`HLine` or :class:`VLine` at ``value``, drawn from (x1, y1) to (x2, y2)."""
    x1, y1, x2, y2 = line
    return (
        f'<line class="{kind}" data-label={quoteattr(m.label)} data-value="{value!r}" '
        f'x1="{x1}" y1="{y1}" x2="{x2}" y2="{y2}" '
        f'stroke="{m.color}" stroke-width="{m.width}"{_dash(m.dash)}/>'
    )
