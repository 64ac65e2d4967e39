"""The small SVG line-chart writer of the docs' figures (diag_plugin/engine/svgplot.py)."""

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from diag_plugin.engine import svgplot as sp

NS = {"s": "http://www.w3.org/2000/svg"}


@pytest.mark.parametrize(
    "lo, hi", [(0.0, 1.0), (-0.043, 0.127), (3000.0, 4999.0), (-1e-4, 3e-4), (2.0, 2.0)]
)
def test_nice_ticks_cover_the_range_with_round_steps(lo, hi):
    t = sp.nice_ticks(lo, hi, 5)
    assert t[0] <= lo and t[-1] >= hi and 3 <= len(t) <= 9
    steps = np.diff(t)
    assert np.allclose(steps, steps[0])
    mant = steps[0] / 10 ** np.floor(np.log10(steps[0]))
    assert any(np.isclose(mant, m) for m in (1, 2, 2.5, 5, 10))


def test_simplify_keeps_every_point_within_the_tolerance():
    rng = np.random.default_rng(3)
    x = np.linspace(0, 800, 2000)
    y = 60 * np.sin(x / 90) + np.cumsum(rng.normal(0, 0.3, x.size))
    idx = sp.simplify(x, y, tol=0.25)
    assert idx[0] == 0 and idx[-1] == x.size - 1 and np.all(np.diff(idx) > 0)
    assert idx.size < x.size / 2
    yy = np.interp(x, x[idx], y[idx])  # the drawn polyline, sampled at the dropped points
    # vertical gap ≥ perpendicular distance, so allow for the slope: a loose bound
    assert np.max(np.abs(yy - y)) < 2.0


def _figure(note=""):
    x = np.arange(3000, 5000, dtype=float)
    y1 = 0.05 * np.sin(x / 100)
    y2 = np.where(x < 3500, np.nan, 0.1 * np.cos(x / 70))  # a NaN gap breaks the line
    panels = [
        sp.Panel(
            "r1 <eq. 7>",
            [sp.Trace(x, y1, "no fault", color="#aaa"), sp.Trace(x, y2, "fault & more")],
            [sp.HLine(0.042, "threshold"), sp.HLine(-0.042, "threshold")]
            + [sp.HLine(v, "Table III", autoscale=False) for v in (0.3, -0.3)],
            [sp.VLine(3600, "latched")],
        ),
        sp.Panel("r2", [sp.Trace(x, y1, "no fault")], [sp.HLine(0.01, "threshold")]),
    ]
    return sp.figure(panels, title="Fig. 8 & co", xlabel="revolution", note=note)


def test_figure_is_valid_svg_with_traces_lines_and_legend():
    svg = _figure(note="scaled residual")
    root = ET.fromstring(svg)  # well-formed XML (labels with <, & are escaped)
    assert root.tag == "{http://www.w3.org/2000/svg}svg"
    traces = root.findall(".//s:g[@class='trace']", NS)
    assert [t.get("data-label") for t in traces] == ["no fault", "fault & more", "no fault"]
    # the NaN gap splits the second trace into one polyline after the gap
    assert [len(t.findall("s:polyline", NS)) for t in traces] == [1, 1, 1]
    hl = root.findall(".//s:line[@class='hline']", NS)
    assert sorted(float(h.get("data-value")) for h in hl) == [-0.042, 0.01, 0.042]
    assert [float(v.get("data-value")) for v in root.findall(".//s:line[@class='vline']", NS)] == [
        3600.0
    ]
    text = " ".join("".join(t.itertext()) for t in root.iter("{http://www.w3.org/2000/svg}text"))
    # lines kept off the y range are named instead of drawn
    assert "off scale: Table III ±0.3" in text
    for label in ("no fault", "fault & more", "threshold", "latched", "revolution", "r1 <eq. 7>"):
        assert label in text
    assert "Fig. 8 & co" in text and "scaled residual" in text


def test_figure_points_lie_inside_their_panel():
    root = ET.fromstring(_figure())
    w, h = float(root.get("width")), float(root.get("height"))
    for pl in root.iter("{http://www.w3.org/2000/svg}polyline"):
        pts = np.array([p.split(",") for p in pl.get("points").split()], dtype=float)
        assert (pts[:, 0] >= 70 - 0.1).all() and (pts[:, 0] <= w - 20 + 0.1).all()
        assert (pts[:, 1] > 0).all() and (pts[:, 1] < h).all()
