// The review page of `pcreg view RUN_OUT --web`: a run's frames with their labels drawn over them
// (/overlay/T.jpg, rendered by pcreg when asked for), a slider and the arrow keys to move, the key frames
// marked, the predicted error per frame as a plot (click a point to go there; with the truth, the error against it
// beside it, dashed) and the suggested frames.
"use strict";

// $ and el: viz/common.js
const SVG = "http://www.w3.org/2000/svg";
const svg = (tag, attrs = {}) => {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  return e;
};
const MAX_POINTS = 2000; // beyond this many frames the plot draws the line only (a click still picks the frame)

const state = { data: null, current: -1, labels: true, suggested: new Map(), plot: null, preloaded: new Map(), scored: false };

function rgb(c) { return `rgb(${c[0]}, ${c[1]}, ${c[2]})`; }
function pct(v) { return v === null || v === undefined ? "n/a" : `${v.toFixed(1)} %`; }

function imageUrl(t) { return `/${state.labels ? "overlay" : "frame"}/${t}.jpg`; }

function preload(t) { // the neighbours' pictures, so that stepping shows them at once
  const n = state.data.frames.length;
  for (const u of [t + 1, t - 1, t + 2]) {
    if (u < 0 || u >= n) continue;
    const url = imageUrl(u);
    if (state.preloaded.has(url)) continue;
    const img = new Image();
    img.src = url;
    state.preloaded.set(url, img);
    if (state.preloaded.size > 64) state.preloaded.delete(state.preloaded.keys().next().value);
  }
}

function show(t) {
  const frames = state.data.frames;
  t = Math.max(0, Math.min(frames.length - 1, t));
  const f = frames[t];
  state.current = t;
  document.body.dataset.frame = String(t);
  $("slider").value = String(t);
  const img = $("overlay");
  const url = imageUrl(t);
  img.dataset.wanted = url;
  img.onload = () => { if (img.dataset.wanted === url) document.body.dataset.shown = url; };
  img.onerror = () => { if (img.dataset.wanted === url) frameError(url); };
  img.src = url;
  $("frame-name").textContent = `${f.name}  (${t + 1}/${frames.length})`;
  const tag = $("frame-tag");
  const suggested = state.suggested.get(t);
  tag.hidden = !(f.key || suggested !== undefined);
  tag.textContent = f.key ? "key frame" : "suggested";
  tag.className = f.key ? "tag" : "tag suggested";
  const truth = f.truth_error === null || f.truth_error === undefined ? "" : `, against the truth ${pct(f.truth_error)}`;
  $("frame-error").textContent = f.key ? "labelled by a person" : `predicted error ${pct(f.error)}${truth}` +
    (f.no_confidence ? `; no confidence map (${f.no_confidence} is missing): drawn without the hatching` : "");
  for (const li of document.querySelectorAll("li[data-frame]")) li.classList.toggle("current", Number(li.dataset.frame) === t);
  drawCursor();
  preload(t);
  drawClassFigures(t);
}

// why a frame's picture did not come: pcreg's one line naming the file (a label image cut short, say)
async function frameError(url) {
  let why = "this frame could not be read";
  try {
    const r = await fetch(url);
    if (!r.ok) why = (await r.text()).trim() || why;
  } catch (e) { /* the server is gone: the plain message */ }
  if ($("overlay").dataset.wanted === url) $("frame-error").textContent = why;
}

// each class's share of the frame and its predicted IoU (with --truth, its IoU against the truth after it), beside
// its name in the legend (none when the frame's
// label image cannot be read: not the figures of the frame shown before); a frame without an IoU (a key frame)
// keeps its room, unseen, so that the legend does not wrap anew and move the frame from one frame to the next
async function drawClassFigures(t) {
  let figures = [];
  try {
    const r = await fetch(`/classes/${t}.json`);
    if (r.ok) figures = await r.json();
  } catch (e) { /* the server is gone: no figures */ }
  if (state.current !== t) return;
  for (const span of document.querySelectorAll("#legend span[data-class]")) span.textContent = "";
  for (const f of figures) {
    const span = document.querySelector(`#legend span[data-class="${f.id}"]`);
    if (!span) continue;
    const scored = f.truth_iou === null || f.truth_iou === undefined ? "" : `, IoU ${f.truth_iou.toFixed(2)} against the truth`;
    const iou = f.iou === null || f.iou === undefined ? null : `, predicted IoU ${f.iou.toFixed(2)}${scored}`;
    span.textContent = ` ${f.share.toFixed(1)} %${iou === null ? "" : iou}`;
    if (iou === null && state.data.ious) {
      const room = document.createElement("span");
      room.className = "room";
      room.textContent = ", predicted IoU 0.00" + (state.scored ? ", IoU 0.00 against the truth" : "");
      span.append(room);
    }
  }
  document.body.dataset.figures = String(t); // the legend filled in for this frame: the layout stands
}

// -- the plot --------------------------------------------------------------------------------------

