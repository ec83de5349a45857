// osap view: the page. Reads api/info once, then follows the websocket's
// state messages. Everything inserted is text (textContent), never HTML.
"use strict";

const TOKEN = new URLSearchParams(location.search).get("token");
const TOKEN_MSG = "this view needs its token: open the URL osap view printed";
const SVG_NS = "http://www.w3.org/2000/svg";
const LIVE = "live:axes";
const LIVE_WINDOW_US = 30e6;
const LIVE_MAX_POINTS = 3000; // guards memory if the server ever sends faster
const FAULT_KEEP = 200;
const PLOT_MIN_MS = 200; // at most 5 live redraws a second
const PALETTE = ["#2563c9", "#d1342f", "#1f9d55", "#d97706", "#7c3aed",
  "#0891b2", "#be185d", "#4d7c0f", "#475569", "#b45309"];

// Public for tests and debugging; kept up to date in place.
window.osapView = { info: null, state: null, calls: 0 };

// Page-private state.
const view = {
  info: null,
  byId: new Map(), // runtime id -> runtime (from info)
  layout: new Map(), // runtime id -> box geometry
  boxes: new Map(), // runtime id -> {g, clock, stack}
  edges: [], // {edge, line, label}
  rows: new Map(), // "R-I" -> link table cells
  linkStats: new Map(), // "R-I" -> latest link stats
  axisRows: new Map(), // "axis NAME" / "motor NAME" -> value cell
  live: new Map(), // series name -> {kind, name, t: [], v: []}
  lastTime: null, // time_us of the last state, to notice a restarted clock
  capture: null, // series of the chosen capture file
  plotTimer: null, lastPlot: 0,
  current: null, // {rt, fn} shown in the function panel
  inFlight: false, authFailed: false,
};

const $ = (id) => document.getElementById(id);
const arr = (x) => (Array.isArray(x) ? x : []);

// ---------- helpers ----------

/** An HTML element with attributes and text/element children. */
function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) if (v != null) e.setAttribute(k, v);
  e.append(...children.map((c) => (typeof c === "string" ? document.createTextNode(c) : c)));
  return e;
}

/** An SVG element; `text` becomes its text content. */
function sv(tag, attrs = {}, text) {
  const e = document.createElementNS(SVG_NS, tag);
  for (const [k, v] of Object.entries(attrs)) if (v != null) e.setAttribute(k, String(v));
  if (text != null) e.textContent = text;
  return e;
}

const isNum = (x) => typeof x === "number" && Number.isFinite(x);

function fmtBytes(x) {
  if (!isNum(x)) return "–";
  if (x < 1000) return `${Math.round(x)} B/s`;
  if (x < 1e6) return `${(x / 1e3).toFixed(1)} kB/s`;
  return `${(x / 1e6).toFixed(2)} MB/s`;
}
const fmtPct = (load) => (isNum(load) ? `${(load * 100).toFixed(1)} %` : "–");
const fmtSeconds = (us) => (isNum(us) ? (us / 1e6).toFixed(3) : "–");
const fmtPos = (x) => (isNum(x) ? x.toFixed(3) : "–");
const fmtSigned = (n) => (isNum(n) && n < 0 ? `\u2212${-n}` : String(n ?? "?"));

/** The colour class of a link load: grey < 1 %, green < 30 %, orange < 70 %, red. */
const loadClass = (load) => (!isNum(load) ? "load-none" : load < 0.01 ? "load-idle"
  : load < 0.3 ? "load-ok" : load < 0.7 ? "load-busy" : "load-high");

// ---------- server ----------

/** A URL next to the page, carrying the token when the page has one. */
function apiUrl(path, params = {}) {
  const u = new URL(path, location.href);
  for (const [k, v] of Object.entries(params)) u.searchParams.set(k, v);
  if (TOKEN) u.searchParams.set("token", TOKEN);
  return u.toString();
}

/** Fetches JSON; throws an Error with the server's words on failure. */
async function fetchJSON(path, opts = {}, params = {}) {
  const res = await fetch(apiUrl(path, params), opts);
  if (res.status === 401) throw showAuthError();
  const text = await res.text();
  let body = null;
  try { body = JSON.parse(text); } catch (_) { /* not JSON: use the text */ }
  if (!res.ok) throw new Error((body && body.error) || text || `HTTP ${res.status}`);
  if (body === null || typeof body !== "object") throw new Error("the server did not answer JSON");
  return body;
}

function showBanner(msg) {
  $("error").textContent = msg;
  $("error").hidden = false;
}

