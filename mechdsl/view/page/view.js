// mechdsl view: the page. It draws what the server sends (mechdsl/outputs/payload.py: a JSON
// header and float64 arrays in one binary message) and sends slider moves back. Every name
// and message from the file is set as text (textContent, fillText), never as markup.
"use strict";

(function () {
  const $ = (id) => document.getElementById(id);
  const canvas = $("mechanism");
  const ctx = canvas.getContext("2d");
  //: the shortest time (s) a run takes to play at 1x (a shorter run plays in slow motion)
  const PLAY_SECONDS = 2;
  const PALETTE = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b",
                   "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"];

  // what the page holds, for the user and for the tests (window.mechdslView)
  const view = {
    header: null, data: null, k: 0, playing: true, speed: 1, pace: 1, simTime: 0,
    latencies: [], handled: [], events: [], sliders: {}, nextId: 1, sent: {}, inFlight: null, queued: null,
  };
  window.mechdslView = view;

  function color(v, n) {
    if (n <= PALETTE.length) return PALETTE[v % PALETTE.length];
    return `hsl(${Math.round(240 - 240 * v / Math.max(n - 1, 1))}, 70%, 42%)`;
  }

  // -- messages ---------------------------------------------------------------------------
  function parse(buffer) {
    const dv = new DataView(buffer);
    const magic = String.fromCharCode(dv.getUint8(0), dv.getUint8(1), dv.getUint8(2), dv.getUint8(3));
    if (magic !== "MDV1") throw new Error("not a mechdsl view message");
    const n = dv.getUint32(4, true);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 8, n)));
    const data = new Float64Array(buffer, 8 + n, (buffer.byteLength - 8 - n) / 8);
    return { header, data };
  }

  let socket = null;
  function connect() {
    const path = location.pathname.replace(/\/(index\.html)?$/, "");
    const proto = location.protocol === "https:" ? "wss" : "ws";
    socket = new WebSocket(`${proto}://${location.host}${path}/ws`);
    socket.binaryType = "arraybuffer";
    socket.onopen = () => setState("connected: solving");
    socket.onclose = () => { setState("disconnected: the server stopped"); };
    socket.onmessage = (ev) => {
      if (!(ev.data instanceof ArrayBuffer)) return;
      const start = performance.now();
      let msg;
      try { msg = parse(ev.data); } catch (e) { showErrors([String(e)]); return; }
      receive(msg.header, msg.data);
      view.handled.push(performance.now() - start);  // the page's own share of a latency
    };
  }

  function send(obj) {
    if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(obj));
  }

  function receive(header, data) {
    if (header.sliders && header.sliders.length && !view.static) buildSliders(header.sliders);
    // any answer ends the request in flight (the server merges requests, and a reload or a
    // reset drops those waiting): the next move goes now
    if (view.inFlight !== null) {
      view.inFlight = null;
      if (view.queued) { const q = view.queued; view.queued = null; requestSet(q); }
    }
    if (header.type === "run") {
      const first = view.header === null;
      view.header = header; view.data = data;
      setupPlots();
      setupSweepPlots();
      setupVectors();
      const solved = Math.max(...header.solved, 1);
      $("scrub").max = String(solved - 1);
      if (view.k > solved - 1) view.k = 0;
      view.simTime = times()[view.k];
      // a run shorter than PLAY_SECONDS plays in slow motion, over PLAY_SECONDS at 1x: a
      // mechanism that moves in 0.03 s would otherwise be a blur, drawn in two frames a loop
      const t = times(), span = header.K > 1 ? t[header.K - 1] - t[0] : 0;
      view.pace = span > 0 ? Math.min(1, span / PLAY_SECONDS) : 1;
      $("pace").textContent = view.pace < 1 ? `(1x = ${fmt(view.pace)} of real time)` : "";
      showErrors(header.status === "ok" ? [] : header.messages.concat(header.warnings || []));
      $("file").textContent = `mechdsl view: ${header.file}`;
      $("summary").textContent = header.summary;
      setState(header.status === "ok" ? "ok" : `stopped: ${header.status}`);
      if (first) fitCanvas();
      draw();
    } else {
      // a file with errors, or a failed solve: the last good drawing stays
      showErrors(header.errors || []);
      setState(header.type === "error" ? "the file has errors (the last good run is shown)"
                                       : header.type === "protocol" ? "request refused"
                                       : "the run failed");
    }
    const id = header.id;
    requestAnimationFrame(() => {
      const now = performance.now();
      view.events.push({ type: header.type, reason: header.reason || "", id: id,
                         at: performance.timeOrigin + now });
      if (id != null && view.sent[id] !== undefined) {
        view.latencies.push(now - view.sent[id]);
        delete view.sent[id];
      }
    });
  }

  function setState(text) { $("state").textContent = text; }

  function showErrors(lines) {
    const box = $("errors");
    box.textContent = lines.join("\n\n");
    box.hidden = lines.length === 0;
  }

  // -- sliders ----------------------------------------------------------------------------
  function buildSliders(list) {
    const box = $("sliders");
    const names = list.map((s) => s.name).join("\u0000");
    if (box.dataset.names !== names) {
      box.textContent = "";
      view.sliders = {};
      for (const s of list) {
        const row = document.createElement("div");
        row.className = "slider";
        const label = document.createElement("label");
        label.textContent = s.name;
        const input = document.createElement("input");
        input.type = "range";
        input.setAttribute("aria-label", s.name);
        input.dataset.param = s.name;
        const out = document.createElement("output");
        label.htmlFor = input.id = `param-${Object.keys(view.sliders).length}`;
        input.addEventListener("input", () => {
          out.textContent = fmt(Number(input.value));
          requestSet({ [s.name]: Number(input.value) });
          updateSetText();
        });
        row.append(label, input, out);
        box.append(row);
        view.sliders[s.name] = { input, out };
      }
      box.dataset.names = names;
    }
    for (const s of list) {
      const w = view.sliders[s.name];
      if (!w) continue;
      // a value outside the range widens it (a clamped slider would copy a wrong value)
      const v = s.value ?? 0, lo = Math.min(s.lo ?? -1, v), hi = Math.max(s.hi ?? 1, v);
      w.input.min = String(lo); w.input.max = String(hi);
      w.input.step = "any";  // a value of the file, or typed, is kept as it is
      if (document.activeElement !== w.input && s.value != null) {
        w.input.value = String(s.value);
        w.out.textContent = fmt(s.value);
      }
    }
    updateSetText();
  }

  function requestSet(params) {
    // one request in flight: a newer move waits for its answer (the server merges too)
    if (view.inFlight !== null) { view.queued = Object.assign(view.queued || {}, params); return; }
    const id = view.nextId++;
    view.inFlight = id;
    view.sent[id] = performance.now();
    send({ type: "set", params, id });
  }

  function setText() {
    return Object.entries(view.sliders)
      .map(([name, w]) => `--set ${name}=${w.input.value}`).join(" ");
  }
  function updateSetText() { $("set-text").textContent = setText(); }

  function fmt(x) {
    if (!Number.isFinite(x)) return String(x);
    return Math.abs(x) >= 1e4 || (Math.abs(x) < 1e-3 && x !== 0) ? x.toExponential(3)
                                                                  : String(+x.toPrecision(5));
  }

  // -- geometry of the run ----------------------------------------------------------------
  function times() {
    const h = view.header;
    return view.data.subarray(h.t, h.t + h.K);
  }

  function slice(item, per) {
    const o = item.o + view.k * per;
    return view.data.subarray(o, o + per);
  }

  // the drawn points of body ``name`` of variant ``v`` at the current instant: [[x, y], ...]
  view.positions = function (name, v) {
    const it = view.header.items.find((i) => i.kind === "body" && i.name === name && i.v === (v || 0));
    if (!it) return null;
    const a = slice(it, 2 * it.p);
    const out = [];
    for (let j = 0; j < it.p; j++) out.push([a[2 * j], a[2 * j + 1]]);
    return out;
  };
  view.frame = () => view.k;
  view.setFrame = (k) => { view.k = k; view.playing = false; draw(); };

  let transform = { s: 1, x0: 0, y0: 0 };
  function fitCanvas() {
    const rect = canvas.getBoundingClientRect();
    const dpr = window.devicePixelRatio || 1;
    canvas.width = Math.max(320, Math.round(rect.width * dpr));
    canvas.height = Math.round(canvas.width * 0.7);
  }

  function setTransform() {
    const [x0, y0, x1, y1] = view.header.bounds;
    const w = Math.max(x1 - x0, 1e-9), h = Math.max(y1 - y0, 1e-9);
    const pad = 0.08 * Math.max(w, h);
    const s = Math.min(canvas.width / (w + 2 * pad), canvas.height / (h + 2 * pad));
    transform = { s, x0: (x0 + x1) / 2, y0: (y0 + y1) / 2 };
  }
  function X(x) { return canvas.width / 2 + (x - transform.x0) * transform.s; }
  function Y(y) { return canvas.height / 2 - (y - transform.y0) * transform.s; }

  // -- drawing ----------------------------------------------------------------------------
  function draw() {
    if (!view.header) return;
    const h = view.header;
    setTransform();
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    const unit = Math.max(2, canvas.width / 160);
    for (const it of h.items) {
      const c = color(it.v, h.V);
      if (it.kind === "ground") drawSupports(view.data.subarray(it.o, it.o + 2 * it.p), unit);
      else if (it.kind === "trace") drawTrace(it, c, unit);
      else if (it.kind === "centrode") drawCentrodes(it, c, unit);
    }
    for (const it of h.items) {
      const c = color(it.v, h.V);
      ctx.strokeStyle = c; ctx.fillStyle = c;
      if (it.kind === "body") drawBody(slice(it, 2 * it.p), it.p, c, unit);
      else if (it.kind === "shape") drawEdges(slice(it, 4 * it.p), it.p, c);
      else if (it.kind === "spring") drawSpring(slice(it, 4), c, unit);
    }
    drawVectors(h, unit);
    for (const it of h.items) {
      if (it.kind !== "pin") continue;
      const a = slice(it, 2);
      ctx.beginPath(); ctx.arc(X(a[0]), Y(a[1]), unit * 1.4, 0, 2 * Math.PI);
      ctx.fillStyle = "#fff"; ctx.fill();
      ctx.lineWidth = unit * 0.5; ctx.strokeStyle = color(it.v, h.V); ctx.stroke();
    }
    if (h.V > 1) drawLegend(h);
    const t = times()[view.k];
    $("time").textContent = `t = ${fmt(t)}${h.time_unit ? " " + h.time_unit : ""}`;
    $("scrub").value = String(view.k);
    drawCursor();
  }

  function drawBody(a, p, c, unit) {
    ctx.lineWidth = unit; ctx.lineJoin = "round"; ctx.lineCap = "round";
    if (p === 1) {
      ctx.beginPath(); ctx.rect(X(a[0]) - 2 * unit, Y(a[1]) - 1.5 * unit, 4 * unit, 3 * unit);
      ctx.globalAlpha = 0.35; ctx.fill(); ctx.globalAlpha = 1; ctx.stroke(); return;
    }
    ctx.beginPath();
    ctx.moveTo(X(a[0]), Y(a[1]));
    for (let j = 1; j < p; j++) ctx.lineTo(X(a[2 * j]), Y(a[2 * j + 1]));
    if (p >= 3) { ctx.closePath(); ctx.globalAlpha = 0.25; ctx.fill(); ctx.globalAlpha = 1; }
    ctx.stroke();
  }

  function drawEdges(a, e, c) {
    ctx.lineWidth = 1; ctx.beginPath();
    for (let j = 0; j < e; j++) {
      ctx.moveTo(X(a[4 * j]), Y(a[4 * j + 1])); ctx.lineTo(X(a[4 * j + 2]), Y(a[4 * j + 3]));
    }
    ctx.stroke();
  }

  function drawSpring(a, c, unit) {
    const [px, py, qx, qy] = a;
    const dx = qx - px, dy = qy - py, len = Math.hypot(dx, dy);
    if (!(len > 0)) return;
    const ux = dx / len, uy = dy / len, nx = -uy, ny = ux, turns = 8;
    ctx.lineWidth = unit * 0.5; ctx.beginPath(); ctx.moveTo(X(px), Y(py));
    const n = 2 * turns;
    for (let j = 0; j <= n; j++) {
      const s = 0.15 + 0.7 * j / n, side = (j === 0 || j === n) ? 0 : (j % 2 ? 1 : -1);
      ctx.lineTo(X(px + s * len * ux + side * 0.05 * len * nx),
                 Y(py + s * len * uy + side * 0.05 * len * ny));
    }
    ctx.lineTo(X(qx), Y(qy)); ctx.stroke();
  }

  function drawSupports(a, unit) {
    ctx.strokeStyle = "#595959"; ctx.fillStyle = "#595959"; ctx.lineWidth = unit * 0.4;
    for (let j = 0; j < a.length / 2; j++) {
      const x = X(a[2 * j]), y = Y(a[2 * j + 1]), s = unit * 4;
      ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(x - s, y + s * 1.4); ctx.lineTo(x + s, y + s * 1.4);
      ctx.closePath(); ctx.stroke();
      ctx.beginPath();
      for (let i = -1; i <= 1; i += 0.5) {
        ctx.moveTo(x + i * s, y + s * 1.4); ctx.lineTo(x + i * s - s * 0.5, y + s * 1.9);
      }
      ctx.stroke();
    }
  }

  function drawTrace(it, c, unit) {
    const h = view.header, n = h.solved[it.v];
    const a = view.data.subarray(it.o, it.o + 2 * h.K);
    ctx.strokeStyle = c; ctx.globalAlpha = 0.5; ctx.lineWidth = unit * 0.4; ctx.beginPath();
    let pen = false;
    for (let k = 0; k < n; k++) {
      const x = a[2 * k], y = a[2 * k + 1];
      if (!Number.isFinite(x) || !Number.isFinite(y)) { pen = false; continue; }
      if (pen) ctx.lineTo(X(x), Y(y)); else { ctx.moveTo(X(x), Y(y)); pen = true; }
    }
    ctx.stroke(); ctx.globalAlpha = 1;
  }

  // the centrodes at the instant shown: the fixed one (dashed) carried by its frame's pose,
  // the moving one (dotted) by the moving body's, touching at the instant centre (a cross)
  function drawCentrodes(it, c, unit) {
    const k = Math.min(view.k, view.header.solved[it.v] - 1);
    if (k < 0) return;
    const curve = (o, p, dash) => {
      const x0 = view.data[p + 3 * k], y0 = view.data[p + 3 * k + 1], f = view.data[p + 3 * k + 2];
      const cs = Math.cos(f), sn = Math.sin(f), a = view.data.subarray(o, o + 2 * it.m);
      ctx.setLineDash(dash); ctx.beginPath();
      let pen = false;
      for (let i = 0; i < it.m; i++) {
        const u = a[2 * i], w = a[2 * i + 1];
        if (!Number.isFinite(u) || !Number.isFinite(w)) { pen = false; continue; }
        const x = X(x0 + cs * u - sn * w), y = Y(y0 + sn * u + cs * w);
        if (pen) ctx.lineTo(x, y); else { ctx.moveTo(x, y); pen = true; }
      }
      ctx.stroke();
    };
    ctx.strokeStyle = c; ctx.globalAlpha = 0.6; ctx.lineWidth = unit * 0.35;
    curve(it.fixed, it.pb, [4 * unit, 2 * unit]);
    curve(it.moving, it.pa, [unit, 1.5 * unit]);
    ctx.setLineDash([]); ctx.globalAlpha = 1;
    const x = view.data[it.ic + 2 * k], y = view.data[it.ic + 2 * k + 1];
    if (Number.isFinite(x) && Number.isFinite(y)) {
      const d = 1.5 * unit;
      ctx.lineWidth = unit * 0.5; ctx.beginPath();
      ctx.moveTo(X(x) - d, Y(y) - d); ctx.lineTo(X(x) + d, Y(y) + d);
      ctx.moveTo(X(x) - d, Y(y) + d); ctx.lineTo(X(x) + d, Y(y) - d); ctx.stroke();
    }
  }

  function drawLegend(h) {
    const box = Math.max(10, canvas.width / 80);
    ctx.font = `${box}px system-ui, sans-serif`;
    h.variants.forEach((label, v) => {
      ctx.fillStyle = color(v, h.V);
      ctx.fillRect(box, box + v * box * 1.5, box, box);
      ctx.fillStyle = "#222";
      ctx.fillText(label, box * 2.4, box * 1.9 + v * box * 1.5);
    });
  }

  // -- velocity and acceleration of the traced points --------------------------------------
  const vectorScale = { v: 0, a: 0 };
  function setupVectors() {
    const h = view.header, traced = h.items.filter((i) => i.kind === "trace" && i.vo != null);
    $("vectors").hidden = $("vectors-a").hidden = traced.length === 0;
    // the largest over the run is drawn a fifth of the drawing's size
    const [x0, y0, x1, y1] = h.bounds, size = 0.2 * Math.max(x1 - x0, y1 - y0, 1e-9);
    for (const [key, field] of [["v", "vo"], ["a", "ao"]]) {
      let most = 0;
      for (const it of traced) {
        const a = view.data.subarray(it[field], it[field] + 2 * h.K);
        for (let k = 0; k < h.solved[it.v]; k++) {
          const m = Math.hypot(a[2 * k], a[2 * k + 1]);
          if (m > most) most = m;
        }
      }
      vectorScale[key] = most > 0 ? size / most : 0;
    }
  }

  function arrow(x, y, dx, dy, c, unit) {
    const X0 = X(x), Y0 = Y(y), X1 = X(x + dx), Y1 = Y(y + dy);
    const len = Math.hypot(X1 - X0, Y1 - Y0);
    if (!(len > 1)) return;
    const ux = (X1 - X0) / len, uy = (Y1 - Y0) / len, head = Math.min(len / 3, unit * 4);
    ctx.strokeStyle = c; ctx.fillStyle = c; ctx.lineWidth = unit * 0.5;
    ctx.beginPath(); ctx.moveTo(X0, Y0); ctx.lineTo(X1, Y1); ctx.stroke();
    ctx.beginPath(); ctx.moveTo(X1, Y1);
    ctx.lineTo(X1 - head * ux - head * 0.5 * uy, Y1 - head * uy + head * 0.5 * ux);
    ctx.lineTo(X1 - head * ux + head * 0.5 * uy, Y1 - head * uy - head * 0.5 * ux);
    ctx.closePath(); ctx.fill();
  }

  function drawVectors(h, unit) {
    const showV = $("show-v").checked, showA = $("show-a").checked;
    if (!showV && !showA) return;
    for (const it of h.items) {
      if (it.kind !== "trace" || it.vo == null || view.k >= h.solved[it.v]) continue;
      const p = slice(it, 2);
      if (showV) {
        const v = view.data.subarray(it.vo + 2 * view.k, it.vo + 2 * view.k + 2);
        arrow(p[0], p[1], v[0] * vectorScale.v, v[1] * vectorScale.v, "#111111", unit);
      }
      if (showA) {
        const a = view.data.subarray(it.ao + 2 * view.k, it.ao + 2 * view.k + 2);
        arrow(p[0], p[1], a[0] * vectorScale.a, a[1] * vectorScale.a, "#b000b0", unit);
      }
    }
  }

  // -- a sweep's outputs against its param --------------------------------------------------
  function setupSweepPlots() {
    const h = view.header, box = $("sweep-plots"), names = Object.keys(h.sweep || {});
    box.textContent = "";
    const show = h.V > 1 && names.length === 1;
    $("sweep-title").hidden = !show;
    if (!show) return;
    const xs = h.sweep[names[0]], order = xs.map((_, i) => i).sort((a, b) => xs[a] - xs[b]);
    for (const name of [...new Set(h.series.map((s) => s.name))]) {
      const lo = [], hi = [];
      for (const s of h.series.filter((s) => s.name === name)) {
        [lo[s.v], hi[s.v]] = solvedRange(s, Infinity, -Infinity);
      }
      const { label, canvas: cv } = plotBox(box);
      label.textContent = `${name}: least and largest over the run, against ${names[0]}`;
      const c = cv.getContext("2d"), W = cv.width, H = cv.height;
      const finite = [...lo, ...hi].filter(Number.isFinite);
      if (!finite.length) continue;
      let ymin = Math.min(...finite), ymax = Math.max(...finite);
      if (ymax === ymin) { ymin -= 1; ymax += 1; }
      const xmin = xs[order[0]], xmax = xs[order[order.length - 1]] > xmin ? xs[order[order.length - 1]] : xmin + 1;
      const px = (x) => 8 + (x - xmin) / (xmax - xmin) * (W - 16);
      const py = (y) => H - 6 - (y - ymin) / (ymax - ymin) * (H - 12);
      for (const [ys, col] of [[hi, "#d62728"], [lo, "#1f77b4"]]) {
        c.strokeStyle = col; c.fillStyle = col; c.lineWidth = 1.5; c.beginPath();
        order.forEach((v, j) => {
          if (!Number.isFinite(ys[v])) return;
          if (j) c.lineTo(px(xs[v]), py(ys[v])); else c.moveTo(px(xs[v]), py(ys[v]));
        });
        c.stroke();
        for (const v of order) {
          if (Number.isFinite(ys[v])) { c.beginPath(); c.arc(px(xs[v]), py(ys[v]), 2.5, 0, 2 * Math.PI); c.fill(); }
        }
      }
    }
  }

  // -- plots ------------------------------------------------------------------------------
  /** The least and largest finite values of a series over its solved instants, widening
   * [lo, hi]. */
  function solvedRange(s, lo, hi) {
    for (const x of view.data.subarray(s.o, s.o + view.header.solved[s.v])) {
      if (Number.isFinite(x)) { if (x < lo) lo = x; if (x > hi) hi = x; }
    }
    return [lo, hi];
  }

  /** A plot's title and canvas, appended to ``box``. */
  function plotBox(box) {
    const div = document.createElement("div"); div.className = "plot";
    const label = document.createElement("div"); label.className = "label";
    const canvas = document.createElement("canvas"); canvas.width = 560; canvas.height = 140;
    // the cursor is an element over the canvas: moving it redraws no pixel of the plot
    // (copying the plot back at every frame took a core of a laptop's CPU while playing)
    const area = document.createElement("div"); area.className = "area";
    const cursor = document.createElement("div"); cursor.className = "cursor";
    area.append(canvas, cursor);
    div.append(label, area); box.append(div);
    return { label, canvas, cursor };
  }

  let plots = [];
  function setupPlots() {
    const h = view.header, box = $("plots");
    const names = [...new Set(h.series.map((s) => s.name))];
    if (box.dataset.names !== names.join("\u0000")) {
      box.textContent = "";
      plots = names.map((name) => {
        return { name, ...plotBox(box) };
      });
      box.dataset.names = names.join("\u0000");
    }
    for (const p of plots) {
      p.series = h.series.filter((s) => s.name === p.name);
      let lo = Infinity, hi = -Infinity;
      for (const s of p.series) [lo, hi] = solvedRange(s, lo, hi);
      if (!(hi >= lo)) { lo = -1; hi = 1; }
      if (hi === lo) { lo -= 1; hi += 1; }
      p.lo = lo; p.hi = hi;
      p.unit = p.series.length ? p.series[0].unit : "";
      drawPlot(p);
      p.text = null;
    }
  }

  function drawPlot(p) {
    const h = view.header, c = p.canvas.getContext("2d"), W = p.canvas.width, H = p.canvas.height;
    const t = times(), t0 = t[0], t1 = t[h.K - 1] > t0 ? t[h.K - 1] : t0 + 1;
    c.clearRect(0, 0, W, H);
    c.strokeStyle = "#ddd"; c.beginPath(); c.moveTo(0, H / 2); c.lineTo(W, H / 2); c.stroke();
    for (const s of p.series) {
      const a = view.data.subarray(s.o, s.o + h.K);
      c.strokeStyle = color(s.v, h.V); c.lineWidth = 1.5; c.beginPath();
      let pen = false;
      for (let k = 0; k < h.solved[s.v]; k++) {
        if (!Number.isFinite(a[k])) { pen = false; continue; }
        const x = (t[k] - t0) / (t1 - t0) * W, y = H - 6 - (a[k] - p.lo) / (p.hi - p.lo) * (H - 12);
        if (pen) c.lineTo(x, y); else { c.moveTo(x, y); pen = true; }
      }
      c.stroke();
    }
  }

  function drawCursor() {
    const h = view.header, t = times(), t0 = t[0], t1 = t[h.K - 1] > t0 ? t[h.K - 1] : t0 + 1;
    const at = `${(100 * (t[view.k] - t0) / (t1 - t0)).toFixed(3)}%`;
    for (const p of plots) {
      p.cursor.style.left = at;
      const values = p.series.map((s) => fmt(view.data[s.o + view.k]));
      const text = `${p.name}${p.unit ? " [" + p.unit + "]" : ""} = ${values.join(", ")}` +
        `   (${fmt(p.lo)} .. ${fmt(p.hi)})`;
      if (text !== p.text) { p.label.textContent = text; p.text = text; }
    }
  }

  // -- animation --------------------------------------------------------------------------
  let last = null;
  function tick(now) {
    if (view.header && view.playing) {
      const h = view.header, t = times(), solved = Math.max(...h.solved, 1);
      const dt = last === null ? 0 : (now - last) / 1000;
      view.simTime += dt * view.speed * view.pace;
      const tEnd = t[solved - 1];
      if (view.simTime > tEnd || view.simTime < t[0]) view.simTime = t[0];
      // the instants are evenly spaced: the index from the time
      const step = h.K > 1 ? (t[h.K - 1] - t[0]) / (h.K - 1) : 1;
      const k = Math.min(solved - 1, Math.max(0, Math.floor((view.simTime - t[0]) / step + 1e-9)));
      if (k !== view.k) { view.k = k; view.draw(); }
    }
    last = now;
    view.frameTime = now;  // the frame the simulated time stands at (for the tests' clocks)
    requestAnimationFrame(tick);
  }

  // -- saving what is shown ---------------------------------------------------------------
  function download(name, blob) {
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob); a.download = name;
    document.body.append(a); a.click(); a.remove();
    setTimeout(() => URL.revokeObjectURL(a.href), 1000);
  }
  function stem() { return (view.header ? view.header.file : "mechanism").replace(/\.mech$/, ""); }

  function frameSvg() {
    const h = view.header, parts = [];
    const esc = (s) => String(s).replace(/[&<>"']/g, (ch) => `&#${ch.charCodeAt(0)};`);
    for (const it of h.items) {
      const c = color(it.v, h.V);
      if (it.kind === "body") {
        const a = slice(it, 2 * it.p), pts = [];
        for (let j = 0; j < it.p; j++) pts.push(`${X(a[2 * j]).toFixed(2)},${Y(a[2 * j + 1]).toFixed(2)}`);
        const tag = it.p >= 3 ? "polygon" : "polyline";
        parts.push(`<${tag} points="${pts.join(" ")}" fill="${it.p >= 3 ? c : "none"}" fill-opacity="0.25" stroke="${c}" stroke-width="3"><title>${esc(it.name)}</title></${tag}>`);
      } else if (it.kind === "pin") {
        const a = slice(it, 2);
        parts.push(`<circle cx="${X(a[0]).toFixed(2)}" cy="${Y(a[1]).toFixed(2)}" r="5" fill="#fff" stroke="${c}" stroke-width="2"/>`);
      }
    }
    return `<svg xmlns="http://www.w3.org/2000/svg" width="${canvas.width}" height="${canvas.height}">${parts.join("")}</svg>`;
  }

  function runCsv() {
    const h = view.header, t = times(), cols = ["t"], arrays = [t];
    for (const s of h.series) {
      cols.push(h.V > 1 ? `${s.name}[${h.variants[s.v]}]` : s.name);
      arrays.push(view.data.subarray(s.o, s.o + h.K));
    }
    const quote = (s) => /[",\n]/.test(s) ? `"${s.replace(/"/g, '""')}"` : s;
    const n = Math.max(...h.solved, 1), lines = [cols.map(quote).join(",")];
    for (let k = 0; k < n; k++) lines.push(arrays.map((a) => String(a[k])).join(","));
    return lines.join("\n") + "\n";
  }
  view.svg = frameSvg;
  view.draw = draw;  // (replaceable: the benchmark times it)
  view.csv = runCsv;

  // -- wiring -----------------------------------------------------------------------------
  $("play").addEventListener("click", () => {
    view.playing = !view.playing;
    $("play").textContent = view.playing ? "pause" : "play";
  });
  $("scrub").addEventListener("input", () => {
    view.playing = false; $("play").textContent = "play";
    view.k = Number($("scrub").value);
    if (view.header) view.simTime = times()[view.k];
    draw();
  });
  $("speed").addEventListener("change", () => { view.speed = Number($("speed").value); });
  $("show-v").addEventListener("change", () => draw());
  $("show-a").addEventListener("change", () => draw());
  $("reset").addEventListener("click", () => send({ type: "reset" }));
  $("copy-set").addEventListener("click", () => {
    const text = setText();
    if (navigator.clipboard) navigator.clipboard.writeText(text).catch(() => {});
    $("set-text").textContent = text;
  });
  $("save-png").addEventListener("click", () => canvas.toBlob((b) => download(`${stem()}.png`, b)));
  $("save-svg").addEventListener("click", () =>
    download(`${stem()}.svg`, new Blob([frameSvg()], { type: "image/svg+xml" })));
  $("save-csv").addEventListener("click", () =>
    download(`${stem()}.csv`, new Blob([runCsv()], { type: "text/csv" })));
  window.addEventListener("resize", () => { fitCanvas(); draw(); });

  // a page written by `mechdsl run --html`: the run is inside it, there is no server
  const embedded = document.getElementById("mechdsl-run");
  if (embedded) {
    const text = atob(embedded.textContent.trim());
    const bytes = new Uint8Array(text.length);
    for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
    const msg = parse(bytes.buffer);
    view.static = true;
    $("setline").hidden = true;
    const heading = $("right").querySelector("h2");
    if (msg.header.V > 1) {
      heading.textContent = "Variants (computed beforehand)";
      $("sliders").textContent = msg.header.variants.join("\n");
      $("sliders").style.whiteSpace = "pre-line";
    } else {
      heading.hidden = true;
    }
    receive(msg.header, msg.data);
    setState("a saved run: mechdsl run --html");
  } else {
    connect();
  }
  requestAnimationFrame(tick);
})();
