"""``diag report``: one self-contained page, rendered in headless Chromium.

The page is built from a synthetic valve (flow from controller output and
upstream pressure, 24 days of 10 s samples) without a database. Chromium
(Debian package ``chromium``) loads it with the network off; the page's own
script marks ``<body data-rendered="ok">`` once every chart is drawn and lists
any script error in ``#errors``; Chromium's console log is checked too.
"""

from __future__ import annotations

import base64
import html
import json
import re
import shutil
import struct
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import requires, valve_frame

from diag_plugin.metrics import error_figures
from diag_plugin.regressors import build_design
from diag_plugin.rulebase.document import RuleBase, Variable
from diag_plugin.workbench.compare import Comparison, compare, worst_periods
from diag_plugin.workbench.explain import explain
from diag_plugin.workbench.report import (
    OVERVIEW_BUCKETS,
    experiment_rows,
    time_breaks,
    time_levels,
    write_report,
)

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
needs_chromium = requires(
    "headless Chromium",
    CHROMIUM is not None,
    "Debian package 'chromium'; .ci/sysdeps installs it",
)
SPANS = {"CV": (0.0, 100.0, "%"), "P1": (0.0, 1000.0, "kPa")}
TAG_INFO = {
    "CV": {"unit": "%", "lo": 0, "hi": 100, "description": "controller output"},
    "P1": {"unit": "kPa", "lo": 0, "hi": 1000, "description": "upstream pressure"},
    "F": {"unit": "t/h", "lo": 0, "hi": 40, "description": "feed-water flow"},
}
SPIKE = 37.5  # t/h: one sample of the measured flow, far above everything else
NAN = float("nan")


def _rulebase(path: Path, inputs) -> RuleBase:
    return RuleBase.new(
        "valve",
        Variable("F[k]", "F", "t/h", (0.0, 40.0), 31),
        [Variable(s, s.split("[")[0], SPANS[s[:2]][2], SPANS[s[:2]][:2], 31) for s in inputs],
        path=path / "valve.toml",
        description='Feed-water valve <script>alert("x")</script> & flow',
    )