/** Says the token is missing or wrong, for good: returns the error to throw. */
function showAuthError() {
  view.authFailed = true;
  showBanner(TOKEN_MSG);
  setBadge(false, "needs token");
  return new Error(TOKEN_MSG);
}

function setBadge(on, text) {
  $("conn").textContent = text;
  $("conn").className = `badge ${on ? "badge-on" : "badge-off"}`;
}

/** Follows the state websocket, reconnecting a second after it closes. */
function connect() {
  if (view.authFailed) return;
  const u = new URL(apiUrl("ws"));
  u.protocol = location.protocol === "https:" ? "wss:" : "ws:";
  const ws = new WebSocket(u.toString());
  ws.onopen = () => {
    setBadge(true, "live");
    if (!view.info) loadInfo(); // the first try failed (server was restarting)
  };
  ws.onmessage = (ev) => {
    let msg = null;
    try { msg = JSON.parse(ev.data); } catch (_) { /* not ours: ignore */ }
    if (msg && msg.type === "state") applyState(msg);
  };
  ws.onclose = () => {
    if (view.authFailed) return;
    setBadge(false, "disconnected");
    setTimeout(connect, 1000);
  };
}

// ---------- graph ----------

const G = { pad: 20, colGap: 200, rowGap: 26, minW: 230, line: 14, fnTop: 86 };

/** How many hops from the host: the route's length, else the parent chain's. */
function depthOf(rt) {
  if (Array.isArray(rt.route)) return rt.route.length;
  let d = 0;
  for (let p = rt.parent; p != null && d < 64; d++) p = view.byId.get(p)?.parent;
  return d;
}

const fnsOf = (rt) => arr(rt.functions);
const pipesOf = (fn) => arr(fn.pipes);
const fnLabel = (fn) => (pipesOf(fn).length ? `${fn.name} →${pipesOf(fn).length}` : String(fn.name));

/** Columns by depth, boxes stacked in parent order so edges cross less. */
function layoutGraph(runtimes) {
  const cols = [];
  for (const rt of runtimes) (cols[depthOf(rt)] ||= []).push(rt);
  const rowOf = new Map();
  let x = G.pad, maxX = 0, maxY = 0;
  for (const col of cols) {
    if (!col) continue;
    col.sort((a, b) => (rowOf.get(a.parent) ?? 0) - (rowOf.get(b.parent) ?? 0) || a.id - b.id);
    // Box width from an estimate of the widest text line (no layout pass needed).
    const w = Math.max(G.minW, ...col.map((rt) => Math.max(
      String(rt.name).length * 8.5 + 24,
      String(rt.type ?? "").length * 6.2 + 24,
      ...fnsOf(rt).map((f) => fnLabel(f).length * 6.8 + 24))));
    let y = G.pad;
    col.forEach((rt, i) => {
      rowOf.set(rt.id, i);
      const h = G.fnTop + fnsOf(rt).length * G.line - (fnsOf(rt).length ? 4 : 10);
      view.layout.set(rt.id, { x, y, w, h, cx: x + w / 2, cy: y + h / 2 });
      y += h + G.rowGap;
    });
    maxY = Math.max(maxY, y - G.rowGap);
    maxX = x + w;
    x += w + G.colGap;
  }
  return { width: maxX + G.pad + 70, height: maxY + G.pad };
}

/** The y of a function's line, in graph coordinates. */
const fnY = (box, i) => box.y + G.fnTop + i * G.line - 4;

/** End points of an edge between two boxes: facing sides. */
function edgeEnds(a, b) {
  if (a.x + a.w <= b.x) return [a.x + a.w, a.cy, b.x, b.cy];
  if (b.x + b.w <= a.x) return [a.x, a.cy, b.x + b.w, b.cy];
  return a.y < b.y ? [a.cx, a.y + a.h, b.cx, b.y] : [a.cx, a.y, b.cx, b.y + b.h];
}

function drawGraph(info) {
  const svg = $("graph");
  svg.replaceChildren();
  const runtimes = arr(info.runtimes);
  const size = layoutGraph(runtimes);
  svg.setAttribute("viewBox", `0 0 ${size.width} ${size.height}`);
  svg.setAttribute("width", size.width);
  svg.setAttribute("height", size.height);
  // Layers: edges under pipes under boxes; labels on top so they stay legible.
  const marker = svg.appendChild(sv("defs")).appendChild(sv("marker", { id: "pipe-arrow", viewBox: "0 0 6 6",
    refX: 6, refY: 3, markerWidth: 6, markerHeight: 6, orient: "auto" }));
  marker.appendChild(sv("path", { class: "pipe-head", d: "M0,0 L6,3 L0,6 z" }));
  const layers = ["edges", "pipes", "boxes", "labels"].map((n) => svg.appendChild(sv("g", { class: n })));
  drawEdges(info.edges, layers[0], layers[3]);
  drawPipes(runtimes, layers[1]);
  for (const rt of runtimes) drawBox(layers[2], rt, view.layout.get(rt.id));
}

