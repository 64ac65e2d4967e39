/* diag report page: charts from the embedded data (see diag_plugin/workbench/report.py). */
(function () {
  "use strict";

  // ---- errors are shown on the page and mark it, so a headless test can read them
  const errors = [];
  const errBox = document.getElementById("errors");
  function report(msg) {
    errors.push(String(msg));
    if (errBox) {
      errBox.hidden = false;
      errBox.textContent = "Errors while drawing this page:\n" + errors.join("\n");
    }
    document.body.dataset.rendered = "error";
  }
  window.addEventListener("error", (ev) =>
    report("error: " + ev.message + " (" + ev.filename + ":" + ev.lineno + ")"));
  window.addEventListener("unhandledrejection", (ev) => report("unhandled rejection: " + ev.reason));
  // the page must need nothing from outside: anything it tries to load is a bug
  document.addEventListener("securitypolicyviolation", (ev) =>
    report("blocked by the page's Content-Security-Policy: " + ev.blockedURI));
  const consoleError = console.error.bind(console);
  console.error = function (...args) {
    report("console.error: " + args.map(String).join(" "));
    consoleError(...args);
  };
  function guard(name, fn) {
    try {
      fn();
    } catch (err) {
      report(name + ": " + (err && err.stack ? err.stack : err));
    }
  }

  const D = JSON.parse(document.getElementById("report-data").textContent);
  const UTC = (ts) => uPlot.tzDate(new Date(ts * 1e3), "Etc/UTC");
  const charts = [];

  function fmt(v, d) {
    return v == null || !isFinite(v) ? "—" : Number(v).toFixed(d === undefined ? 3 : d);
  }
  function short(v) {
    if (v == null) return "";
    const a = Math.abs(v);
    if (a >= 1000 || a === 0) return String(Math.round(v));
    return String(+v.toPrecision(3));
  }
  function widthOf(el) {
    return Math.max(320, Math.floor(el.getBoundingClientRect().width) || 1200);
  }
  function decode(b64) {
    const bin = atob(b64);
    const u8 = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) u8[i] = bin.charCodeAt(i);
    return new Float32Array(u8.buffer);
  }
  const nn = (v) => (Number.isNaN(v) ? null : v);

  // ---- measured vs model and the residual trend, two resolution levels
  // a dashed line at y = 0 (a uPlot draw hook), where zero is in view
  function zeroLine(u) {
    const y = u.valToPos(0, "y", true);
    if (y < u.bbox.top || y > u.bbox.top + u.bbox.height) return;
    const ctx = u.ctx;
    ctx.save();
    ctx.strokeStyle = "#555";
    ctx.setLineDash([4, 4]);
    ctx.lineWidth = 1;
    ctx.beginPath();
    ctx.moveTo(u.bbox.left, y);
    ctx.lineTo(u.bbox.left + u.bbox.width, y);
    ctx.stroke();
    ctx.restore();
  }

  function timeCharts() {
    const elY = document.getElementById("chart-y");
    const elR = document.getElementById("chart-r");
    if (!elY || !D.levels.length) return;
    const L = D.levels.map((l) => ({
      x0: l.x0, w: l.w, n: l.n, per: l.per_bucket,
      y: decode(l.y), yhat: decode(l.yhat), r: decode(l.r), rmean: decode(l.rmean),
    }));
    const full = [L[0].x0, L[0].x0 + L[0].n * L[0].w];
    const finest = L[L.length - 1];
    const minSpan = Math.max(finest.w * 8, 1);

    // ---- short runs far apart: the chart's x axis is the drawn time, on which each long
    // gap is a break b.w s wide at b.at (report.py: time_breaks); labels, readout and the
    // address give true times. Without breaks the drawn time is the true time.
    const B = D.breaks || [];
    function toTrue(x) {
      let cut = 0;
      for (const b of B) {
        if (x <= b.at) break;
        if (x < b.at + b.w) return b.from + ((x - b.at) / b.w) * (b.to - b.from);
        cut += b.to - b.from - b.w;
      }
      return x + cut;
    }
    function toAxis(t) {
      let cut = 0;
      for (const b of B) {
        if (t <= b.from) break;
        if (t < b.to) return b.at + ((t - b.from) / (b.to - b.from)) * b.w;
        cut += b.to - b.from - b.w;
      }
      return t - cut;
    }
    const runs = [];
    for (let i = 0, a = full[0]; i <= B.length; i++) {
      const b = B[i];
      runs.push([a, b ? b.at : full[1]]);
      if (b) a = b.at + b.w;
    }
    const iso = (t) => new Date(t * 1e3).toISOString();
    const stamp = (t) => iso(t).slice(0, 19).replace("T", " ");
    function lasting(s) {
      // a day or more in whole hours, less in whole minutes (as report.py's _lasting)
      if (s >= 86400) {
        const hours = Math.round(s / 3600);
        return Math.floor(hours / 24) + " d " + (hours % 24) + " h";
      }
      const mins = Math.round(s / 60), h = Math.floor(mins / 60), m = mins % 60;
      return h ? h + " h " + m + " min" : m + " min";
    }
    // where a break is, on the drawn axis: the break x lies in (-1: none), and the run (0 ..
    // B.length) a point outside every break belongs to
    function breakAt(x) {
      for (let k = 0; k < B.length; k++) if (x > B[k].at && x < B[k].at + B[k].w) return k;
      return -1;
    }
    function runOf(x) {
      let k = 0;
      while (k < B.length && x >= B[k].at + B[k].w) k++;
      return k;
    }
    // the columns drawn now (slice: out.gap) that hold no value of one run: a point inside a
    // break (its bucket reaches into the gap) or points of runs either side of one
    let gapCols = null, runCols = null;
    const inGap = (idx) => idx != null && gapCols !== null && gapCols[idx] === 1;
    function readout(u, x, si, idx) {
      if (x == null) return "—";
      let k = breakAt(x);
      const r = idx != null && runCols !== null ? runCols[idx] : -1;
      if (k >= 0 && !inGap(idx) && r >= 0) {
        // a column centred just inside a break whose values are all of the run beside it:
        // the time of that run's end (or start)
        return stamp(toTrue(r <= k ? B[k].at : B[k].at + B[k].w));
      }
      if (k < 0 && inGap(idx)) {
        // a column over a break narrower than itself: the break nearest its centre
        let best = Infinity;
        B.forEach((b, j) => {
          const d = Math.abs(b.at + b.w / 2 - x);
          if (d < best) [best, k] = [d, j];
        });
      }
      if (k >= 0) {
        const b = B[k];
        return "gap of " + lasting(b.to - b.from) + ": " + stamp(b.from) + " to " + stamp(b.to);
      }
      return stamp(toTrue(x));
    }
    // a value's readout: none over a gap, where the time readout names the gap instead
    const shown = (d) => (u, v, si, idx) => (inGap(idx) ? "—" : fmt(v, d));
    // per run round true times, at most one label per ~90 px, none within 70 px of the run's
    // end (the next run's first label is there); a run too narrow for one gets its start
    const STEPS = [1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600,
      43200, 86400, 172800, 604800];
    const tickLabels = new WeakMap();
    function brokenTicks(u, axis, min, max) {
      // before the first layout the plot's box is empty: the chart's width less the y axis
      const px = u.bbox.width ? plotWidth(u) : Math.max(100, u.width - 80);
      const perPx = (max - min) / px;
      const out = [], labels = [];
      for (const [r0, r1] of runs) {
        const lo = Math.max(r0, min), hi = Math.min(r1, max);
        if (!(hi >= lo)) continue;
        const t0 = toTrue(lo), t1 = toTrue(hi);
        const want = Math.max(1, Math.floor((hi - lo) / perPx / 90));
        const step = STEPS.find((v) => v >= (t1 - t0) / want) || 604800;
        let prevDate = null;
        const add = (x, t) => {
          const s = iso(t), date = s.slice(0, 10);
          const time = step >= 86400 ? "" : s.slice(11, step < 60 ? 19 : 16);
          out.push(x);
          labels.push(!time ? date : date !== prevDate ? time + "\n" + date : time);
          prevDate = date;
        };
        for (let t = Math.ceil(t0 / step) * step; t <= t1; t += step) {
          const x = toAxis(t);
          if (out.length && prevDate !== null && x > hi - 70 * perPx) break;
          add(x, t);
        }
        if (prevDate === null) add(lo, t0);
      }
      tickLabels.set(u, labels);
      return out;
    }
    const xAxis = () => (B.length ? {
      splits: brokenTicks,
      values: (u, splits) => tickLabels.get(u) || splits.map((v) => stamp(toTrue(v))),
      size: 54,
    } : {});
    // a break: a shaded strip with the slashes of a broken axis and the gap's length; on the
    // time chart its element records the breaks, runs (px) and labels drawn, for a reader
    const breakMarks = (el) => (u) => {
      const ctx = u.ctx, r = uPlot.pxRatio, top = u.bbox.top, h = u.bbox.height;
      const left = u.bbox.left, right = left + u.bbox.width;
      let shown = 0;
      ctx.save();
      for (const b of B) {
        const x0 = Math.round(u.valToPos(b.at, "x", true));
        const x1 = Math.round(u.valToPos(b.at + b.w, "x", true));
        if (x1 < left || x0 > right) continue;
        shown++;
        ctx.fillStyle = "#e4e0ec";
        ctx.fillRect(x0, top, Math.max(2 * r, x1 - x0), h);
        ctx.strokeStyle = "#5b5570";
        ctx.lineWidth = 1.5 * r;
        ctx.beginPath();
        for (const x of [x0, x1]) {
          for (const y of [top, top + h]) {
            ctx.moveTo(x - 4 * r, y + 6 * r);
            ctx.lineTo(x + 4 * r, y - 6 * r);
          }
        }
        ctx.stroke();
        if (x1 - x0 >= 12 * r) {
          ctx.save();
          ctx.fillStyle = "#3d3850";
          ctx.font = Math.round(10 * r) + "px system-ui, sans-serif";
          ctx.textAlign = "center";
          ctx.translate((x0 + x1) / 2 + 3.5 * r, top + h / 2);
          ctx.rotate(-Math.PI / 2);
          ctx.fillText("gap " + lasting(b.to - b.from), 0, 0);
          ctx.restore();
        }
      }
      ctx.restore();
      if (el) {
        const pos = (v) => Math.round(u.valToPos(v, "x"));
        el.dataset.breaks = String(shown);
        el.dataset.runs = runs.map(([a, b]) => pos(a) + ":" + pos(b)).join(" ");
        el.dataset.ticks = (tickLabels.get(u) || []).map((s) => s.replace("\n", " ")).join("|");
      }
    };

    function pick(span) {
      for (const l of L) if (span / l.w >= 900) return l;
      return finest;
    }
    // the visible buckets of level l between a and b, as at most `px` columns (one per pixel
    // of the plot): per column the lowest and highest value of each series (an envelope that
    // holds every sample), and the mean of the residual's bucket means; with fewer buckets
    // than pixels, each bucket's two extremes in their order (a line through the samples)
    function slice(l, a, b, px) {
      const i0 = Math.max(0, Math.floor((a - l.x0) / l.w) - 1);
      const i1 = Math.min(l.n, Math.ceil((b - l.x0) / l.w) + 1);
      const nb = Math.max(0, i1 - i0);
      const cols = 2 * nb <= px ? 2 * nb : Math.max(1, Math.floor(px));
      const perCol = 2 * nb <= px;
      const x = new Float64Array(cols);
      const out = {};
      for (const k of ["ylo", "yhi", "hlo", "hhi", "rlo", "rhi", "rm"]) out[k] = new Array(cols).fill(null);
      const rsum = new Float64Array(cols), rcnt = new Float64Array(cols);
      // per column the run of its points (-1: none yet); 1 in gap where it holds a point
      // inside a break or points of two runs (its band would join values across the gap)
      const run = new Int32Array(cols).fill(-1), gap = new Uint8Array(cols);
      const cw = (b - a) / cols;
      const lower = (arr, j, v) => { if (v !== null && (arr[j] === null || v < arr[j])) arr[j] = v; };
      const upper = (arr, j, v) => { if (v !== null && (arr[j] === null || v > arr[j])) arr[j] = v; };
      for (let j = 0; j < cols; j++) x[j] = perCol ? 0 : a + (j + 0.5) * cw;
      for (let i = i0, c = 0; i < i1; i++) {
        for (let h = 0; h < 2; h++) {
          // a bucket's two extremes sit at its first and third quarter
          const t = l.x0 + (i + (h ? 0.75 : 0.25)) * l.w;
          let j;
          if (perCol) {
            j = c++;
            x[j] = t;
          } else {
            j = Math.floor((t - a) / cw);
            if (j < 0 || j >= cols) continue;
          }
          const k = 2 * i + h;
          const y = nn(l.y[k]), yh = nn(l.yhat[k]), r = nn(l.r[k]);
          if (B.length && (y !== null || yh !== null || r !== null)) {
            const rk = breakAt(t) >= 0 ? -2 : runOf(t);
            if (rk === -2 || (run[j] >= 0 && run[j] !== rk)) gap[j] = 1;
            run[j] = rk;
          }
          lower(out.ylo, j, y); upper(out.yhi, j, y);
          lower(out.hlo, j, yh); upper(out.hhi, j, yh);
          lower(out.rlo, j, r); upper(out.rhi, j, r);
          const m = nn(l.rmean[i]);
          if (m !== null) {
            rsum[j] += m;
            rcnt[j] += 1;
          }
        }
      }
      for (let j = 0; j < cols; j++) if (rcnt[j] > 0) out.rm[j] = rsum[j] / rcnt[j];
      out.x = x;
      out.perCol = perCol;
      out.gap = gap;
      out.run = run;
      return out;
    }
    const plotWidth = (u) => Math.max(100, Math.round(u.bbox.width / uPlot.pxRatio));
    const unit = D.output.unit ? " [" + D.output.unit + "]" : "";
    const cursor = () => ({
      sync: { key: "time", setSeries: true },
      drag: { x: true, y: false, setScale: false },
      bind: {
        dblclick: () => () => {
          zoomTo(full[0], full[1]);
          return null;
        },
      },
    });
    const zoomHook = {
      setSelect: [
        (u) => {
          if (u.select.width > 3) {
            const a = u.posToVal(u.select.left, "x");
            const b = u.posToVal(u.select.left + u.select.width, "x");
            u.setSelect({ left: 0, top: 0, width: 0, height: 0 }, false);
            zoomTo(a, b);
          }
        },
      ],
    };
    const common = (el, height, draw, mark) => {
      const draws = [draw, B.length ? breakMarks(mark) : null].filter(Boolean);
      return {
        width: widthOf(el),
        height,
        tzDate: UTC,
        cursor: cursor(),
        scales: { x: { time: !B.length } },
        hooks: Object.assign({}, zoomHook, draws.length ? { draw: draws } : {}),
      };
    };
    const timeSeries = () => (B.length ? { label: "time (UTC)", value: readout } : { label: "time (UTC)" });
    const s0 = slice(L[0], full[0], full[1], widthOf(elY) - 80);
    gapCols = s0.gap;
    runCols = s0.run;
    const band = (label, colour, value) => ({ label, stroke: colour, width: 1, value });
    const cy = new uPlot(
      Object.assign(common(elY, 330, null, elY), {
        series: [
          timeSeries(),
          band("measured " + D.output.spec + unit + ", highest", "#1f5fa8", shown()),
          band("measured, lowest", "#1f5fa8", shown()),
          band("model, highest", "#e07b00", shown()),
          band("model, lowest", "#e07b00", shown()),
        ],
        bands: [
          { series: [1, 2], fill: "rgba(31,95,168,0.28)" },
          { series: [3, 4], fill: "rgba(224,123,0,0.20)" },
        ],
        axes: [xAxis(), { label: D.output.spec + unit, size: 60 }],
      }),
      [s0.x, s0.yhi, s0.ylo, s0.hhi, s0.hlo],
      elY,
    );
    const cr = new uPlot(
      Object.assign(common(elR, 230, zeroLine), {
        series: [
          timeSeries(),
          band("residual, highest [% of span]", "rgba(198,40,40,0.75)", shown()),
          band("residual, lowest", "rgba(198,40,40,0.75)", shown()),
          { label: "average", stroke: "#4a148c", width: 1.5, value: shown() },
        ],
        bands: [{ series: [1, 2], fill: "rgba(198,40,40,0.22)" }],
        axes: [xAxis(), { label: "% of span", size: 60 }],
      }),
      [s0.x, s0.rhi, s0.rlo, s0.rm],
      elR,
    );
    charts.push(cy, cr);
    const resEl = document.getElementById("resolution");

    function zoomTo(a, b) {
      a = Math.max(a, full[0]);
      b = Math.min(b, full[1]);
      if (!(b > a)) return;
      if (b - a < minSpan) {
        const c = (a + b) / 2;
        a = Math.max(full[0], c - minSpan / 2);
        b = Math.min(full[1], c + minSpan / 2);
      }
      const l = pick(b - a);
      const px = plotWidth(cy);
      const s = slice(l, a, b, px);
      gapCols = s.gap;
      runCols = s.run;
      cy.batch(() => {
        cy.setData([s.x, s.yhi, s.ylo, s.hhi, s.hlo], false);
        cy.setScale("x", { min: a, max: b });
      });
      cr.batch(() => {
        cr.setData([s.x, s.rhi, s.rlo, s.rm], false);
        cr.setScale("x", { min: a, max: b });
      });
      view = [a, b];
      const li = L.indexOf(l);
      try {
        const at = (v) => iso(toTrue(v)).replace(".000Z", "Z");
        const whole = a <= full[0] && b >= full[1];
        history.replaceState(null, "", whole ? location.pathname + location.search :
          "#zoom=" + at(a) + "/" + at(b));
      } catch (err) {
        // a page opened from some viewers cannot change its address: zoom still works
      }
      if (resEl) {
        resEl.dataset.level = String(li);
        resEl.dataset.points = String(s.x.length);
        resEl.dataset.envelope = s.perCol ? "0" : "1";
        const samples = ((b - a) / l.w) * Math.max(1, l.per);
        resEl.textContent = s.perCol
          ? (l.per <= 1 ? "Showing every sample." :
            "Each step holds ~" + Math.round(l.per).toLocaleString("en") + " samples.")
          : "Each pixel column holds ~" +
            Math.max(1, Math.round(samples / s.x.length)).toLocaleString("en") +
            " samples: the band runs from the lowest to the highest.";
      }
    }
    let view = full.slice();
    window.diagZoom = zoomTo;
    // a new width re-cuts the pixel columns
    charts.resized = () => zoomTo(view[0], view[1]);
    const m = /zoom=([^/&]+)\/([^&]+)/.exec(decodeURIComponent(location.hash));
    const a0 = m ? toAxis(Date.parse(m[1]) / 1e3) : NaN, b0 = m ? toAxis(Date.parse(m[2]) / 1e3) : NaN;
    if (b0 > a0) zoomTo(a0, b0);
    else zoomTo(full[0], full[1]);
    const reset = document.getElementById("zoom-reset");
    if (reset) reset.addEventListener("click", () => zoomTo(full[0], full[1]));
    for (const tr of document.querySelectorAll("tr.zoom")) {
      tr.addEventListener("click", () => {
        const a = toAxis(Date.parse(tr.dataset.start) / 1e3);
        const b = toAxis(Date.parse(tr.dataset.end) / 1e3);
        const pad = (b - a) * 0.25;
        zoomTo(a - pad, b + pad);
        elY.scrollIntoView({ behavior: "smooth", block: "start" });
      });
    }
  }

  // ---- residual against the suggested tag: dots and the average along the tag
  function scatter() {
    const el = document.getElementById("chart-s");
    const S = D.scatter;
    if (!el || !S) return;
    const x = Array.from(decode(S.x)), r = Array.from(decode(S.r));
    // the bins' averages as a step line over the dots' x (each dot gets its bin's average)
    const avg = new Array(x.length).fill(null);
    for (let i = 0, k = 0; i < x.length; i++) {
      while (k + 1 < S.bin_x.length && Math.abs(S.bin_x[k + 1] - x[i]) < Math.abs(S.bin_x[k] - x[i])) k++;
      avg[i] = S.bin_mean[k];
    }
    const u = new uPlot(
      {
        width: widthOf(el),
        height: 300,
        scales: { x: { time: false } },
        cursor: { drag: { x: true, y: false } },
        series: [
          { label: S.spec, value: (u, v) => fmt(v) },
          { label: "residual [% of span]", stroke: "rgba(31,95,168,0.55)",
            fill: "rgba(31,95,168,0.55)", paths: () => null,
            points: { show: true, size: 3, width: 0, fill: "rgba(31,95,168,0.45)" },
            value: (u, v) => fmt(v, 2) },
          { label: "average along " + S.spec, stroke: "#c62828", width: 2.5,
            points: { show: false }, value: (u, v) => fmt(v, 2) },
        ],
        axes: [{ label: S.spec }, { label: "residual [% of span]", size: 70 }],
        hooks: {
          draw: [zeroLine],
        },
      },
      [x, r, avg],
      el,
    );
    charts.push(u);
  }

  // ---- residual histogram
  function histogram() {
    const el = document.getElementById("chart-h");
    const h = D.hist;
    if (!el || !h.counts.length) return;
    const x = [];
    for (let i = 0; i < h.counts.length; i++) x.push((h.edges[i] + h.edges[i + 1]) / 2);
    const lo = h.edges[0], hi = h.edges[h.edges.length - 1];
    const u = new uPlot(
      {
        width: widthOf(el),
        height: 260,
        scales: { x: { time: false, range: () => [lo, hi] }, y: { range: (u, a, b) => [0, b * 1.05] } },
        cursor: { drag: { x: false, y: false } },
        series: [
          { label: "residual [% of span]", value: (u, v) => fmt(v) },
          { label: "samples", stroke: "#1f5fa8", fill: "rgba(31,95,168,0.35)", width: 1,
            paths: uPlot.paths.bars({ size: [1, Infinity], gap: 1 }), points: { show: false } },
          { label: "normal, same mean and sd", stroke: "#e07b00", width: 1.5, dash: [5, 4],
            points: { show: false }, value: (u, v) => fmt(v, 0) },
        ],
        axes: [{ label: "residual [% of span]" }, { label: "samples", size: 70 }],
      },
      [x, h.counts, h.normal],
      el,
    );
    charts.push(u);
  }

  // ---- error over the input space
  const VIRIDIS = [
    [68, 1, 84], [72, 40, 120], [62, 74, 137], [49, 104, 142], [38, 130, 142],
    [31, 158, 137], [53, 183, 121], [110, 206, 88], [181, 222, 43], [253, 231, 37],
  ];
  function colour(t) {
    t = Math.min(1, Math.max(0, t)) * (VIRIDIS.length - 1);
    const i = Math.min(VIRIDIS.length - 2, Math.floor(t)), f = t - i;
    const a = VIRIDIS[i], b = VIRIDIS[i + 1];
    return "rgb(" + [0, 1, 2].map((k) => Math.round(a[k] + f * (b[k] - a[k]))).join(",") + ")";
  }
  function hatch(ctx, x, y, w, h, fill) {
    ctx.save();
    if (fill) {
      ctx.fillStyle = fill;
      ctx.fillRect(x, y, w, h);
    }
    ctx.beginPath();
    ctx.rect(x, y, w, h);
    ctx.clip();
    ctx.strokeStyle = "#c62828";
    ctx.lineWidth = 1;
    ctx.beginPath();
    for (let k = -h; k < w; k += 5) {
      ctx.moveTo(x + k, y + h);
      ctx.lineTo(x + k + h, y);
    }
    ctx.stroke();
    ctx.restore();
  }

  function heatmap() {
    const box = document.getElementById("heatmap");
    const M = D.map;
    if (!box || M.dims !== 2) return;
    const [ax, ay] = M.axes;
    const canvas = box.querySelector("canvas"), tip = box.querySelector(".tip");
    // show the sets that hold samples, one set of margin around them
    let i0 = ax.sets, i1 = -1, j0 = ay.sets, j1 = -1;
    for (const c of M.cells) {
      i0 = Math.min(i0, c.i[0]); i1 = Math.max(i1, c.i[0]);
      j0 = Math.min(j0, c.i[1]); j1 = Math.max(j1, c.i[1]);
    }
    if (i1 < 0) return;
    i0 = Math.max(0, i0 - 1); i1 = Math.min(ax.sets - 1, i1 + 1);
    j0 = Math.max(0, j0 - 1); j1 = Math.min(ay.sets - 1, j1 + 1);
    const nx = i1 - i0 + 1, ny = j1 - j0 + 1;
    const left = 78, bottom = 54, top = 8, right = 12;
    const avail = Math.min(widthOf(box), 1000) - left - right;
    const cw = Math.max(6, Math.min(34, Math.floor(avail / nx)));
    const ch = Math.max(6, Math.min(26, Math.floor(620 / ny)));
    const W = left + cw * nx + right, H = top + ch * ny + bottom;
    const dpr = window.devicePixelRatio || 1;
    canvas.width = W * dpr;
    canvas.height = H * dpr;
    canvas.style.width = W + "px";
    canvas.style.height = H + "px";
    const ctx = canvas.getContext("2d");
    ctx.scale(dpr, dpr);
    const grid = new Map();
    const vals = [];
    for (const c of M.cells) {
      grid.set(c.i[0] + "," + c.i[1], c);
      if (c.rmse != null && c.count >= 5) vals.push(c.rmse);
    }
    vals.sort((a, b) => a - b);
    const vmax = vals.length ? vals[vals.length - 1] || 1 : 1;
    const X = (i) => left + (i - i0) * cw, Y = (j) => top + (ny - 1 - (j - j0)) * ch;
    ctx.fillStyle = "#f5f7fa";
    ctx.fillRect(left, top, cw * nx, ch * ny);
    for (const c of M.cells) {
      const x = X(c.i[0]), y = Y(c.i[1]);
      if (c.rmse == null) hatch(ctx, x, y, cw, ch, "#fde0e0");
      else {
        ctx.fillStyle = colour(c.rmse / vmax);
        ctx.fillRect(x, y, cw, ch);
        if (!c.rule) hatch(ctx, x, y, cw, ch, null);
      }
    }
    ctx.strokeStyle = "rgba(255,255,255,0.7)";
    ctx.lineWidth = 1;
    ctx.beginPath();
    for (let i = 0; i <= nx; i++) {
      ctx.moveTo(left + i * cw + 0.5, top);
      ctx.lineTo(left + i * cw + 0.5, top + ny * ch);
    }
    for (let j = 0; j <= ny; j++) {
      ctx.moveTo(left, top + j * ch + 0.5);
      ctx.lineTo(left + nx * cw, top + j * ch + 0.5);
    }
    ctx.stroke();
    ctx.strokeStyle = "#8a96a3";
    ctx.strokeRect(left + 0.5, top + 0.5, cw * nx, ch * ny);
    // ticks: centre values, thinned so they do not overlap
    ctx.fillStyle = "#1d2430";
    ctx.font = "11px system-ui, sans-serif";
    ctx.textAlign = "center";
    const sx = Math.max(1, Math.ceil(34 / cw)), sy = Math.max(1, Math.ceil(16 / ch));
    for (let i = i0; i <= i1; i += sx) {
      ctx.fillText(short(ax.centres[i]), X(i) + cw / 2, top + ny * ch + 14);
    }
    ctx.textAlign = "right";
    for (let j = j0; j <= j1; j += sy) ctx.fillText(short(ay.centres[j]), left - 6, Y(j) + ch / 2 + 4);
    ctx.textAlign = "center";
    ctx.font = "600 12px system-ui, sans-serif";
    ctx.fillText(ax.spec + (ax.unit ? " [" + ax.unit + "]" : ""), left + (nx * cw) / 2, H - 10);
    ctx.save();
    ctx.translate(16, top + (ny * ch) / 2);
    ctx.rotate(-Math.PI / 2);
    ctx.fillText(ay.spec + (ay.unit ? " [" + ay.unit + "]" : ""), 0, 0);
    ctx.restore();
    // legend
    const leg = box.querySelector(".legend");
    const lc = document.createElement("canvas");
    lc.width = 220;
    lc.height = 12;
    const lx = lc.getContext("2d");
    for (let i = 0; i < 220; i++) {
      lx.fillStyle = colour(i / 219);
      lx.fillRect(i, 0, 1, 12);
    }
    const sw = document.createElement("canvas");
    sw.width = 24;
    sw.height = 12;
    const swc = sw.getContext("2d");
    swc.fillStyle = colour(0.3);
    swc.fillRect(0, 0, 12, 12);
    hatch(swc, 0, 0, 12, 12, null);
    hatch(swc, 12, 0, 12, 12, "#fde0e0");
    const t0 = document.createElement("span"), t1 = document.createElement("span");
    const t2 = document.createElement("span");
    t0.textContent = "RMSE 0 %";
    t1.textContent = fmt(vmax, 2) + " % and above";
    t2.textContent = "no rule in the cell (light red: no model value at all)";
    const t3 = document.createElement("span");
    t3.textContent = "· sets " + ax.labels[i0] + "–" + ax.labels[i1] + " of " + ax.sets + ", " +
      ay.labels[j0] + "–" + ay.labels[j1] + " of " + ay.sets + " (the rest hold no samples)";
    leg.append(t0, lc, t1, sw, t2, t3);
    canvas.addEventListener("mousemove", (ev) => {
      const r = canvas.getBoundingClientRect();
      const px = ev.clientX - r.left, py = ev.clientY - r.top;
      const i = i0 + Math.floor((px - left) / cw), j = j0 + ny - 1 - Math.floor((py - top) / ch);
      if (i < i0 || i > i1 || j < j0 || j > j1) {
        tip.hidden = true;
        return;
      }
      const c = grid.get(i + "," + j);
      const head = ax.labels[i] + " (" + short(ax.centres[i]) + ") × " +
        ay.labels[j] + " (" + short(ay.centres[j]) + ")";
      tip.textContent = c
        ? head + "\n" + c.count.toLocaleString("en") + " samples\nRMSE " + fmt(c.rmse, 2) +
          " %, mean " + fmt(c.mean, 2) + " %" + (c.rule ? "" : "\nno rule: unsupported")
        : head + "\nno samples";
      tip.hidden = false;
      tip.style.left = px + 14 + "px";
      tip.style.top = py + 10 + "px";
    });
    canvas.addEventListener("mouseleave", () => (tip.hidden = true));
  }

  function mapBars() {
    const el = document.getElementById("chart-map");
    const M = D.map;
    if (!el || M.dims !== 1) return;
    const ax = M.axes[0];
    const byI = new Map(M.cells.map((c) => [c.i[0], c]));
    const x = [], rmse = [], mean = [], unsup = [];
    let first = ax.sets, last = -1;
    for (let i = 0; i < ax.sets; i++) {
      const c = byI.get(i);
      x.push(ax.centres[i]);
      rmse.push(c && c.rmse != null ? c.rmse : null);
      mean.push(c && c.mean != null ? c.mean : null);
      unsup.push(c && !c.rule ? 0 : null);
      if (c) {
        first = Math.min(first, i);
        last = Math.max(last, i);
      }
    }
    if (last < 0) return;
    first = Math.max(0, first - 1);
    last = Math.min(ax.sets - 1, last + 1);
    const step = ax.sets > 1 ? ax.centres[1] - ax.centres[0] : 1;
    const lo = ax.centres[first] - step / 2, hi = ax.centres[last] + step / 2;
    const u = new uPlot(
      {
        width: widthOf(el),
        height: 280,
        scales: { x: { time: false, range: () => [lo, hi] } },
        cursor: { drag: { x: false, y: false } },
        series: [
          { label: ax.spec + (ax.unit ? " [" + ax.unit + "]" : ""), value: (u, v) => fmt(v, 3) },
          { label: "RMSE [% of span]", stroke: "#1f5fa8", fill: "rgba(31,95,168,0.35)",
            paths: uPlot.paths.bars({ size: [0.8, 60] }), points: { show: false },
            value: (u, v) => fmt(v, 2) },
          { label: "mean [% of span]", stroke: "#4a148c", width: 1.5, value: (u, v) => fmt(v, 2) },
          { label: "no rule in the set", stroke: "#c62828", width: 0,
            points: { show: true, size: 10, fill: "#c62828" }, paths: () => null,
            value: (u, v) => (v == null ? "" : "no rule") },
        ],
        axes: [{ label: ax.spec + (ax.unit ? " [" + ax.unit + "]" : "") },
          { label: "% of span", size: 60 }],
      },
      [x, rmse, mean, unsup],
      el,
    );
    charts.push(u);
  }

  // ---- experiment history: the error falling version by version
  function experiments() {
    const el = document.getElementById("chart-x");
    const rows = D.experiments;
    if (!el || !rows.length) return;
    const x = rows.map((r, i) => i + 1);
    const rmse = rows.map((r) => r.rmse_pct);
    const mae = rows.map((r) => r.mae_pct);
    const hasMae = mae.some((v) => v != null);
    const n = rows.length;
    const labels = rows.map((r) => {
      const s = r.inputs.join(", ");
      return s.length > 44 ? s.slice(0, 43) + "…" : s;
    });
    const series = [
      { label: "version", value: (u, v) => (v == null ? "" : "v" + rows[v - 1].version) },
      { label: "validation RMSE [% of span]", stroke: "#c62828", width: 2,
        points: { show: true, size: 8, fill: "#c62828" }, value: (u, v) => fmt(v, 2) },
    ];
    const data = [x, rmse];
    if (hasMae) {
      series.push({ label: "validation MAE [% of span]", stroke: "#8a96a3", width: 1.5,
        dash: [5, 4], value: (u, v) => fmt(v, 2) });
      data.push(mae);
    }
    const u = new uPlot(
      {
        width: widthOf(el),
        height: 300,
        padding: [28, 30, 0, 10],
        scales: {
          x: { time: false, range: () => [0.5, n + 0.5] },
          y: { range: (u, a, b) => [0, (b || 1) * 1.25] },
        },
        cursor: { drag: { x: false, y: false } },
        series,
        axes: [
          {
            label: "version (inputs)",
            splits: () => x.filter((v, i) => n <= 24 || i % Math.ceil(n / 24) === 0),
            values: (u, vals) => vals.map((v) => (rows[v - 1] ? "v" + rows[v - 1].version : "")),
          },
          { label: "% of span", size: 60 },
        ],
        hooks: {
          draw: [
            (u) => {
              const ctx = u.ctx;
              ctx.save();
              ctx.fillStyle = "#1d2430";
              ctx.font = Math.round(11 * uPlot.pxRatio) + "px system-ui, sans-serif";
              const rot = n > 6;
              for (let i = 0; i < n; i++) {
                if (rmse[i] == null) continue;
                const px = u.valToPos(x[i], "x", true), py = u.valToPos(rmse[i], "y", true);
                ctx.save();
                ctx.translate(px, py - 10 * uPlot.pxRatio);
                if (rot) ctx.rotate(-Math.PI / 9);
                ctx.textAlign = rot ? "left" : "center";
                ctx.fillText(labels[i] + "  " + fmt(rmse[i], 2) + " %", 0, 0);
                ctx.restore();
              }
              ctx.restore();
            },
          ],
        },
      },
      data,
      el,
    );
    charts.push(u);
  }

  // ---- copy buttons of the candidate commands
  function copyButtons() {
    for (const b of document.querySelectorAll("button.copy")) {
      b.addEventListener("click", () => {
        const code = b.parentElement.querySelector("code");
        const done = () => {
          b.textContent = "copied";
          setTimeout(() => (b.textContent = "copy"), 1500);
        };
        const select = () => {
          const range = document.createRange();
          range.selectNodeContents(code);
          const sel = window.getSelection();
          sel.removeAllRanges();
          sel.addRange(range);
          b.textContent = "selected: Ctrl+C";
        };
        if (navigator.clipboard && navigator.clipboard.writeText) {
          navigator.clipboard.writeText(code.textContent).then(done, select);
        } else select();
      });
    }
  }

  guard("time charts", timeCharts);
  guard("residual against a tag", scatter);
  guard("histogram", histogram);
  guard("heat map", heatmap);
  guard("error map", mapBars);
  guard("experiments", experiments);
  guard("copy buttons", copyButtons);

  let resizing = null;
  window.addEventListener("resize", () => {
    clearTimeout(resizing);
    resizing = setTimeout(() => {
      for (const u of charts) {
        const w = widthOf(u.root.parentElement);
        if (w !== u.width) u.setSize({ width: w, height: u.height });
      }
      if (charts.resized) charts.resized();
    }, 150);
  });

  // uPlot commits its drawing in a microtask: mark the page once that has run
  setTimeout(() => {
    if (!errors.length) document.body.dataset.rendered = "ok";
    document.body.dataset.charts = String(charts.length);
  }, 0);
})();
