// The report page of `pcreg view OUT_DIR --web`: the evaluation's tables (from results.json, served as
// /report.json), checks and figures, with the run's recording in rerun's web viewer beside them.
// Choosing a row with a recording frame moves the viewer's time cursor there, through the viewer's
// control API (WebHandle.viewer_control, which takes an encoded ViewerControlRequest).
"use strict";

// $ and el: viz/common.js

// -- the viewer's control messages (protobuf, rerun.viewer_control.v1alpha1) ----------------------

function varint(n) {
  const out = [];
  while (n > 127) { out.push((n % 128) | 128); n = Math.floor(n / 128); }
  out.push(n);
  return out;
}
const lengthField = (num, bytes) => [...varint((num << 3) | 2), ...varint(bytes.length), ...bytes];
const varintField = (num, value) => [...varint(num << 3), ...varint(value)];

// ViewerControlRequest.set_time_cursor (6) = SetTimeCursorRequest { timeline (2): Timeline { name (1) },
// time (3): TimelineTime { time (1) }, play_state (5): PLAY_STATE_PAUSED (1) }
function setTimeCursor(timeline, frame) {
  const request = [
    ...lengthField(2, lengthField(1, [...new TextEncoder().encode(timeline)])),
    ...lengthField(3, varintField(1, frame)),
    ...varintField(5, 1),
  ];
  return new Uint8Array(lengthField(6, request));
}

function fields(bytes) { // one protobuf message's fields: [number, value (a number or the bytes)]
  const out = [];
  let p = 0;
  const read = () => { let v = 0, s = 1, c; do { c = bytes[p++]; v += (c & 127) * s; s *= 128; } while (c & 128); return v; };
  while (p < bytes.length) {
    const tag = read(), num = Math.floor(tag / 8), wire = tag & 7;
    if (wire === 0) out.push([num, read()]);
    else if (wire === 2) { const n = read(); out.push([num, bytes.subarray(p, p + n)]); p += n; }
    else if (wire === 1) { p += 8; } else if (wire === 5) { p += 4; } else break;
  }
  return out;
}
const field = (bytes, num) => (fields(bytes).find(([n]) => n === num) || [])[1];

// ViewerControlResponse.set_time_cursor (6) -> SetTimeCursorResponse.time (4) -> TimelineTime.time (1)
function answeredTime(bytes) {
  const answer = field(new Uint8Array(bytes), 6);
  const time = answer && field(answer, 4);
  return time ? field(time, 1) || 0 : null;
}

// -- the recording ---------------------------------------------------------------------------------

const rec = { frame: null, wanted: null, handle: null, timeline: "frame", iframe: null };

function status(text, kind = "") {
  const s = $("rec-status");
  s.textContent = text;
  s.className = "status " + kind;
}

function embedRecording(info) {
  rec.timeline = info.timeline;
  const data = `rerun+http://${location.hostname}:${info.grpc_port}/proxy`;
  const src = `${info.viewer}?url=${encodeURIComponent(data)}&persist=0&hide_welcome_screen`;
  rec.iframe = el("iframe", { id: "viewer", title: "rerun web viewer", src });
  $("rec-empty").remove();
  $("rec-body").append(rec.iframe);
  const open = $("rec-open");
  open.href = src;
  open.hidden = false;
  status("starting the viewer…");
  window.addEventListener("message", (e) => {
    if (e.data === "READY" && e.source === rec.iframe.contentWindow) viewerReady();
  });
}

function viewerReady() {
  const handle = rec.iframe.contentWindow._handle;
  if (!handle || typeof handle.viewer_control !== "function") {
    status("this viewer cannot be moved from the page: use its timeline", "bad");
    return;
  }
  rec.handle = handle;
  for (const panel of ["blueprint", "selection"]) {
    try { handle.override_panel_state(panel, "collapsed"); } catch (err) { /* an older viewer */ }
  }
  status("ready: choose a row");
  if (rec.wanted !== null) seek(rec.wanted);
}

function seek(frame, tries = 40) {
  rec.wanted = frame;
  if (!rec.handle) { status(`frame ${frame} once the viewer has started…`); return; }
  status(`moving to frame ${frame}…`);
  rec.handle.viewer_control(setTimeCursor(rec.timeline, frame)).then((answer) => {
    if (rec.wanted !== frame) return;
    const t = answeredTime(answer);
    rec.frame = t === null ? frame : t;
    document.body.dataset.recordingFrame = String(rec.frame);
    status(`${rec.timeline} ${rec.frame}`, "ok");
  }).catch((err) => { // the recording is still arriving: try again shortly
    if (rec.wanted !== frame) return;
    if (tries > 0) setTimeout(() => seek(frame, tries - 1), 250);
    else status(`could not move to frame ${frame}: ${err.message || err}`, "bad");
  });
}