function drawEdges(edges, lineLayer, labelLayer) {
  const seen = new Map(); // pair -> count, to spread labels of parallel links
  for (const e of arr(edges)) {
    const [a, b] = e ? [view.layout.get(e.from), view.layout.get(e.to)] : [];
    if (!a || !b) continue;
    const [x1, y1, x2, y2] = edgeEnds(a, b);
    const pair = [e.from, e.to].sort().join("-");
    const k = seen.get(pair) || 0;
    seen.set(pair, k + 1);
    const line = lineLayer.appendChild(sv("line", { class: "edge load-none", x1, y1, x2, y2 }));
    const label = labelLayer.appendChild(sv("text", { class: "edge-label", id: `link-${e.from}-${e.from_link}`,
      "text-anchor": "middle", x: (x1 + x2) / 2, y: (y1 + y2) / 2 - 5 + k * 15 }, `${e.kind ?? "link"} · –`));
    view.edges.push({ edge: e, line, label });
  }
}

/** Dashed curves from a function's line to the runtime (or function) it feeds. */
function drawPipes(runtimes, layer) {
  for (const rt of runtimes) {
    const src = view.layout.get(rt.id);
    fnsOf(rt).forEach((fn, i) => {
      for (const p of pipesOf(fn)) {
        const dstRt = view.byId.get(p.to_runtime);
        const dst = dstRt && view.layout.get(dstRt.id);
        if (!src || !dst) continue;
        const j = fnsOf(dstRt).findIndex((f) => f.name === p.to_function);
        const y1 = fnY(src, i);
        const y2 = j >= 0 ? fnY(dst, j) : dst.cy;
        const path = layer.appendChild(sv("path", { class: "pipe", d: pipePath(src, y1, dst, y2), "marker-end": "url(#pipe-arrow)" }));
        path.appendChild(sv("title", {}, `${rt.name}/${fn.name} slot ${p.slot ?? "?"} → ${dstRt.name}/${p.to_function ?? "?"}`));
      }
    });
  }
}

function pipePath(src, y1, dst, y2) {
  let x1, x2, c1, c2;
  if (dst.x >= src.x + src.w) {
    [x1, x2] = [src.x + src.w, dst.x];
    c1 = x1 + (x2 - x1) / 2; c2 = x2 - (x2 - x1) / 2;
  } else if (dst.x + dst.w <= src.x) {
    [x1, x2] = [src.x, dst.x + dst.w];
    c1 = x1 - (x1 - x2) / 2; c2 = x2 + (x1 - x2) / 2;
  } else {
    // Same column (or itself): loop out to the right and back.
    [x1, x2] = [src.x + src.w, dst.x + dst.w];
    const bulge = 40 + Math.min(30, Math.abs(y2 - y1) / 8);
    c1 = x1 + bulge; c2 = x2 + bulge;
  }
  return `M${x1},${y1} C${c1},${y1} ${c2},${y2} ${x2},${y2}`;
}

function drawBox(layer, rt, b) {
  if (!b) return;
  const g = layer.appendChild(sv("g", { class: "rt", "data-runtime": rt.name, transform: `translate(${b.x},${b.y})` }));
  g.appendChild(sv("rect", { class: "rt-box", width: b.w, height: b.h, rx: 6 }));
  g.appendChild(sv("text", { class: "rt-name", x: 10, y: 19 }, rt.name));
  g.appendChild(sv("text", { class: "rt-type", x: 10, y: 34 }, rt.type ?? ""));
  const clock = g.appendChild(sv("text", { class: "rt-clock", x: 10, y: 50 }, "clock …"));
  const stack = g.appendChild(sv("text", { class: "rt-stack", x: 10, y: 64 }, "stack …"));
  if (fnsOf(rt).length) g.appendChild(sv("line", { class: "rt-sep", x1: 6, x2: b.w - 6, y1: 72, y2: 72 }));
  fnsOf(rt).forEach((fn, i) => g.appendChild(drawFunctionLine(rt, fn, i, b)));
  view.boxes.set(rt.id, { g, clock, stack, maxChars: Math.floor((b.w - 20) / 6) });
}