def _story(path: Path, days: float, inputs):
    """A trained model (rules only below 600 kPa, so some cells are unsupported)."""
    f = valve_frame(days, seed=3)
    rb = _rulebase(path, inputs)
    d = build_design(f, [v.spec for v in rb.inputs], rb.output.spec)
    keep = d.X[:, -1] < 600 if "P1[k]" in inputs else d.X[:, 0] < 90
    rb.apply_training(rb.new_model().fit(d.X[keep], d.y[keep]))
    f.iloc[len(f) // 3, f.columns.get_loc("F")] = SPIKE
    return rb, f


def _experiments() -> pd.DataFrame:
    # the historian's shape: metrics as dicts or JSON text, inputs as lists or JSON text
    return pd.DataFrame(
        {
            "version": ["1", "2", "3"],
            "created_at": pd.to_datetime(
                ["2026-02-03 09:00", "2026-02-01 09:00", "2026-02-02 09:00"], utc=True
            ),
            "inputs": ['["CV[k-1]", "P1[k]"]', ["CV[k]"], ["CV[k-1]"]],
            "metrics": [
                {"rmse_pct": 0.52, "mae_pct": 0.41, "coverage": 0.81},
                '{"rmse_pct": 7.9, "mae_pct": 6.1, "coverage": 1.0}',
                {"rmse_pct": 6.02, "mae_pct": 5.0, "coverage": NAN},
            ],
        }
    )


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """The user-story page: two inputs, ≥ 200k samples, explanation and history."""
    tmp = tmp_path_factory.mktemp("report")
    rb, f = _story(tmp, 24, ("CV[k-1]", "P1[k]"))
    assert len(f) >= 200_000
    c = compare(rb, f)
    e = explain(rb, f, tag_info=TAG_INFO, max_lag=3)
    path = write_report(tmp / "valve.html", rb, c, e, _experiments(), f)
    return path, c, e


def _data(page: str) -> dict:
    m = re.search(r'<script type="application/json" id="report-data">(.*?)</script>', page, re.S)
    assert m, "no embedded data"

    def bad(token):
        raise AssertionError(f"{token} in the embedded JSON")

    return json.loads(m.group(1), parse_constant=bad)


def _f32(b64: str) -> np.ndarray:
    return np.frombuffer(base64.b64decode(b64), "<f4")


# --------------------------------------------------------------------- the page itself
def test_page_is_self_contained_and_escaped(report):
    path, c, e = report
    page = path.read_text("utf-8")
    assert path.stat().st_size < 5_000_000
    # nothing is fetched: no external src/href, no <link>, and a CSP that forbids it anyway
    assert not re.search(r"""(?:src|href)\s*=\s*["']?\s*(?:https?:)?//""", page, re.I)
    assert not re.search(r"<link\b", page, re.I)
    assert "default-src 'none'" in page
    assert not re.search(r"<script[^>]*\bsrc\s*=", page, re.I)
    # uPlot and its MIT licence are inlined
    assert "uPlot" in page and "Permission is hereby granted" in page
    # text is escaped: the description's markup shows as text
    assert '<script>alert("x")</script>' not in page
    assert "&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt; &amp; flow" in page
    d = _data(page)  # no NaN / Infinity tokens
    assert d["model"] == "valve" and d["map"]["dims"] == 2
    # every section is there, with the exact command of the best candidate
    for section in ("metrics", "time", "hist", "map", "windows", "candidates", "experiments"):
        assert f'id="{section}"' in page
    best = e.candidates[0]
    assert f"<code>{best.command.replace(chr(39), '&#x27;')}</code>" in page
    assert "cells with samples but no rule" in page  # the untrained high-pressure cells
    assert f"{c.metrics['rmse_pct']:.2f} %" in page


def test_downsampling_is_honest(report):
    path, c, _ = report
    d = _data(path.read_text("utf-8"))
    levels = d["levels"]
    assert levels[0]["n"] == OVERVIEW_BUCKETS and len(levels) == 2
    assert levels[1]["n"] > 10 * OVERVIEW_BUCKETS
    assert "each pixel column shows the band from the lowest to the highest" in path.read_text(
        "utf-8"
    )
    res = np.asarray(c.residual, float)
    ok = np.isfinite(res)
    assert 0.05 < 1 - ok.mean() < 0.95  # unsupported samples: the means must skip them
    t = (c.index.as_unit("ns").asi8 - c.index[0].as_unit("ns").value) / 1e9
    for lv in levels:
        y, r = _f32(lv["y"]), _f32(lv["r"])
        assert y.size == 2 * lv["n"]
        # the one-sample spike survives at every level, in the measurement and the residual
        assert np.nanmax(y) == pytest.approx(SPIKE, rel=1e-6)
        assert np.nanmax(r) == pytest.approx(np.nanmax(c.residual), rel=1e-5)
        assert np.nanmin(r) == pytest.approx(np.nanmin(c.residual), rel=1e-5)
        # the bucket means of the residual, recomputed here from the samples' times: each
        # bucket's mean of its supported samples (NaN without any) ...
        rmean = _f32(lv["rmean"]).astype(float)
        assert rmean.size == lv["n"]
        bucket = np.minimum((t / lv["w"]).astype(np.int64), lv["n"] - 1)
        k = np.bincount(bucket[ok], minlength=lv["n"])
        s = np.bincount(bucket[ok], weights=res[ok], minlength=lv["n"])
        np.testing.assert_array_equal(np.isnan(rmean), k == 0)
        has = k > 0
        np.testing.assert_allclose(rmean[has], s[has] / k[has], rtol=1e-6, atol=1e-5)
        # ... so, weighted by those sample counts, they average to the overall mean
        weighted = np.sum(rmean[has] * k[has]) / k.sum()
        assert weighted == pytest.approx(np.mean(res[ok]), abs=1e-5), (weighted, np.mean(res[ok]))


def test_min_max_order_and_gaps():
    idx = pd.date_range("2026-01-01", periods=12, freq="10s", tz="UTC")
    y = np.array([1, 5, 2, 9, 0, 3, 4, 4, 4, NAN, NAN, NAN], float)
    lv = time_levels(idx, y, y, y, overview=4, detail=4)
    assert len(lv) == 1 and lv[0]["n"] == 4 and lv[0]["per_bucket"] == 3
    got = _f32(lv[0]["y"]).reshape(4, 2)
    np.testing.assert_array_equal(got[0], [1, 5])  # min came first
    np.testing.assert_array_equal(got[1], [9, 0])  # max came first
    np.testing.assert_array_equal(got[2], [4, 4])
    assert np.isnan(got[3]).all()  # an unsupported stretch stays a gap
    assert lv[0]["x0"] == pytest.approx(idx[0].timestamp())


def test_page_size_for_months_of_data(report, tmp_path):
    """1.5 M samples (half a year of 10 s data) stay well under 5 MB."""
    _, small, _ = report
    n = 1_500_000
    rng = np.random.default_rng(1)
    idx = pd.date_range("2026-01-01", periods=n, freq="10s", tz="UTC")
    y = 20 + 10 * np.sin(np.arange(n) / 8640 * 2 * np.pi) + rng.normal(0, 0.2, n)
    yhat = y - rng.normal(0, 0.2, n)
    yhat[200_000:230_000] = np.nan  # an unsupported stretch
    y[777_777] = 39.0
    res = (y - yhat) / 40 * 100
    big = Comparison(
        name="valve",
        index=idx,
        y=y,
        yhat=yhat,
        residual=res,
        reason=np.zeros(n, np.int8),
        metrics=error_figures(res),
        regions=small.regions,
        periods=worst_periods(idx, res),
        tags=small.tags,
    )
    rb = _rulebase(tmp_path, ("CV[k-1]", "P1[k]"))
    path = write_report(tmp_path / "months.html", rb, big, None, None)
    size = path.stat().st_size
    assert size < 5_000_000, size
    d = _data(path.read_text("utf-8"))
    assert [lv["n"] for lv in d["levels"]] == [2_000, 50_000]
    assert all(np.nanmax(_f32(lv["y"])) == pytest.approx(39.0) for lv in d["levels"])
    print(f"1.5 M samples: {size / 1e6:.2f} MB")


def test_experiment_rows_are_tolerant():
    rows = experiment_rows(_experiments())
    assert [r["version"] for r in rows] == ["2", "3", "1"]  # oldest first
    assert [r["rmse_pct"] for r in rows] == [7.9, 6.02, 0.52]
    assert rows[2]["inputs"] == ["CV[k-1]", "P1[k]"] and rows[1]["coverage"] is None
    assert experiment_rows(None) == [] and experiment_rows(pd.DataFrame()) == []
    # metrics as columns, no created_at, the job's key name, inputs as plain text
    odd = pd.DataFrame({"version": [1, 2], "inputs": ["CV[k]", "CV[k-1], P1[k]"]})
    odd["metrics"] = ['{"validation_rmse_pct": 3.0}', "not json"]
    rows = experiment_rows(odd)
    assert [r["rmse_pct"] for r in rows] == [3.0, None]
    assert rows[1]["inputs"] == ["CV[k-1]", "P1[k]"]


# ------------------------------------------------------------------------- Chromium
def _chromium(url: str, profile: Path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [
        CHROMIUM,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--hide-scrollbars",
        f"--user-data-dir={profile}",
        "--enable-logging=stderr",
        "--v=0",
        "--virtual-time-budget=10000",
        *extra,
        url,
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)


def _render(path: Path, tmp: Path, fragment: str = "") -> str:
    """The DOM after the page's scripts ran; fails on any console error."""
    res = _chromium(path.as_uri() + fragment, tmp / "profile-dom", "--dump-dom")
    assert res.returncode == 0, res.stderr[-2000:]
    console = [ln for ln in res.stderr.splitlines() if ":CONSOLE" in ln]
    bad_words = r"Uncaught|Refused|Content Security Policy|error"
    bad = [ln for ln in console if re.search(bad_words, ln, re.I)]
    assert not bad, "\n".join(bad)
    dom = res.stdout
    errors = re.search(r'<div id="errors"[^>]*>(.*?)</div>', dom, re.S)
    assert errors is not None and errors.group(1).strip() == "", errors.group(1)
    assert 'data-rendered="ok"' in dom, dom[:500]
    return dom


def _png_pixels(path: Path, max_rows: int = 1200) -> np.ndarray:
    """Decode the top rows of an 8-bit RGB(A) PNG (enough to see the charts)."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, hdr = 8, [], None
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos : pos + 8])
        body = data[pos + 8 : pos + 8 + n]
        if kind == b"IHDR":
            hdr = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        pos += 12 + n
    w, h, depth, ctype, _, _, interlace = hdr
    assert depth == 8 and ctype in (2, 6) and interlace == 0, hdr
    bpp = 3 if ctype == 2 else 4
    raw = zlib.decompress(b"".join(idat))
    stride = w * bpp
    assert len(raw) == h * (stride + 1)
    rows = min(h, max_rows)
    out = np.zeros((rows, stride), np.uint8)
    prev = np.zeros(stride, np.uint8)
    for y in range(rows):
        f = raw[y * (stride + 1)]
        r = np.frombuffer(raw, np.uint8, stride, y * (stride + 1) + 1)
        if f == 0:
            cur = r.copy()
        elif f == 1:
            cur = np.cumsum(r.reshape(w, bpp), axis=0, dtype=np.uint8).ravel()
        elif f == 2:
            cur = r + prev
        else:  # average / Paeth: sequential along the row
            cur, p = bytearray(r.tobytes()), prev.tobytes()
            for i in range(stride):
                a = cur[i - bpp] if i >= bpp else 0
                b = p[i]
                if f == 3:
                    cur[i] = (cur[i] + ((a + b) >> 1)) & 255
                    continue
                c = p[i - bpp] if i >= bpp else 0
                pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                cur[i] = (cur[i] + pred) & 255
            cur = np.frombuffer(bytes(cur), np.uint8)
        out[y] = cur
        prev = cur
    return out.reshape(rows, w, bpp)[..., :3]


@needs_chromium
def test_renders_in_headless_chromium_with_a_screenshot(report, tmp_path):
    path, _, _ = report
    dom = _render(path, tmp_path)
    # time, residual, histogram, runs, and the residual against a tag where one cuts the error
    drawn = 4 + ("x" in (_data(path.read_text("utf-8"))["scatter"] or {}))
    assert f'data-charts="{drawn}"' in dom
    shot = tmp_path / "report.png"
    res = _chromium(
        path.as_uri(), tmp_path / "profile-shot", f"--screenshot={shot}", "--window-size=1400,3000"
    )
    assert res.returncode == 0 and shot.exists(), res.stderr[-2000:]
    assert shot.stat().st_size > 100_000
    px = _png_pixels(shot)
    colours = np.unique(px.reshape(-1, 3), axis=0)
    assert len(colours) > 500  # text, lines, bars: not a blank page
    # the measured (blue) and model (orange) lines are drawn
    blue = (px[..., 2] > 140) & (px[..., 0] < 80)
    orange = (px[..., 0] > 200) & (px[..., 1] > 90) & (px[..., 1] < 160) & (px[..., 2] < 60)
    assert blue.sum() > 2000 and orange.sum() > 2000
    keep = Path(path).with_suffix(".png")
    shutil.copy(shot, keep)
    print(f"screenshot: {keep}")


@needs_chromium
def test_zoom_from_the_address_uses_the_detail_level(report, tmp_path):
    path, _, _ = report
    dom = _render(path, tmp_path, "#zoom=2026-01-05T00:00:00Z/2026-01-05T06:00:00Z")
    m = re.search(r'<span id="resolution"[^>]*data-level="(\d)"[^>]*data-points="(\d+)"', dom)
    assert m and m.group(1) == "1", dom[:300]
    assert 500 < int(m.group(2)) < 5000  # 6 h of a 50,000-bucket level


@needs_chromium
@pytest.mark.parametrize(
    ("inputs", "charts", "with_explanation"),
    [(("CV[k-1]",), 5, True), (("CV[k-1]", "P1[k]", "CV[k-2]"), 3, False)],
)
def test_one_and_three_inputs_render(tmp_path, inputs, charts, with_explanation):
    rb, f = _story(tmp_path, 3, inputs)
    c = compare(rb, f)
    e = explain(rb, f, tag_info=TAG_INFO, max_lag=2) if with_explanation else None
    path = write_report(tmp_path / "r.html", rb, c, e, _experiments() if e else None)
    page = path.read_text("utf-8")
    if len(inputs) == 1:
        assert 'id="chart-map"' in page
    else:
        assert "cells with the largest error" in page and 'id="heatmap"' not in page
        assert "No experiments recorded" in page
    dom = _render(path, tmp_path)
    assert f'data-charts="{charts}"' in dom


# ------------------------------------------------------------------ issue 37: the page reads
@needs_chromium
@pytest.mark.parametrize("width", [900, 1400])
def test_the_whole_range_is_an_envelope_per_pixel_column_not_a_zigzag(report, tmp_path, width):
    """Issue 37: 30 days drawn as 2 × 2,000 bucket extremes per series on ~1,300 pixels made
    measured and model one blur. Zoomed out, each series is a band of at most one column per
    pixel of the plot (lowest to highest there); zoomed in past the pixels, every sample."""
    path, _, _ = report
    res = _chromium(
        path.as_uri(), tmp_path / "profile-env", "--dump-dom", f"--window-size={width},2000"
    )
    assert res.returncode == 0, res.stderr[-2000:]
    m = re.search(
        r'<span id="resolution"[^>]*data-level="(\d)"[^>]*data-points="(\d+)"'
        r'[^>]*data-envelope="(\d)"',
        res.stdout,
    )
    assert m, res.stdout[:300]
    assert m.group(3) == "1" and 0.5 * width < int(m.group(2)) <= width, m.groups()
    assert "Each pixel column holds ~" in res.stdout
    dom = _render(path, tmp_path, "#zoom=2026-01-05T00:00:00Z/2026-01-05T00:30:00Z")
    m = re.search(r'data-points="(\d+)"[^>]*data-envelope="(\d)"', dom)
    assert m and m.group(2) == "0" and int(m.group(1)) < 200, m and m.groups()


def test_residual_against_the_tag_explain_suggests(report):
    """The chart is drawn against explain's first missing effect where one cuts the error;
    where none does, the page says so (:func:`test_no_residual_chart_when_no_candidate_
    cuts_the_error`)."""
    from diag_plugin.workbench.explain import CUTS

    path, c, e = report
    d = _data(path.read_text("utf-8"))
    s = d["scatter"]
    missing = [x for x in e.candidates if x.input not in ("CV[k-1]", "P1[k]")]
    first = missing[0]
    assert s["spec"] == first.input and s["why"] == "the effect diag explain ranks first"
    cuts = any(x.rmse_pct_if_added < CUTS * e.baseline_rmse_pct for x in missing)
    assert bool(s.get("none_cuts")) == (not cuts), (s, e.as_dict())
    if not cuts:
        assert 'id="scatter-none"' in path.read_text("utf-8")
        return
    _check_scatter(s, c)
    assert 'id="scatter"' in path.read_text("utf-8")


def _check_scatter(s: dict, c: Comparison) -> None:
    """The drawn residual-against-a-variable chart's data are consistent."""
    x, r = _f32(s["x"]), _f32(s["r"])
    assert len(x) == len(r) == s["shown"] == min(4000, s["samples"])
    assert np.all(np.diff(x) >= 0) and s["samples"] > 0.5 * np.isfinite(c.residual).sum()
    # the average line: the residual's mean in equal-count bins of the variable, so its
    # count-weighted mean is the residual's mean over the samples with both
    assert 5 <= len(s["bin_x"]) == len(s["bin_mean"]) <= 30
    assert np.all(np.diff(s["bin_x"]) > 0)
    assert np.mean(s["bin_mean"]) == pytest.approx(np.nanmean(c.residual), abs=0.5)


def test_without_explain_the_scatter_takes_the_tag_the_residual_follows(tmp_path):
    rb, f = _story(tmp_path, 3, ("CV[k-1]",))
    c = compare(rb, f)
    page = write_report(tmp_path / "r.html", rb, c, None, None, f).read_text("utf-8")
    s = _data(page)["scatter"]
    assert s["spec"] == c.tags["tag"].iloc[0] + "[k]"
    assert s["why"] == "the tag the residual follows most"
    # the same share of the residual as compare's table says (deciles there, 30 bins here)
    assert s["explained_pct"] == pytest.approx(c.tags["explained_pct"].iloc[0], abs=5)
    # a scatter needs the data: without the frame there is none, and no empty section
    page = write_report(tmp_path / "r2.html", rb, c, None, None).read_text("utf-8")
    assert _data(page)["scatter"] is None and 'id="scatter"' not in page


def test_warnings_are_worded_for_a_plant_engineer(report):
    from diag_plugin.workbench.report import plain_note

    said = plain_note(
        "strongly correlated with P1[k] (r = 0.93): the two effects are hard to separate in "
        "these data"
    )
    assert said.startswith("moves together with P1[k] in these data (correlation 0.93)")
    said = plain_note(
        "the rule grid would be thin (12 samples per rule, the fine grid answering 81% of the "
        "samples; coarser rules answer the rest): consider fewer sets, e.g. --sets 9"
    )
    assert "few measurements per operating point (about 12 each)" in said
    assert "81 % of the samples" in said and said.endswith("(--sets 9)")
    assert "rule grid" not in said
    said = plain_note(
        "with 31 sets the rule grid would be thin (4 samples per rule, the fine grid answering "
        "60%): 9 sets score better"
    )
    assert said == (
        "with 31 sets there would be too few measurements per operating point; 9 sets do "
        "better here, and the command uses them"
    )
    assert plain_note("something else") == "something else"
    path, _, _ = report
    text = re.sub(r"<script.*?</script>", "", path.read_text("utf-8"), flags=re.S)
    prose = " ".join(re.findall(r'<p class="(?:note|warn)">(.*?)</p>', text, re.S))
    for jargon in ("unsupported", "rule cell", "bucket", "supported)"):
        assert jargon not in prose, jargon


# ------------------------------------------------- short runs far apart: a broken time axis
RUNS = (("2026-01-01 06:00", 720), ("2026-01-05 14:00", 540), ("2026-01-10 22:00", 900))


def _runs_frame(seed: int) -> pd.DataFrame:
    """Three 1.5–2.5 h runs of 10 s samples, days apart, on the regular grid the historian
    aligns them on (empty rows between the runs, which ``compare`` drops)."""
    f = valve_frame(11, seed=seed)
    parts = [f.iloc[f.index.get_loc(pd.Timestamp(a, tz="UTC")) :][:n] for a, n in RUNS]
    runs = pd.concat(parts)
    return runs.reindex(pd.date_range(runs.index[0], runs.index[-1], freq="10s", name="ts"))


def test_breaks_only_where_gaps_dominate():
    idx = pd.date_range("2026-01-01", periods=1000, freq="10s", tz="UTC")
    assert time_breaks(idx) == []  # continuous
    out = idx.delete(slice(400, 480))  # an outage of 8 % of the span: the calendar stays
    assert time_breaks(out) == []
    runs = _runs_frame(5).dropna(subset=["F"]).index
    b = time_breaks(runs)
    assert len(b) == 2
    starts = [pd.Timestamp(a, tz="UTC").timestamp() for a, _ in RUNS]
    assert [x["to"] for x in b] == pytest.approx(starts[1:])
    assert b[0]["from"] == pytest.approx(starts[0] + 719 * 10)
    kept = 2160 * 10 - 20  # the three runs' 10 s samples, less the two steps over a gap
    assert b[0]["w"] == b[1]["w"] == pytest.approx(0.02 * kept)
    # two 20-minute runs 6 h apart, three weeks after a 2-h run: the 6 h are 1 % of the
    # calendar span but most of what is left once the three weeks are a break
    one = [
        pd.date_range(a, periods=k, freq="10s", tz="UTC")
        for a, k in (
            ("2026-02-01 08:00", 720),
            ("2026-02-22 10:00", 120),
            ("2026-02-22 16:00", 120),
        )
    ]
    nested = time_breaks(one[0].append(one[1]).append(one[2]))
    assert [pd.Timestamp(x["to"], unit="s", tz="UTC") for x in nested] == [one[1][0], one[2][0]]
    # the levels cut the drawn axis: the three runs and two breaks, not the ten days
    y = np.arange(len(runs), dtype=float)
    lv = time_levels(runs, y, y, y, overview=200, detail=2000, breaks=b)
    assert lv[0]["n"] == 200 and lv[0]["w"] * 200 == pytest.approx(kept + 2 * b[0]["w"])
    ext = _f32(lv[-1]["y"])
    assert np.nanmin(ext) == 0 and np.nanmax(ext) == len(runs) - 1  # every sample inside
    # each run's buckets hold its own samples only, and the breaks' buckets none
    t = np.array([x["at"] for x in b]) - lv[-1]["x0"]
    fin = np.isfinite(ext.reshape(-1, 2)[:, 0])
    inside = (np.arange(lv[-1]["n"]) + 0.5) * lv[-1]["w"]
    for at in t:
        gap = (inside > at + lv[-1]["w"]) & (inside < at + b[0]["w"] - lv[-1]["w"])
        assert gap.sum() > 5 and not fin[gap].any()


@needs_chromium
def test_runs_days_apart_share_the_width_with_marked_breaks(tmp_path):
    """Three short runs over ten days: each takes a visible share of the chart, the two
    gaps are marked breaks, and the axis labels carry each run's true date and time."""
    rb, _ = _story(tmp_path, 3, ("CV[k-1]", "P1[k]"))
    f = _runs_frame(7)  # not the training data
    c = compare(rb, f)
    path = write_report(tmp_path / "runs.html", rb, c, None, None, f)
    page = path.read_text("utf-8")
    assert "3 runs far apart in time" in page and "the longest 5 days 7 h" in page
    shot = tmp_path / "runs.png"
    res = _chromium(
        path.as_uri(), tmp_path / "profile-runs", f"--screenshot={shot}", "--window-size=1400,1400"
    )
    assert res.returncode == 0 and shot.exists(), res.stderr[-2000:]
    _render(path, tmp_path)  # no script error at the default size
    res = _chromium(path.as_uri(), tmp_path / "p-wide", "--dump-dom", "--window-size=1400,1400")
    el = re.search(r'<div id="chart-y"[^>]*>', res.stdout).group(0)
    attr = dict(re.findall(r'data-(\w+)="([^"]*)"', el))
    assert attr["breaks"] == "2", el
    runs = [tuple(map(int, r.split(":"))) for r in attr["runs"].split()]
    width = runs[-1][1] - runs[0][0]
    shares = [(b - a) / width for a, b in runs]
    # shares follow the runs' lengths (720 : 540 : 900 samples) less the two ~2 % breaks
    assert shares == pytest.approx([0.32, 0.24, 0.40], abs=0.02), shares
    ticks = attr["ticks"].split("|")
    assert len(ticks) >= 6, ticks
    # every label with a date is a true time inside a run, and every run has one
    dated = [pd.Timestamp(f"{t.split()[1]} {t.split()[0]}", tz="UTC") for t in ticks if " " in t]
    run = [
        (pd.Timestamp(a, tz="UTC"), pd.Timestamp(a, tz="UTC") + n * pd.Timedelta("10s"))
        for a, n in RUNS
    ]
    assert all(any(a <= t <= b for a, b in run) for t in dated), ticks
    assert all(any(a <= t <= b for t in dated) for a, b in run), ticks
    # the breaks are drawn: a strip of their shade across the time chart
    px = _png_pixels(shot)
    shade = np.all(px == (0xE4, 0xE0, 0xEC), axis=-1)
    cols = np.flatnonzero(shade.sum(axis=0) > 150)
    assert cols.size >= 2 * 10 and np.diff(cols).max() > 200, cols
    # a zoom from the address is in true times: the second run alone, at the detail level
    dom = _render(path, tmp_path, "#zoom=2026-01-05T14:05:00Z/2026-01-05T15:20:00Z")
    el = re.search(r'<div id="chart-y"[^>]*>', dom).group(0)
    attr = dict(re.findall(r'data-(\w+)="([^"]*)"', el))
    assert attr["breaks"] == "0" and "2026-01-05" in attr["ticks"], attr
    assert attr["ticks"].split("|")[0].startswith("14:"), attr["ticks"]


@needs_chromium
def test_a_continuous_record_keeps_its_calendar_axis(report, tmp_path):
    path, _, _ = report
    assert _data(path.read_text("utf-8"))["breaks"] == []
    dom = _render(path, tmp_path)
    el = re.search(r'<div id="chart-y"[^>]*>', dom).group(0)
    assert "data-breaks" not in el and "data-ticks" not in el, el


# a script appended to a copy of the page: moves the pointer over every pixel column from 3 px
# before each break to 3 px after it on the time chart (uPlot's own mousemove handler) and
# records what the readout (legend) says at each
_HOVER = """
<script>
setTimeout(() => {
  const el = document.getElementById("chart-y"), over = el.querySelector(".u-over");
  const box = over.getBoundingClientRect(), out = [];
  const runs = el.dataset.runs.split(" ").map((s) => s.split(":").map(Number));
  for (let i = 0; i + 1 < runs.length; i++) {
    for (let x = runs[i][1] - 3; x <= runs[i + 1][0] + 3; x++) {
      if (x < 0 || x > box.width) continue;
      const at = { clientX: box.left + x, clientY: box.top + 20 };
      over.dispatchEvent(new MouseEvent("mousemove", at));
      const cells = [...el.querySelectorAll(".u-legend .u-series .u-value")];
      out.push(cells.map((c) => c.textContent).join("|"));
    }
  }
  document.body.dataset.hover = out.join("~");
}, 300);
</script>
"""


@needs_chromium
@pytest.mark.parametrize("fragment", ["", "#zoom=2026-01-05T15:10:00Z/2026-01-10T22:20:00Z"])
def test_the_readout_over_a_break_names_the_gap_not_a_value(tmp_path, fragment):
    """Pointer over a break (the whole range, and zoomed to a break): the readout names the
    gap and shows no value; wherever it shows values, its time is a true time inside a run
    (before, a column centred inside the break gave the run's edge value beside the gap's
    name)."""
    rb, _ = _story(tmp_path, 3, ("CV[k-1]", "P1[k]"))
    f = _runs_frame(9)
    c = compare(rb, f)
    path = write_report(tmp_path / "runs.html", rb, c, None, None, f)
    probe = tmp_path / "hover.html"
    probe.write_text(path.read_text("utf-8").replace("</body>", _HOVER + "</body>"), "utf-8")
    res = _chromium(
        probe.as_uri() + fragment, tmp_path / "p-hover", "--dump-dom", "--window-size=1400,1400"
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert 'data-rendered="ok"' in res.stdout
    rows = [
        r.split("|") for r in re.search(r'data-hover="([^"]*)"', res.stdout).group(1).split("~")
    ]
    assert len(rows) >= 20, rows
    run = [
        (pd.Timestamp(a, tz="UTC"), pd.Timestamp(a, tz="UTC") + n * pd.Timedelta("10s"))
        for a, n in RUNS
    ]
    gaps = values = 0
    for when, *vals in rows:
        assert len(vals) == 4, vals
        if when.startswith("gap of "):
            gaps += 1
            assert all(v == "—" for v in vals), (when, vals)
            continue
        shown = [v for v in vals if v != "—"]
        values += bool(shown)
        if shown:
            t = pd.Timestamp(when, tz="UTC")
            assert any(a <= t <= b for a, b in run), (when, vals)
            assert all(0 <= float(v) <= 40 for v in shown), vals  # a flow in its span, t/h
    assert gaps >= 10 and values >= 4, rows


# ------------------------------------------------------------------ the baseline beside the claim
@needs_chromium
def test_the_page_shows_hist_gradient_boosting_beside_the_held_out_error(tmp_path):
    pytest.importorskip("sklearn")
    rb, f = _story(tmp_path, 3, ("CV[k-1]",))
    c = compare(rb, f, baseline=True)
    e = explain(rb, f, tag_info=TAG_INFO, max_lag=2, baseline=True)
    b = e.baseline
    assert b["rows"]["held_out"] == int(np.isfinite(f["F"][e.validation_from :]).sum())
    dom = _render(write_report(tmp_path / "r.html", rb, c, e, None), tmp_path)
    held = re.search(r'<div class="k">held-out RMSE</div><div class="v">([^<]*)</div>', dom)
    hgb = re.search(
        r'title="([^"]*)"><div class="k">HistGradientBoosting held-out RMSE</div>'
        r'<div class="v">([^<]*)</div>',
        dom,
    )
    assert held and hgb, "no held-out or baseline card"
    assert held.group(1) == f"{e.baseline_rmse_pct:.2f} %"
    assert hgb.group(2) == f"{b['rmse_pct']:.2f} %"
    assert f"scored on the same {b['rows']['held_out']:,} held-out rows" in html.unescape(
        hgb.group(1)
    )
    assert "early stopping off" in html.unescape(hgb.group(1))
    assert "HistGradientBoosting on the model's inputs" in dom  # beside the candidates
    # without --no-baseline's opposite, none of it
    plain = write_report(tmp_path / "p.html", rb, compare(rb, f), explain(rb, f, max_lag=2), None)
    assert "HistGradientBoosting" not in plain.read_text("utf-8")


@needs_chromium
def test_no_residual_chart_when_no_candidate_cuts_the_error(tmp_path):
    """The i34-qa2 pass: after the last step explain's best effect took the held-out error
    from 0.87 to 0.86 % and the page still plotted the residual against it under "the effect
    diag explain ranks first", as if an effect were missing. When no candidate cuts the error
    below CUTS × the model's (what explain calls "would cut"), the page says so instead."""
    from diag_plugin.workbench.explain import CUTS, Candidate, Explanation

    rb, f = _story(tmp_path, 2, ("CV[k-1]", "P1[k]"))
    c = compare(rb, f)
    base = 0.87

    def cand(spec, rmse):
        return Candidate(spec, "dynamics", f"adding {spec}", rmse, 1.0, f"add-input {spec}")

    barely = Explanation("valve", base, 1.0, [cand("CV[k-2]", 0.99 * base), cand("F[k-1]", 2.0)])
    path = write_report(tmp_path / "none.html", rb, c, barely, _experiments(), f)
    s = _data(path.read_text("utf-8"))["scatter"]
    assert s["none_cuts"] and "x" not in s, s
    assert f"{100 * (1 - CUTS):.0f} %" in s["note"] and f"{0.99 * base:.2f} %" in s["note"]
    dom = _render(path, tmp_path)
    assert 'id="scatter-none"' in dom and 'id="chart-s"' not in dom
    # one candidate that cuts: the chart is drawn against it, as before
    cuts = Explanation("valve", base, 1.0, [cand("CV[k-2]", 0.9 * CUTS * base)])
    path = write_report(tmp_path / "cuts.html", rb, c, cuts, _experiments(), f)
    s = _data(path.read_text("utf-8"))["scatter"]
    assert s["spec"] == "CV[k-2]" and not s.get("none_cuts")
    _check_scatter(s, c)
    assert 'id="chart-s"' in _render(path, tmp_path)


# ------------------------------------------------- a held-out block at one operating point
@needs_chromium
def test_the_page_warns_when_the_held_out_block_sees_one_operating_point(tmp_path):
    """Issue 34: train and compare warn when the held-out samples see an input at one
    operating point (:mod:`diag_plugin.training.heldout`); the page put it, if at all, as a
    clause of the scope sentence. It is now a warning of its own beside the held-out card,
    for explain's cut (the card's block, also in explain's JSON) as for train's; none when
    the input moves in the held-out block."""
    from test_workbench_core import INFO, trained_1s, valve_1s

    rng = np.random.default_rng(29)
    levels = np.sort(rng.uniform(15, 90, 3))
    f = valve_1s(29, 640, holds=(216, 222), levels=levels)  # the last 20 %: one opening
    (tmp_path / "a").mkdir(), (tmp_path / "b").mkdir()
    rb, _ = trained_1s(tmp_path / "a", f, ["CV[k]"])
    e = explain(rb, f, tag_info=INFO)
    narrow = e.as_dict()["heldout_narrow"]
    held = f["CV"][e.validation_from :]
    assert [n["input"] for n in narrow] == ["CV[k]"], narrow
    assert narrow[0]["heldout"] == pytest.approx([held.min(), held.max()])
    dom = _render(write_report(tmp_path / "r.html", rb, compare(rb, f), e, None, f), tmp_path)
    warns = re.findall(r'<p class="warn heldout-narrow">([^<]*)</p>', dom)
    assert len(warns) == 1, warns  # explain's cut and train's block are the same rows here
    text = html.unescape(warns[0])
    assert "CV[k] at one operating point" in text and "the held-out RMSE above" in text
    assert f"{held.min():.4g} … {held.max():.4g}" in text
    scope = re.search(r'<p class="scope">([^<]*)</p>', dom).group(1)
    assert "operating point" not in scope  # said once, as a warning
    # the opening moved every few minutes: no warning
    g = valve_1s(31, 18_000)
    rb2, _ = trained_1s(tmp_path / "b", g, ["CV[k]"])
    e2 = explain(rb2, g, tag_info=INFO)
    assert e2.heldout_narrow == []
    page = write_report(tmp_path / "q.html", rb2, compare(rb2, g), e2, None, g)
    assert "heldout-narrow" not in _render(page, tmp_path)