// -- the report ------------------------------------------------------------------------------------

function fmt(v, float, digits) {
  if (v === null || v === undefined) return "n/a";
  if (typeof v === "number") return float ? v.toFixed(digits ?? 2) : String(v);
  return String(v);
}

function shade(values, better) { // background of the compared cells: best green, worst red, pale
  const nums = values.filter((v) => typeof v === "number");
  if (nums.length < 2) return values.map(() => null);
  const lo = Math.min(...nums), hi = Math.max(...nums);
  return values.map((v) => {
    if (typeof v !== "number" || hi === lo) return null;
    let t = (v - lo) / (hi - lo);
    if (better === "higher") t = 1 - t;
    return { colour: `hsl(${Math.round(140 - 130 * t)}, 70%, ${Math.round(88 + 4 * t)}%)`, best: t === 0 };
  });
}

function renderTable(t) {
  const wrap = el("section", { class: "card table-card", id: `table-${t.name}` });
  const seekable = t.rows.some((r) => r.frame !== null && r.frame !== undefined);
  wrap.append(el("h2", { text: t.title }));
  if (seekable) wrap.append(el("p", { class: "hint", text: `Choose ${t.select} to see it in the recording.` }));
  const table = el("table", { "data-name": t.name });
  const head = el("tr");
  if (seekable) head.append(el("th", { class: "frame", text: "rec.", title: "the frame of the recording this row shows" }));
  t.columns.forEach((c, i) => head.append(el("th", { text: c.replace(/_/g, " "), class: t.errors.includes(i) ? "num metric" : "" })));
  table.append(el("thead", {}, head));
  const body = el("tbody");
  for (const row of t.rows) {
    const tr = el("tr");
    const compared = shade(t.errors.map((i) => row.cells[i]), t.better);
    if (seekable) {
      const has = row.frame !== null && row.frame !== undefined;
      tr.append(el("td", { class: "frame", text: has ? `▶ ${row.frame}` : "" }));
      if (has) {
        tr.dataset.frame = row.frame;
        tr.tabIndex = 0;
        tr.classList.add("seekable");
        const choose = () => {
          document.querySelectorAll("tr.chosen").forEach((r) => r.classList.remove("chosen"));
          tr.classList.add("chosen");
          seek(row.frame);
        };
        tr.addEventListener("click", choose);
        tr.addEventListener("keydown", (e) => { if (e.key === "Enter" || e.key === " ") { e.preventDefault(); choose(); } });
      }
    }
    row.cells.forEach((v, i) => {
      const td = el("td", { text: fmt(v, row.floats.includes(i), t.digits) });
      if (typeof v === "number") { td.classList.add("num"); td.dataset.value = String(v); td.title = String(v); }
      const k = t.errors.indexOf(i);
      if (k >= 0 && compared[k]) {
        td.style.background = compared[k].colour;
        if (compared[k].best) td.classList.add("best");
      }
      tr.append(td);
    });
    body.append(tr);
  }
  table.append(body);
  wrap.append(el("div", { class: "scroll" }, table));
  for (const text of t.footer || []) wrap.append(el("p", { class: "footer" }, inline(text)));
  return wrap;
}