function drawFunctionLine(rt, fn, i, b) {
  const y = G.fnTop + i * G.line;
  const fg = sv("g", { class: "fn", "data-function": `${rt.name}/${fn.name}`, tabindex: 0, role: "button" });
  fg.appendChild(sv("rect", { class: "fn-hit", x: 4, y: y - 11, width: b.w - 8, height: G.line }));
  const t = fg.appendChild(sv("text", { class: "fn-name", x: 10, y }, fn.name));
  const n = pipesOf(fn).length;
  if (n) t.appendChild(sv("tspan", { class: "fn-pipes" }, ` →${n}`));
  const open = () => openFunction(rt, fn, fg);
  fg.addEventListener("click", open);
  fg.addEventListener("keydown", (ev) => { if (ev.key === "Enter" || ev.key === " ") { ev.preventDefault(); open(); } });
  return fg;
}

/** Shows a runtime's clock, stack and read error from a state message. */
function updateRuntimes(list) {
  for (const r of arr(list)) {
    const ref = r && view.boxes.get(r.id);
    if (!ref) continue;
    ref.g.classList.toggle("stale", r.error != null);
    if (r.error != null) {
      setFitText(ref.clock, `error: ${r.error}`, ref.maxChars);
      ref.clock.setAttribute("class", "rt-clock");
      continue;
    }
    const settled = !!r.settled;
    const text = r.root
      ? `root · tier ${r.tier ?? "?"}`
      : `tier ${r.tier ?? "?"} · offset ${fmtSigned(r.offset_us)} µs · ${settled ? "settled" : "not settled"}`;
    setFitText(ref.clock, text, ref.maxChars);
    ref.clock.setAttribute("class", `rt-clock ${r.root || settled ? "clock-ok" : "clock-warn"}`);
    ref.stack.textContent = `stack ${r.stack_used ?? "?"}/${r.stack_slots ?? "?"}`;
  }
}

/** Sets SVG text, shortened to fit its box, with the whole text as a tooltip. */
function setFitText(node, text, maxChars) {
  const s = String(text);
  node.textContent = s.length > maxChars ? `${s.slice(0, Math.max(1, maxChars - 1))}…` : s;
  if (s.length > maxChars) node.appendChild(sv("title", {}, s));
}

// ---------- links ----------

function buildLinkRows(runtimes) {
  const body = $("link-rows");
  body.replaceChildren();
  for (const rt of runtimes) {
    for (const l of arr(rt.links)) {
      const num = () => el("td", { class: "num" }, "–");
      const cells = { rx: num(), tx: num(), load: num(), bar: el("div"), packets: num(), dropped: num() };
      const named = l.name ? `${l.kind ?? "?"} (${l.name})` : String(l.kind ?? "?");
      // Open, but nothing heard and nothing answered a scan: an unwired UART.
      const kind = l.open !== false && l.heard === false ? `${named} · no neighbour` : named;
      const row = el("tr", { id: `row-${rt.id}-${l.index}`, class: l.open === false ? "closed" : null },
        el("td", {}, String(rt.name)), el("td", { class: "num" }, String(l.index)),
        el("td", { title: l.peer == null ? "no neighbour" : `to ${view.byId.get(l.peer)?.name ?? l.peer}` }, kind),
        cells.rx, cells.tx, cells.load, el("td", {}, el("div", { class: "bar" }, cells.bar)),
        cells.packets, cells.dropped);
      body.appendChild(row);
      view.rows.set(`${rt.id}-${l.index}`, cells);
    }
  }
}

/** Updates the table rows and edge labels from a state message's links. */
function updateLinks(list) {
  for (const l of arr(list)) {
    if (!l) continue;
    const key = `${l.runtime}-${l.index}`;
    view.linkStats.set(key, l);
    const c = view.rows.get(key);
    if (!c) continue;
    c.rx.textContent = fmtBytes(l.rx_bytes_per_s);
    c.tx.textContent = fmtBytes(l.tx_bytes_per_s);
    // The link's rate: what it carries, in packet bytes per second.
    c.load.textContent = isNum(l.capacity_bytes_per_s)
      ? `${fmtPct(l.load)} of ${fmtBytes(l.capacity_bytes_per_s)}`
      : fmtPct(l.load);
    c.bar.className = loadClass(l.load);
    c.bar.style.width = isNum(l.load) ? `${Math.min(100, l.load * 100)}%` : "0";
    c.packets.textContent = `${l.packets_in ?? "–"} / ${l.packets_out ?? "–"}`;
    c.dropped.textContent = String(l.dropped ?? "–");
    c.dropped.className = isNum(l.dropped) && l.dropped > 0 ? "num warn" : "num";
  }
  for (const { edge, line, label } of view.edges) {
    // Either end measures the same link; prefer the side the label is named by.
    const s = view.linkStats.get(`${edge.from}-${edge.from_link}`) || view.linkStats.get(`${edge.to}-${edge.to_link}`);
    if (!s) continue;
    const total = (isNum(s.rx_bytes_per_s) ? s.rx_bytes_per_s : 0) + (isNum(s.tx_bytes_per_s) ? s.tx_bytes_per_s : 0);
    const kind = isNum(s.capacity_bytes_per_s)
      ? `${edge.kind ?? "link"} ${fmtBytes(s.capacity_bytes_per_s)}`
      : (edge.kind ?? "link");
    label.textContent = isNum(s.load) ? `${kind} · ${fmtBytes(total)} · ${fmtPct(s.load)}` : `${kind} · ${fmtBytes(total)}`;
    label.setAttribute("data-bytes-per-s", String(total));
    line.setAttribute("class", `edge ${loadClass(s.load)}`);
  }
}

