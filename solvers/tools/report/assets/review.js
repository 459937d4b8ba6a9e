/* facecap review page: unpacks the page's data block, draws the plots with plotly.js, keeps every curve
   reduced to the min/max envelope of the frames on screen (again after each zoom or pan), keeps the
   time axes of all plots together, and wires the buttons. Sets window.facecapReady when done
   (window.facecapError says what went wrong, if anything). */
(function () {
  "use strict";
  const TYPES = { i2: Int16Array, i4: Int32Array, f8: Float64Array };
  const CONFIG = { responsive: true, displaylogo: false, modeBarButtonsToRemove: ["select2d", "lasso2d"] };
  const CONTEXT_BUCKETS = 150; // outside the zoomed range: enough for the range slider's overview

  function fail(message) {
    window.facecapError = message;
    const box = document.getElementById("facecap-error");
    box.textContent = message;
    box.hidden = false;
  }

  function base64Bytes(text) {
    const bin = atob(text);
    const out = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
    return out;
  }

  async function unpack(text, manifest) {
    const stream = new Blob([base64Bytes(text.trim())]).stream().pipeThrough(new DecompressionStream("deflate"));
    const buffer = await new Response(stream).arrayBuffer();
    const arrays = {};
    for (const e of manifest) {
      const n = e.shape.reduce((a, b) => a * b, 1);
      const raw = new TYPES[e.dtype](buffer, e.offset, n);
      const values = new Float64Array(n);
      for (let i = 0; i < n; i++) values[i] = e.nan !== null && raw[i] === e.nan ? NaN : raw[i] * e.step;
      arrays[e.name] = { values: values, shape: e.shape };
    }
    return arrays;
  }

  function series(arrays, ref) {
    if (typeof ref === "string") return arrays[ref].values;
    const a = arrays[ref[0]], n = a.shape[1];
    return a.values.subarray(ref[1] * n, (ref[1] + 1) * n);
  }

  // The min/max envelope of y[i0:i1] in `buckets` equal runs, in frame order (blob.py's `envelope`).
  function envelope(x, y, i0, i1, buckets, xs, ys) {
    const n = i1 - i0;
    if (n <= 2 * buckets) {
      for (let i = i0; i < i1; i++) { xs.push(x[i]); ys.push(y[i] === y[i] ? y[i] : null); }
      return;
    }
    for (let b = 0; b < buckets; b++) {
      const s = i0 + Math.floor((b * n) / buckets), e = i0 + Math.floor(((b + 1) * n) / buckets);
      let lo = -1, hi = -1;
      for (let i = s; i < e; i++) {
        const v = y[i];
        if (v !== v) continue;
        if (lo < 0 || v < y[lo]) lo = i;
        if (hi < 0 || v > y[hi]) hi = i;
      }
      if (lo < 0) { xs.push(x[s]); ys.push(null); continue; }
      const a = Math.min(lo, hi), c = Math.max(lo, hi);
      xs.push(x[a]); ys.push(y[a]);
      if (c !== a) { xs.push(x[c]); ys.push(y[c]); }
    }
  }

  function bound(x, value, upper) { // first index with x >= value (upper: x > value)
    let lo = 0, hi = x.length;
    while (lo < hi) { const mid = (lo + hi) >> 1; if (upper ? x[mid] <= value : x[mid] < value) lo = mid + 1; else hi = mid; }
    return lo;
  }

  // The curve over the whole take: the frames in `range` (or all) at screen resolution, the rest coarser.
  function reduce(x, y, range, buckets) {
    const xs = [], ys = [];
    if (!range) { envelope(x, y, 0, x.length, buckets, xs, ys); return [xs, ys]; }
    const i0 = Math.max(0, bound(x, range[0], false) - 1), i1 = Math.min(x.length, bound(x, range[1], true) + 1);
    envelope(x, y, 0, i0, CONTEXT_BUCKETS, xs, ys);
    envelope(x, y, i0, i1, buckets, xs, ys);
    envelope(x, y, i1, x.length, CONTEXT_BUCKETS, xs, ys);
    return [xs, ys];
  }

  function buckets(el) {
    const width = (el._fullLayout && el._fullLayout._size && el._fullLayout._size.w) || el.clientWidth || 1000;
    return Math.max(200, Math.min(2000, Math.round(width)));
  }

  function restyle(el, range) {
    const st = el.facecap;
    if (!st.bound.length) return Promise.resolve();
    const n = buckets(el), xs = [], ys = [];
    for (const b of st.bound) { const [x, y] = reduce(b.x, b.y, range, n); xs.push(x); ys.push(y); }
    st.range = range;
    return Plotly.restyle(el, { x: xs, y: ys }, st.bound.map(b => b.index));
  }

  async function draw(fig, arrays) {
    const el = document.getElementById("plot-" + fig.id);
    const data = fig.traces.map(t => Object.assign({}, t.trace));
    const boundTraces = [];
    fig.traces.forEach((t, index) => {
      if (t.y === undefined) return;
      boundTraces.push({ index: index, x: series(arrays, t.x), y: series(arrays, t.y) });
    });
    const n = Math.max(200, Math.min(2000, Math.round(el.clientWidth || 1000)));
    for (const b of boundTraces) { const [x, y] = reduce(b.x, b.y, null, n); data[b.index].x = x; data[b.index].y = y; }
    await Plotly.newPlot(el, data, fig.layout, CONFIG);
    el.facecap = { fig: fig, bound: boundTraces, range: null };
    return el;
  }

  function xRange(ev) { // the new x range of a relayout event: [a, b], null (whole take) or undefined (no change)
    if (ev["xaxis.range[0]"] !== undefined) return [ev["xaxis.range[0]"], ev["xaxis.range[1]"]];
    if (ev["xaxis.range"] !== undefined) return ev["xaxis.range"].slice(0, 2);
    if (ev["xaxis.autorange"]) return null;
    return undefined;
  }

  function linkTime(plots) {
    let following = false;
    for (const el of plots) {
      el.on("plotly_relayout", ev => {
        const range = xRange(ev);
        if (range === undefined) return;
        restyle(el, range);
        if (following) return;
        following = true;
        const update = range ? { "xaxis.range": range } : { "xaxis.autorange": true };
        Promise.all(plots.filter(o => o !== el).map(o => Plotly.relayout(o, update)))
          .finally(() => { following = false; });
      });
    }
  }

  function zoomTo(plots, frame, half) {
    if (plots.length) Plotly.relayout(plots[0], { "xaxis.range": [frame - half, frame + half] });
  }

  function wireButtons(meta, plots) {
    const weights = document.getElementById("plot-weights");
    document.querySelectorAll("button[data-shapes]").forEach(button => {
      button.addEventListener("click", () => {
        const mode = button.dataset.shapes;
        const visible = weights.facecap.fig.traces.map(t =>
          mode === "all" ? true : mode === "none" ? "legendonly" : t.shown ? true : "legendonly");
        Plotly.restyle(weights, { visible: visible });
      });
    });
    document.querySelectorAll("button[data-shape]").forEach(button => {
      button.addEventListener("click", () => { // that shape (and its truth) alone in the weights plot
        const name = weights.facecap.fig.traces[Number(button.dataset.shape)].trace.name;
        Plotly.restyle(weights, { visible: weights.facecap.fig.traces.map(t =>
          t.trace.legendgroup === name ? true : "legendonly") });
        document.getElementById("weights").scrollIntoView({ behavior: "smooth" });
      });
    });
    const half = Math.max(30, Math.round(2 * (meta.fps || 30)));
    document.querySelectorAll("[data-frame]").forEach(link => {
      link.addEventListener("click", ev => {
        ev.preventDefault();
        zoomTo(plots, Number(link.dataset.frame), half);
        document.getElementById("weights").scrollIntoView({ behavior: "smooth" });
      });
    });
  }

  function ghosts() { // the marker panels show their render faintly behind the points
    document.querySelectorAll("image[data-from]").forEach(g => {
      const img = document.getElementById(g.dataset.from);
      if (img) g.setAttribute("href", img.getAttribute("src"));
    });
  }

  async function main() {
    ghosts();
    const meta = JSON.parse(document.getElementById("facecap-meta").textContent);
    if (typeof Plotly === "undefined") {
      fail("The plots need plotly.js, which did not load: " + meta.plotly + " must be beside this page.");
      return;
    }
    if (typeof DecompressionStream === "undefined") {
      fail("This browser cannot unpack the page's data (DecompressionStream: Chrome 80, Firefox 113, Safari 16.4 or later).");
      return;
    }
    const t0 = performance.now();
    const arrays = await unpack(document.getElementById("facecap-blob").textContent, meta.arrays);
    const t1 = performance.now();
    const timePlots = [];
    for (const fig of meta.figures) {
      const el = await draw(fig, arrays);
      if (fig.time) timePlots.push(el);
    }
    window.facecapTimings = { unpack_ms: t1 - t0, draw_ms: performance.now() - t1, since_start_ms: performance.now() };
    linkTime(timePlots);
    wireButtons(meta, timePlots);
  }

  window.facecapEnvelope = envelope; // for the tests: the page's own reduction
  main().catch(err => { console.error(err); fail("The page could not be drawn: " + err); })
    .finally(() => { window.facecapReady = true; });
})();