function niceStep(v) { // the smallest of 1, 2, 5 x 10^k at least v
  if (!(v > 0)) return 1;
  const p = Math.pow(10, Math.floor(Math.log10(v)));
  for (const m of [1, 2, 5, 10]) if (m * p >= v - 1e-12) return m * p;
  return 10 * p;
}

function drawPlot() {
  const frames = state.data.frames;
  const n = frames.length;
  const W = 400, H = 220, L = 38, R = 10, T = 10, B = 26;
  const errs = frames.map((f) => (f.key ? null : f.error));
  const truths = frames.map((f) => (f.key || f.truth_error === undefined ? null : f.truth_error));
  const scored = state.scored;
  // not Math.max(...errs): past about 120,000 arguments (an hour's run at 30 frames a second) it throws
  const highest = errs.concat(truths).reduce((m, e) => (e !== null && e > m ? e : m), 0);
  const yStep = niceStep(highest / 5);
  const top = Math.max(yStep, Math.ceil(highest / yStep - 1e-9) * yStep);
  const x = (t) => L + (n > 1 ? (t / (n - 1)) * (W - L - R) : (W - L - R) / 2);
  const y = (e) => T + (1 - e / top) * (H - T - B);
  const root = svg("svg", { viewBox: `0 0 ${W} ${H}`, role: "img", "aria-label": "predicted error per frame" });
  for (let i = 0; i <= Math.round(top / yStep); i++) {
    const v = i * yStep;
    root.append(svg("line", { class: "grid", x1: L, x2: W - R, y1: y(v), y2: y(v) }));
    const label = svg("text", { class: "tick", x: L - 4, y: y(v) + 3, "text-anchor": "end" });
    label.textContent = `${+v.toFixed(2)}%`;
    root.append(label);
  }
  root.append(svg("line", { class: "axis", x1: L, x2: W - R, y1: H - B, y2: H - B }));
  const xStep = Math.max(1, niceStep((n - 1) / 6));
  for (let t = 0; t < n; t += xStep) {
    const label = svg("text", { class: "tick", x: x(t), y: H - B + 14, "text-anchor": "middle" });
    label.textContent = String(t);
    root.append(label);
  }
  const line = (values) => {
    let d = "";
    let pen = false;
    values.forEach((e, t) => {
      if (e === null) { pen = false; return; }
      d += `${pen ? "L" : "M"}${x(t).toFixed(1)},${y(e).toFixed(1)}`;
      pen = true;
    });
    return d;
  };
  if (scored) root.append(svg("path", { class: "series truth", d: line(truths) }));
  root.append(svg("path", { class: "series", d: line(errs) }));
  frames.forEach((f, t) => {
    if (!f.key) return;
    const mark = svg("path", { class: "keymark", d: `M${x(t)},${H - B - 9}l5,9h-10z`, "data-frame": t });
    const title = svg("title");
    title.textContent = `${f.name}: key frame`;
    mark.append(title);
    root.append(mark);
  });
  const cursor = svg("line", { class: "cursor", x1: 0, x2: 0, y1: T, y2: H - B });
  root.append(cursor);
  const points = [];
  if (errs.filter((e) => e !== null).length <= MAX_POINTS) {
    errs.forEach((e, t) => {
      if (e === null) return;
      const c = svg("circle", { class: "point" + (state.suggested.has(t) ? " suggested" : ""), cx: x(t), cy: y(e), r: n > 300 ? 2.5 : 4, "data-frame": t });
      const title = svg("title");
      title.textContent = `${frames[t].name}: ${pct(e)}`;
      c.append(title);
      c.addEventListener("click", (ev) => { ev.stopPropagation(); show(t); });
      root.append(c);
      points[t] = c;
    });
  }
  root.addEventListener("click", (ev) => { // anywhere on the plot: the frame under the pointer
    const box = root.getBoundingClientRect();
    const px = ((ev.clientX - box.left) / box.width) * W;
    show(Math.round(n > 1 ? ((px - L) / (W - L - R)) * (n - 1) : 0));
  });
  $("plot").replaceChildren(root);
  $("plot-key").hidden = !scored;
  state.plot = { x, cursor, points };
}

function drawCursor() {
  const p = state.plot;
  if (!p) return;
  const t = state.current;
  p.cursor.setAttribute("x1", p.x(t));
  p.cursor.setAttribute("x2", p.x(t));
  for (const c of document.querySelectorAll("circle.point.current")) c.classList.remove("current");
  if (p.points[t]) p.points[t].classList.add("current");
}

// -- the lists and the legend ----------------------------------------------------------------------

function frameLink(t, text) {
  const a = el("a", { text, href: `#${t}` });
  a.addEventListener("click", (ev) => { ev.preventDefault(); show(t); });
  return a;
}

function drawLists() {
  const d = state.data;
  const sug = $("suggested");
  sug.replaceChildren();
  for (const s of d.suggested) {
    const li = el("li", { "data-frame": s.frame }, frameLink(s.frame, s.name));
    if (s.error !== null) li.append(el("span", { class: "muted", text: ` predicted error ${pct(s.error)}` }));
    sug.append(li);
  }
  $("suggest-card").hidden = d.suggested.length === 0;
  const keys = $("keys");
  keys.replaceChildren();
  d.frames.forEach((f, t) => { if (f.key) keys.append(el("li", { "data-frame": t }, frameLink(t, f.name))); });
}