// ---------- axes and faults ----------

/** A row in the axes or motors table, made the first time it is needed. */
function axisCell(kind, name) {
  const key = `${kind} ${name}`;
  let cell = view.axisRows.get(key);
  if (!cell) {
    cell = el("td", { class: "num" }, "–");
    $(kind === "axis" ? "axis-rows" : "motor-rows").appendChild(el("tr", {}, el("td", {}, String(name)), cell));
    view.axisRows.set(key, cell);
  }
  return cell;
}

function buildAxes(machine) {
  if (!machine) return;
  $("axes-panel").hidden = false;
  for (const a of arr(machine.axes)) axisCell("axis", typeof a === "object" && a ? a.name : a);
  for (const m of Object.keys(machine.modules || {})) axisCell("motor", m);
}

function updateAxes(axes, motors) {
  if (arr(axes).length || arr(motors).length) $("axes-panel").hidden = false;
  for (const a of arr(axes)) if (a) axisCell("axis", a.name).textContent = fmtPos(a.position);
  for (const m of arr(motors)) if (m) axisCell("motor", m.module).textContent = fmtPos(m.position);
}

/** Adds new fault events at the top of the log, keeping the newest 200. */
function addFaults(faults) {
  if (!Array.isArray(faults) || !faults.length) return;
  const body = $("fault-rows");
  for (const f of faults) {
    if (!f) continue;
    body.insertBefore(el("tr", {},
      el("td", { class: "num" }, fmtSeconds(f.time_us)), el("td", {}, String(f.module ?? "?")),
      el("td", { class: "fault-kind" }, String(f.kind ?? "?")),
      el("td", { class: "num" }, String(f.detail ?? "")), el("td", { class: "num" }, String(f.count ?? ""))),
    body.firstChild);
  }
  while (body.children.length > FAULT_KEEP) body.lastChild.remove();
  $("faults-empty").hidden = body.children.length > 0;
}

// ---------- state ----------

function applyState(msg) {
  window.osapView.state = msg;
  $("sync-time").textContent = isNum(msg.time_us) ? `${fmtSeconds(msg.time_us)} s` : "–";
  updateRuntimes(msg.runtimes);
  updateLinks(msg.links);
  updateAxes(msg.axes, msg.motors);
  addFaults(msg.faults);
  recordLive(msg);
  if ($("capture-file").value === LIVE) schedulePlot();
}

/** Appends positions to the live ring buffers, keeping the last 30 s. */
function recordLive(msg) {
  const t = msg.time_us;
  if (!isNum(t)) return;
  // A clock that jumps back (machine restarted) would fold the plot: start over.
  if (view.lastTime != null && t < view.lastTime - 1e6) view.live.clear();
  view.lastTime = t;
  const push = (kind, name, v) => {
    if (!isNum(v)) return;
    const key = `${kind} ${name}`;
    let s = view.live.get(key);
    if (!s) view.live.set(key, (s = { kind, name: key, t: [], v: [] }));
    s.t.push(t); s.v.push(v);
  };
  for (const a of arr(msg.axes)) if (a) push("axis", a.name, a.position);
  for (const m of arr(msg.motors)) if (m) push("motor", m.module, m.position);
  for (const s of view.live.values()) {
    let drop = 0;
    while (drop < s.t.length && (s.t[drop] < t - LIVE_WINDOW_US || s.t.length - drop > LIVE_MAX_POINTS)) drop++;
    if (drop) { s.t.splice(0, drop); s.v.splice(0, drop); }
  }
}

// ---------- function panel ----------

const INT_RE = /^([ui])(8|16|32|64|128)$/;
const FLOAT_RE = /^f(16|32|64)$/;
const TEXT_TYPES = new Set(["utf8", "ascii"]);