function inline(text) { // **bold** and `code` of the checks' Markdown, as text nodes
  const span = el("span");
  text.split(/(\*\*[^*]+\*\*|`[^`]+`)/).forEach((part) => {
    if (part.startsWith("**") && part.endsWith("**")) span.append(el("strong", { text: part.slice(2, -2) }));
    else if (part.startsWith("`") && part.endsWith("`")) span.append(el("code", { text: part.slice(1, -1) }));
    else span.append(part);
  });
  return span;
}

function renderChecks(md) {
  const body = $("checks-body");
  let list = null;
  let met = 0, failed = 0;
  for (const raw of md.split("\n")) {
    const line = raw.trim();
    if (!line) { list = null; continue; }
    if (line.startsWith("#")) {
      const text = line.replace(/^#+\s*/, "").replace(/^Checks:?\s*/, "");
      if (text) body.append(el("h3", { text }));
      list = null;
    } else if (line.startsWith("- ")) {
      if (!list) { list = el("ul", { class: "checks" }); body.append(list); }
      const text = line.slice(2);
      const bad = /NOT met/.test(text), ok = !bad && /:\s*met\b/.test(text);
      met += ok; failed += bad;
      list.append(el("li", { class: bad ? "bad" : ok ? "ok" : "info" }, inline(text)));
    } else {
      body.append(el("p", {}, inline(line)));
      list = null;
    }
  }
  return { met, failed };
}

function renderConfig(config, into) {
  const dl = el("dl", { class: "config" });
  for (const [k, v] of Object.entries(config || {})) {
    dl.append(el("dt", { text: k }), el("dd", { text: typeof v === "object" && v !== null ? JSON.stringify(v) : String(v) }));
  }
  into.append(dl);
}

function fact(label, value) { return el("span", { class: "fact" }, el("em", { text: label }), String(value)); }

function render(r) {
  document.title = `pcreg report: ${r.experiment} (${r.folder})`;
  $("title").textContent = r.title;
  const c = r.config || {};
  const facts = $("facts");
  facts.append(fact("folder", r.path));
  if (c.data) facts.append(fact("data", c.data));
  if (c.size) facts.append(fact("size", Array.isArray(c.size) ? c.size.join("×") : c.size));
  if (c.frames) facts.append(fact("frames", c.frames));
  if (c.backends) facts.append(fact("backends", [].concat(c.backends).join(", ")));
  if (c.increments) facts.append(fact("k", [].concat(c.increments).join(", ")));
  if (c.angles) facts.append(fact("angles", [].concat(c.angles).join(", ")));
  if (typeof r.seconds === "number") facts.append(fact("ran", `${r.seconds.toFixed(1)} s`));

  const toc = $("toc");
  if (r.checks) {
    $("checks").hidden = false;
    const { met, failed } = renderChecks(r.checks);
    const text = failed ? `Checks: ${failed} not met, ${met} met` : met ? `Checks: all ${met} met` : "Checks";
    toc.append(el("a", { href: "#checks", class: failed ? "bad" : met ? "ok" : "", text }));
  }
  for (const t of r.tables) {
    $("tables").append(renderTable(t));
    toc.append(el("a", { href: `#table-${t.name}`, text: t.title.split(",")[0].split(" (")[0] }));
  }
  if (r.notes && r.notes.length) {
    $("tables").append(el("section", { class: "card notes" }, el("h2", { text: "Notes" }), el("ul", {}, ...r.notes.map((n) => el("li", { text: n })))));
  }
  if (r.figures.length) {
    $("figures").hidden = false;
    toc.append(el("a", { href: "#figures", text: `Figures (${r.figures.length})` }));
    for (const f of r.figures) {
      const img = el("img", { src: `/files/${encodeURIComponent(f)}`, alt: f, loading: "lazy" });
      img.addEventListener("click", () => { $("lightbox").querySelector("img").src = img.src; $("lightbox").hidden = false; });
      $("figures-body").append(el("figure", {}, img, el("figcaption", { text: f })));
    }
  }
  renderConfig(r.config, $("config"));
  const files = $("files");
  files.append("Files: ");
  r.files.forEach((f, i) => { if (i) files.append(", "); files.append(el("a", { href: `/files/${encodeURIComponent(f)}`, target: "_blank", text: f })); });

  if (r.recording) {
    embedRecording(r.recording);
    const first = document.querySelector("tr.seekable");
    if (first) { first.classList.add("chosen"); rec.wanted = Number(first.dataset.frame); }
  } else {
    document.body.classList.add("no-recording");
  }
  document.body.dataset.loaded = "1";
}

// the splitter between report and recording: drag to share the width, double-click to reset
$("splitter").addEventListener("pointerdown", (e) => {
  const split = $("split");
  const move = (m) => {
    const right = split.getBoundingClientRect().right - m.clientX;
    document.documentElement.style.setProperty("--rec-width", `${Math.max(320, Math.min(right, innerWidth - 360))}px`);
  };
  const up = () => { document.body.classList.remove("dragging"); removeEventListener("pointermove", move); removeEventListener("pointerup", up); };
  document.body.classList.add("dragging");
  addEventListener("pointermove", move);
  addEventListener("pointerup", up);
  e.preventDefault();
});
$("splitter").addEventListener("dblclick", () => document.documentElement.style.removeProperty("--rec-width"));

$("lightbox").addEventListener("click", () => { $("lightbox").hidden = true; });

fetch("/report.json")
  .then((r) => { if (!r.ok) throw new Error(`report.json: HTTP ${r.status}`); return r.json(); })
  .then(render)
  .catch((err) => { $("title").textContent = `The report could not be loaded: ${err.message}`; document.body.dataset.loaded = "error"; });