function drawLegend() {
  const d = state.data;
  const item = (cls, style, text) => {
    const s = el("span", { class: "swatch " + cls });
    if (style) s.style.background = style;
    return el("span", {}, s, text);
  };
  // each class the run's frames show, in the table's order and colours, then its unknown (left clear); the
  // table's other classes (a table of 150 labels a few in a run) counted, named on hover
  const shown = d.classes.filter((c) => c.shown !== false);
  const items = shown.map((c) => {
    const it = item("", rgb(c.colour), c.name);
    it.append(el("span", { class: "muted", "data-class": c.id }));
    return it;
  });
  items.push(item("clear", null, d.unknown.name));
  const absent = d.classes.filter((c) => c.shown === false);
  if (absent.length) {
    const more = el("span", { class: "muted", text: `${absent.length} other class${absent.length > 1 ? "es" : ""} of the table in no frame` });
    more.title = absent.map((c) => c.name).join("\n");
    items.push(more);
  }
  if (d.confidence) items.push(item("hatch", null, `confidence below ${Math.round(d.low_confidence * 100)} %`));
  items.push(item("key", null, "key frame"));
  $("legend").replaceChildren(...items);
}

function truthFact(frames) { // a run scored against the truth (--truth): its frames' mean error against it
  const errs = frames.filter((f) => !f.key && f.truth_error !== null && f.truth_error !== undefined).map((f) => f.truth_error);
  return errs.length ? [["mean error against the truth", pct(errs.reduce((a, b) => a + b, 0) / errs.length)]] : [];
}

function drawHeader() {
  const d = state.data;
  const folder = d.folder.split("/").filter(Boolean).pop() || d.folder;
  $("title").textContent = `Run ${folder}`;
  document.title = `pcreg review: ${folder}`;
  const errs = d.frames.filter((f) => !f.key && f.error !== null).map((f) => f.error);
  const mean = errs.length ? errs.reduce((a, b) => a + b, 0) / errs.length : null;
  const facts = [["folder", d.folder], ["source", d.source], ["frames", String(d.frames.length)],
    ["key frames", String(d.frames.filter((f) => f.key).length)],
    ["mean predicted error", pct(mean)], ...truthFact(d.frames), ["confidence", d.confidence ? "yes" : "not recorded (run --confidence)"]];
  if (d.gaps) facts.push(["frames missing by the video's times", `about ${d.gaps.missing} at ${d.gaps.places} place(s)`]);
  $("facts").replaceChildren(...facts.map(([k, v]) => el("span", { class: "fact" }, el("em", { text: k }), v)));
  // a video that skips frames: the run's frames are numbered by count, not by the file's timeline
  $("gaps").hidden = !d.gaps;
  $("gaps").textContent = d.gaps ? d.gaps.note : "";
  // what reading the frames met (transparent pixels, a turn to interlaced), each kind's line as the run said it
  const notes = d.notes || [];
  $("notes").hidden = !notes.length;
  $("notes").replaceChildren(...notes.map((text) => el("p", { class: "gaps", text })));
}

// -- start -----------------------------------------------------------------------------------------

async function main() {
  let data;
  try {
    const r = await fetch("/review.json");
    data = await r.json();
  } catch (err) {
    $("title").textContent = `The run could not be loaded: ${err.message || err}`;
    return;
  }
  state.data = data;
  state.scored = data.frames.some((f) => f.truth_error !== null && f.truth_error !== undefined); // run --truth
  for (const s of data.suggested) state.suggested.set(s.frame, s.error);
  const slider = $("slider");
  slider.max = String(data.frames.length - 1);
  slider.addEventListener("input", () => show(Number(slider.value)));
  $("prev").addEventListener("click", () => show(state.current - 1));
  $("next").addEventListener("click", () => show(state.current + 1));
  $("show-labels").addEventListener("change", (ev) => { state.labels = ev.target.checked; state.preloaded.clear(); show(state.current); });
  document.addEventListener("keydown", (ev) => {
    if (ev.altKey || ev.ctrlKey || ev.metaKey) return;
    const step = ev.shiftKey ? 10 : 1;
    if (ev.key === "ArrowRight") { show(state.current + step); ev.preventDefault(); }
    else if (ev.key === "ArrowLeft") { show(state.current - step); ev.preventDefault(); }
    else if (ev.key === "Home") { show(0); ev.preventDefault(); }
    else if (ev.key === "End") { show(data.frames.length - 1); ev.preventDefault(); }
    else if (ev.key === "l" || ev.key === "L") { $("show-labels").click(); }
  });
  drawHeader();
  drawLegend();
  drawLists();
  drawPlot();
  const fromHash = Number(location.hash.slice(1));
  show(Number.isInteger(fromHash) && location.hash ? fromHash : 0);
  document.body.dataset.loaded = "1";
}

main();