/** Whether the page can write a value of this type as text. */
const enterable = (type) => type === "bool" || INT_RE.test(type) || FLOAT_RE.test(type) || TEXT_TYPES.has(type);

const signature = (fn) => {
  const list = (xs) => (arr(xs)).map((x) => `${x.name}: ${x.type}`).join(", ");
  return `${fn.name}(${list(fn.inputs)}) -> (${list(fn.outputs)})`;
};

function pipeLines(fn) {
  return pipesOf(fn).map((p) => {
    const rt = view.byId.get(p.to_runtime);
    const to = rt ? `${rt.name}/${p.to_function ?? "?"}` : String(p.to_function ?? "?");
    return `slot ${p.slot ?? "?"} → ${to}`;
  });
}

/** Why `text` is not a value of `type` (as the server parses it), or null. */
function invalidArg(type, raw) {
  const text = raw.trim();
  if (type === "bool") return /^(true|false|1|0)$/.test(text) ? null : "write true, false, 1 or 0";
  const m = INT_RE.exec(type);
  if (m) {
    if (!/^[+-]?\d+$/.test(text)) return "write a whole number";
    const bits = BigInt(m[2]);
    const v = BigInt(text.replace(/^\+/, ""));
    const [lo, hi] = m[1] === "u" ? [0n, (1n << bits) - 1n] : [-(1n << (bits - 1n)), (1n << (bits - 1n)) - 1n];
    return v < lo || v > hi ? `out of range for ${type}` : null;
  }
  if (FLOAT_RE.test(type)) {
    return /^[+-]?(\d+\.?\d*|\.\d+)(e[+-]?\d+)?$/i.test(text) && Number.isFinite(Number(text)) ? null : "write a number";
  }
  if (type === "ascii" && !/^[\x00-\x7f]*$/.test(raw)) return "ASCII only";
  return null;
}

function openFunction(rt, fn, line) {
  view.current = { rt, fn };
  document.querySelectorAll(".fn.selected").forEach((n) => n.classList.remove("selected"));
  if (line) line.classList.add("selected");
  $("function-panel").hidden = false;
  $("fn-title").textContent = `${rt.name}/${fn.name}`;
  $("fn-signature").textContent = signature(fn);
  $("fn-pipes").replaceChildren(...pipeLines(fn).map((l) => el("li", {}, l)));
  const inputs = arr(fn.inputs);
  const box = $("fn-inputs");
  box.replaceChildren();
  inputs.forEach((inp, i) => {
    const id = `fn-arg${i}`;
    box.append(el("label", { for: id }, String(inp.name ?? `arg${i}`)),
      el("input", { id, name: `arg${i}`, placeholder: String(inp.type ?? ""), "data-type": inp.type ?? "" }));
  });
  const blocked = inputs.filter((inp) => !enterable(inp.type)).map((inp) => `${inp.name}: ${inp.type}`);
  $("fn-note").hidden = !blocked.length;
  $("fn-note").textContent = blocked.length ? `not callable from this page: ${blocked.join(", ")} cannot be typed as text` : "";
  $("call-button").disabled = blocked.length > 0 || view.inFlight;
  $("call-result").replaceChildren();
  $("function-panel").scrollIntoView({ block: "nearest" });
}

/** Checks every input, marking the bad ones; returns the args or null. */
function collectArgs(fn) {
  const form = $("call-form");
  form.querySelectorAll(".field-error").forEach((n) => n.remove());
  let ok = true;
  const args = arr(fn.inputs).map((inp, i) => {
    const input = form.elements.namedItem(`arg${i}`);
    const value = input ? input.value : "";
    const why = invalidArg(String(inp.type), value);
    if (input) input.classList.toggle("invalid", !!why);
    if (why) input?.insertAdjacentElement("afterend", el("span", { class: "field-error" }, why));
    ok &&= !why;
    return value;
  });
  return ok ? args : null;
}

async function callCurrent(ev) {
  ev.preventDefault();
  const cur = view.current;
  if (!cur || view.inFlight || $("call-button").disabled) return;
  const args = collectArgs(cur.fn);
  if (!args) return;
  view.inFlight = true;
  $("call-button").disabled = true;
  $("call-result").replaceChildren(el("span", { class: "pending" }, "calling…"));
  let result;
  try {
    const body = JSON.stringify({ runtime: cur.rt.name, function: cur.fn.name, args });
    result = await fetchJSON("api/call", { method: "POST", headers: { "content-type": "application/json" }, body });
  } catch (e) {
    result = { ok: false, error: e.message || String(e) };
  }
  view.inFlight = false;
  // Only show the answer if the panel still shows the function that was called.
  if (view.current === cur) showCallResult(result);
  $("call-button").disabled = !$("fn-note").hidden;
  window.osapView.calls += 1;
}

function showCallResult(r) {
  const out = $("call-result");
  if (!r || !r.ok) {
    out.replaceChildren(el("div", { class: "error" }, String((r && r.error) || "the call failed")));
    return;
  }
  const outputs = arr(r.outputs);
  const show = (v) => (typeof v === "string" ? v : JSON.stringify(v));
  out.replaceChildren(...(outputs.length
    ? outputs.map((o) => el("div", {}, `${o.name} = ${show(o.value)}`))
    : [el("div", { class: "pending" }, "done (no outputs)")]));
}

// ---------- plot ----------

async function loadCaptureList() {
  const sel = $("capture-file");
  try {
    const r = await fetchJSON("api/captures");
    const keep = sel.value;
    while (sel.options.length > 1) sel.remove(1);
    for (const f of arr(r.files)) sel.add(new Option(String(f), String(f)));
    sel.value = [...sel.options].some((o) => o.value === keep) ? keep : LIVE;
  } catch (e) {
    $("plot-status").textContent = `captures: ${e.message}`;
  }
}

async function chooseCapture() {
  const file = $("capture-file").value;
  const status = $("plot-status");
  view.capture = null;
  status.textContent = "";
  if (file === LIVE) return drawPlot();
  status.textContent = "loading…";
  drawPlot();
  try {
    const r = await fetchJSON("api/capture", {}, { file });
    if ($("capture-file").value !== file) return; // chosen something else meanwhile
    view.capture = arr(r.series).map((s) => ({ name: String(s?.name), t: arr(s?.time_us), v: arr(s?.value) }));
    status.textContent = "";
  } catch (e) {
    status.textContent = e.message;
  }
  drawPlot();
}

function schedulePlot() {
  if (view.plotTimer) return;
  const wait = Math.max(0, PLOT_MIN_MS - (performance.now() - view.lastPlot));
  view.plotTimer = setTimeout(() => { view.plotTimer = null; drawPlot(); }, wait);
}

/** The series to draw: live axes (else motors), or the capture file's. */
function plotSeries() {
  if ($("capture-file").value !== LIVE) return view.capture || [];
  const all = [...view.live.values()].filter((s) => s.t.length);
  const axes = all.filter((s) => s.kind === "axis");
  return axes.length ? axes : all;
}

/** Tick values covering [lo, hi] at a 1-2-5 step. */
function ticks(lo, hi, n) {
  const raw = (hi - lo) / n || 1;
  const mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw) || raw;
  const digits = Math.max(0, -Math.floor(Math.log10(step)));
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9 && out.length < 50; v += step) out.push(v);
  return out.map((v) => ({ v, label: v.toFixed(Math.min(digits, 10)) }));
}

function drawPlot() {
  view.lastPlot = performance.now();
  const canvas = $("plot");
  const dpr = window.devicePixelRatio || 1;
  const W = canvas.clientWidth || 600;
  const H = canvas.clientHeight || 280;
  canvas.width = Math.round(W * dpr);
  canvas.height = Math.round(H * dpr);
  const ctx = canvas.getContext("2d");
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, W, H);
  ctx.font = "11px system-ui, sans-serif";
  const series = plotSeries();
  const top = drawLegend(ctx, series, W);
  let t0 = Infinity, t1 = -Infinity, v0 = Infinity, v1 = -Infinity;
  for (const s of series) {
    for (let i = 0; i < s.t.length; i++) {
      if (!isNum(s.t[i]) || !isNum(s.v[i])) continue;
      t0 = Math.min(t0, s.t[i]); t1 = Math.max(t1, s.t[i]);
      v0 = Math.min(v0, s.v[i]); v1 = Math.max(v1, s.v[i]);
    }
  }
  if (!Number.isFinite(t0)) {
    ctx.fillStyle = "#6b7480";
    ctx.textAlign = "center";
    ctx.fillText($("capture-file").value === LIVE ? "no axis positions yet" : "no data", W / 2, H / 2);
    return;
  }
  if (v1 - v0 < 1e-12) { const d = Math.abs(v0) * 0.1 || 1; v0 -= d; v1 += d; }
  const pad = (v1 - v0) * 0.05;
  v0 -= pad; v1 += pad;
  const yt = ticks(v0, v1, 5);
  const left = Math.max(40, ...yt.map((t) => ctx.measureText(t.label).width + 14));
  const box = { l: left, r: W - 12, t: top, b: H - 36 };
  const xs = Math.max(1e-6, (t1 - t0) / 1e6); // seconds shown
  const px = (t) => box.l + ((t - t0) / 1e6 / xs) * (box.r - box.l);
  const py = (v) => box.b - ((v - v0) / (v1 - v0)) * (box.b - box.t);

  drawAxes(ctx, box, ticks(0, xs, Math.max(2, (box.r - box.l) / 90)), xs, yt, py);
  ctx.save();
  ctx.beginPath();
  ctx.rect(box.l, box.t, box.r - box.l, box.b - box.t);
  ctx.clip();
  series.forEach((s, k) => drawLine(ctx, s, PALETTE[k % PALETTE.length], px, py));
  ctx.restore();
}

function drawAxes(ctx, box, xt, xs, yt, py) {
  ctx.strokeStyle = "#e3e6ea";
  ctx.fillStyle = "#6b7480";
  ctx.lineWidth = 1;
  ctx.textAlign = "right";
  ctx.textBaseline = "middle";
  for (const { v, label } of yt) {
    const y = Math.round(py(v)) + 0.5;
    ctx.beginPath(); ctx.moveTo(box.l, y); ctx.lineTo(box.r, y); ctx.stroke();
    ctx.fillText(label, box.l - 6, y);
  }
  ctx.textAlign = "center";
  ctx.textBaseline = "top";
  for (const { v, label } of xt) {
    const x = Math.round(box.l + (v / xs) * (box.r - box.l)) + 0.5;
    ctx.beginPath(); ctx.moveTo(x, box.t); ctx.lineTo(x, box.b); ctx.stroke();
    ctx.fillText(label, x, box.b + 4);
  }
  ctx.fillText("synchronized time, s", (box.l + box.r) / 2, box.b + 19);
  ctx.strokeStyle = "#9aa3ad";
  ctx.strokeRect(box.l + 0.5, box.t + 0.5, box.r - box.l, box.b - box.t);
}

/** One series; missing values lift the pen, a lone point becomes a dot. */
function drawLine(ctx, s, colour, px, py) {
  ctx.strokeStyle = colour;
  ctx.fillStyle = colour;
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  let pen = false;
  let points = 0;
  for (let i = 0; i < s.t.length; i++) {
    if (!isNum(s.t[i]) || !isNum(s.v[i])) { pen = false; continue; }
    const x = px(s.t[i]), y = py(s.v[i]);
    if (pen) ctx.lineTo(x, y); else ctx.moveTo(x, y);
    pen = true;
    points++;
  }
  ctx.stroke();
  if (points === 1) {
    const i = s.t.findIndex((t, j) => isNum(t) && isNum(s.v[j]));
    ctx.beginPath(); ctx.arc(px(s.t[i]), py(s.v[i]), 2.5, 0, 2 * Math.PI); ctx.fill();
  }
}

/** Legend rows above the plot; returns where the plot area starts. */
function drawLegend(ctx, series, W) {
  let x = 60, y = 8;
  ctx.textAlign = "left";
  ctx.textBaseline = "top";
  series.forEach((s, k) => {
    const w = ctx.measureText(s.name).width + 26;
    if (x + w > W - 12 && x > 60) { x = 60; y += 16; }
    ctx.fillStyle = PALETTE[k % PALETTE.length];
    ctx.fillRect(x, y + 4, 12, 4);
    ctx.fillStyle = "#1d2228";
    ctx.fillText(s.name, x + 16, y);
    x += w;
  });
  return y + (series.length ? 24 : 8);
}

// ---------- start ----------

function showInfo(info) {
  view.info = info;
  window.osapView.info = info;
  const title = String(info.title ?? "osap view");
  $("title").textContent = title;
  document.title = `${title} · osap view`;
  const runtimes = arr(info.runtimes);
  for (const rt of runtimes) view.byId.set(rt.id, rt);
  drawGraph(info);
  buildLinkRows(runtimes);
  buildAxes(info.machine);
}

async function start() {
  $("call-form").addEventListener("submit", callCurrent);
  $("fn-close").addEventListener("click", () => {
    $("function-panel").hidden = true;
    document.querySelectorAll(".fn.selected").forEach((n) => n.classList.remove("selected"));
  });
  $("capture-file").addEventListener("change", chooseCapture);
  $("capture-refresh").addEventListener("click", loadCaptureList);
  window.addEventListener("resize", schedulePlot);
  drawPlot();
  await loadInfo();
  if (view.authFailed) return;
  connect();
  loadCaptureList();
}

async function loadInfo() {
  try {
    showInfo(await fetchJSON("api/info"));
    if (!view.authFailed) $("error").hidden = true;
  } catch (e) {
    if (!view.authFailed) showBanner(`could not read the network: ${e.message}`);
  }
}

start();
