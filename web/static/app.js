// Assembly Agent panel: websocket snapshots, colour image with overlays, drag-a-box, mode selection.
// All user-visible text goes through textContent (never innerHTML), so task words are shown, not run.
"use strict";

const $ = (id) => document.getElementById(id);
// "?scene=off" shows the panel and colour image without the embedded 3D scene (small screens, slow machines).
const SHOW_SCENE = new URLSearchParams(location.search).get("scene") !== "off";
const state = {
  snap: null, imageSize: [640, 480], parts: [], drag: null, lastBox: null, imgBusy: false,
  waiting: null, round: null, roundTimer: null,
};

function el(tag, text, cls) {
  const e = document.createElement(tag);
  if (text !== undefined && text !== null) e.textContent = String(text);
  if (cls) e.className = cls;
  return e;
}

function setList(list, items, empty) {
  list.replaceChildren(...(items.length ? items : [el("li", empty, "muted")]));
  delete list.dataset.key;
}

// Per-frame updates touch the page only where something changed: an unchanged text or list is not rewritten,
// so the browser does not lay out and repaint the panel for every frame.
function setText(e, text) {
  const t = String(text);
  if (e.textContent !== t) e.textContent = t;
}

// ``setList`` when ``key`` (what the list shows) differs from the last one; ``build()`` makes the items.
function setListIf(list, key, build, empty) {
  if (list.dataset.key === key) return;
  setList(list, build(), empty);
  list.dataset.key = key;
}

async function api(path, options = {}) {
  const opts = Object.assign({ headers: { "Content-Type": "application/json" } }, options);
  const res = await fetch(path, opts);
  let body = null;
  try { body = await res.json(); } catch (_e) { body = null; }
  if (!res.ok) {
    const detail = body && body.detail;
    let msg = typeof detail === "string" ? detail : res.statusText;
    if (Array.isArray(detail)) msg = detail.map((d) => `${(d.loc || []).slice(1).join(".")}: ${d.msg}`).join("; ");
    throw new Error(msg);
  }
  return body;
}

function showMessage(id, text, isError) {
  const m = $(id);
  m.textContent = text;
  m.classList.toggle("error", !!isError);
}

// ------------------------------------------------------------------ status, modes, tasks
// The 3D scene is framed from the other loopback name when the page is on one (127.0.0.1 <-> localhost): a
// frame of another site runs in its own browser process, so the scene's drawing (in software on a machine
// without a GPU, and the page waits for each of its frames) never holds up the panel. Other hosts: the same.
const OTHER_LOOPBACK = { "127.0.0.1": "localhost", "localhost": "127.0.0.1", "[::1]": "127.0.0.1" };
function sceneHost(host) {
  return OTHER_LOOPBACK[host] || host;
}

async function refreshStatus() {
  try {
    const s = await api("/api/status");
    $("source-name").textContent = s.source;
    const shown = state.modes;
    if (shown && !state.modeDirty && (s.mode !== shown.current || s.source !== shown.source)) {
      refreshModes().catch(() => {});  // changed elsewhere (another panel, a source that lacks the task's parts)
      refreshSources().catch(() => {});
    }
    $("worker-state").textContent = s.worker.state;
    const db = s.storage || {};
    $("storage-message").textContent = db.problem ? `Storage: ${db.problem}` : "";
    $("storage-message").classList.toggle("hidden", !db.problem);
    state.parts = s.parts;
    const sel = $("box-part");
    const current = sel.value;
    const opts = [el("option", "by colour")];
    opts[0].value = "";
    for (const p of s.parts) { const o = el("option", p); o.value = p; opts.push(o); }
    sel.replaceChildren(...opts);
    sel.value = s.parts.includes(current) ? current : "";
    const frame = $("viser-frame");
    if (!SHOW_SCENE) {
      document.querySelector(".scene3d").classList.add("hidden");
    } else if (s.viser_port && frame.dataset.port !== String(s.viser_port)) {
      frame.dataset.port = String(s.viser_port);
      frame.src = `${location.protocol}//${sceneHost(location.hostname)}:${s.viser_port}/`;
    } else if (!s.viser_port) {
      $("viser-message").textContent = "3D scene disabled (--viser-port 0)";
    }
    const errs = s.worker.errors.slice(-5).reverse().map((e) => el("li", `${e.where}: ${e.message}`));
    setList($("error-list"), errs, "none");
  } catch (e) {
    $("worker-state").textContent = "offline";
  }
}

async function refreshSources() {
  const r = await api("/api/sources");
  const sel = $("source-select");
  const specs = r.available.map((a) => a.spec);
  if (!specs.includes(r.current)) specs.unshift(r.current);
  sel.replaceChildren(...specs.map((spec) => { const o = el("option", spec); o.value = spec; return o; }));
  sel.value = r.current;
}

$("source-select").addEventListener("change", async () => {
  const spec = $("source-select").value;
  try {
    await api("/api/sources", { method: "POST", body: JSON.stringify({ source: spec }) });
    showMessage("mode-message", `source ${spec}`);
  } catch (e) {
    showMessage("mode-message", e.message, true);
  }
  refreshSources().catch(() => {});  // the control shows the source in force, switched or not
  refreshModes().catch(() => {});
  refreshStatus();
});

// Mode and source are one choice: the task list offers, for the chosen mode, each task on the current source
// (when it fits) and on the simulated scene built for it; Apply switches mode, task and scene together.
async function refreshModes() {
  const m = await api("/api/modes");
  state.modes = m;
  state.modeDirty = false;
  $("mode-select").value = m.current;
  fillTasks(m, m.current, m.task, m.source);
  document.body.dataset.modesLoaded = "1";
  document.body.dataset.mode = m.current;
  document.body.dataset.source = m.source;
}

function choiceLabel(c) {
  const title = c.mode === "none" ? "tracking only" : c.title;
  return c.switches_source ? `${title} — switches to ${c.source}` : `${title} — this scene`;
}

function fillTasks(m, mode, task, source) {
  const sel = $("task-select");
  const opts = [];
  m.choices.forEach((c, i) => {
    if (c.mode !== mode) return;
    const o = el("option", choiceLabel(c));
    o.value = String(i);
    o.dataset.task = c.task || "";
    o.dataset.source = c.source;
    opts.push(o);
  });
  if (!opts.length) {
    const o = el("option", "no task fits: choose another mode");
    o.value = "";
    opts.push(o);
  }
  sel.replaceChildren(...opts);
  sel.disabled = !opts[0].value;
  const current = opts.find((o) => o.dataset.task === (task || "") && o.dataset.source === source);
  sel.value = (current || opts[0]).value;
}

$("mode-select").addEventListener("change", () => {
  state.modeDirty = true;
  if (state.modes) fillTasks(state.modes, $("mode-select").value, null, state.modes.source);
});
$("task-select").addEventListener("change", () => { state.modeDirty = true; });

$("btn-apply-mode").addEventListener("click", async () => {
  const choice = state.modes && state.modes.choices[Number($("task-select").value)];
  if (!choice || $("task-select").value === "") {
    showMessage("mode-message", "no task of this mode fits: choose another mode", true);
    return;
  }
  const body = { mode: choice.mode, task: choice.task, source: choice.source };
  showMessage("mode-message", "switching…");
  try {
    const m = await api("/api/modes", { method: "POST", body: JSON.stringify(body) });
    showMessage("mode-message", `mode ${m.current}${m.task ? " · " + m.task : ""} on ${m.source}`);
  } catch (e) {
    showMessage("mode-message", e.message, true);
  }
  await refreshModes().catch(() => {});  // the controls show what is in force, whether or not it switched
  refreshSources().catch(() => {});
  refreshStatus();
});

for (const action of ["start", "pause", "reset"]) {
  $(`btn-${action}`).addEventListener("click", async () => {
    try {
      await api("/api/sessions", { method: "POST", body: JSON.stringify({ action }) });
    } catch (e) {
      showMessage("mode-message", e.message, true);  // e.g. a reset needs the teacher's login
    }
    refreshStatus();
  });
}

// ------------------------------------------------------------------ snapshot rendering
function progressOf(ms) {
  const p = ms.progress;
  if (typeof p === "number") return p > 1 ? p / 100 : p;
  if (p && typeof p === "object") {
    const done = p.done ?? p.completed ?? p.established;
    const total = p.total ?? p.steps;
    if (typeof done === "number" && total) return done / total;
    if (typeof p.fraction === "number") return p.fraction;
  }
  return null;
}

// A new round: the source started again (a loop, reset or switch) and every mode state with it.
function noteRound(s) {
  const round = s.source && s.source.round;
  if (round === undefined || round === state.round) return;
  const first = state.round === null;
  state.round = round;
  state.lastBox = null;
  $("auto-place-results").replaceChildren();
  const banner = $("round-banner");
  banner.dataset.round = String(round);
  if (first) return;
  banner.textContent = `New round (${round}): the source started again, the assembly starts over.`;
  banner.classList.remove("hidden");
  clearTimeout(state.roundTimer);
  state.roundTimer = setTimeout(() => banner.classList.add("hidden"), 4000);
}

function renderSnapshot(s) {
  state.snap = s;
  noteRound(s);
  state.imageSize = s.image_size && s.image_size[0] ? s.image_size : state.imageSize;
  setText($("frame-index"), s.frame_index);
  setText($("fps"), (s.fps || 0).toFixed(1));
  if (s.worker) setText($("worker-state"), s.worker.state);
  const ms = s.mode_state || {};
  const instr = $("instruction");
  setText(instr, s.instruction || (s.mode ? "…" : "Tracking only (no assembly mode)"));
  instr.classList.toggle("ok", ms.complete === true);
  instr.classList.toggle("bad", !!ms.warning);
  const frac = progressOf(ms);
  const width = frac === null ? "0" : `${Math.round(Math.max(0, Math.min(1, frac)) * 100)}%`;
  if ($("progress-bar").style.width !== width) $("progress-bar").style.width = width;
  const p = ms.progress || {};
  setText($("progress-text"), frac === null ? "" : `${p.done ?? ""} of ${p.total ?? ""} ${p.unit || "connections"} done`);

  const conns = (s.connections || []).map((c) => {
    const st = String(c.state || c.status || "");
    const score = typeof c.score === "number" ? ` (${c.score.toFixed(2)})` : "";
    return [`${c.first} → ${c.second}: ${st}${score}`, `state-${st.toLowerCase()}`];
  });
  setListIf($("connection-list"), JSON.stringify(conns), () => conns.map(([text, cls]) => el("li", text, cls)), "none yet");

  setText($("warning"), ms.warning || "");

  const ranking = Array.isArray(ms.ranking) ? ms.ranking : [];
  $("ranking-box").classList.toggle("hidden", s.mode !== "guess" || ranking.length === 0);
  const rRows = ranking.map((r) => [
    `${r.title || r.structure || "?"}: ${r.completed ?? 0}/${r.total ?? "?"} connections`,
    r.structure === ms.guess && !ms.tied, Math.round(Number(r.fraction ?? 0) * 80),
  ]);
  setListIf($("ranking-list"), JSON.stringify(rRows), () => rRows.map(([text, isGuess, px]) => {
    const li = el("li", text);
    if (isGuess) li.classList.add("guess");
    const bar = el("span", null, "bar");
    bar.style.width = `${px}px`;
    li.appendChild(bar);
    return li;
  }), "");
  const leader = ranking.length ? (ranking[0].title || ranking[0].structure) : ms.guess;
  setText($("guess-text"), !ms.guess ? "" : ms.tied
    ? "not sure yet: no structure leads"
    : `best guess: ${leader} (confidence ${Math.round((ms.confidence || 0) * 100)} %)`);

  const isLearning = s.mode === "learning";
  $("learning-box").classList.toggle("hidden", !isLearning);
  if (isLearning) {
    setText($("source-sentence"), ms.sentence || "");
    const verdicts = (Array.isArray(ms.verdicts) ? ms.verdicts : []).map((v) => [
      v.placed ?? "·", v.correct === true ? "correct" : v.correct === false ? "wrong" : "", `position ${v.position}`,
    ]);
    const wordList = $("word-list");
    if (wordList.dataset.key !== JSON.stringify(verdicts)) {
      wordList.replaceChildren(...verdicts.map(([text, cls, title]) => {
        const li = el("li", text, cls);
        li.title = title;
        return li;
      }));
      wordList.dataset.key = JSON.stringify(verdicts);
    }
    const words = (Array.isArray(ms.words) ? ms.words : []).map((w) => `${w.cube}: ${w.word}`);
    // which words are distractors is for the learner to find out: the list shows cube and word only
    setListIf($("cube-words"), JSON.stringify(words), () => words.map((w) => el("li", w)), "");
  }
  renderParts(s);
  renderIdentical(s);
  const errs = s.errors || [];
  if (errs.length) setListIf($("error-list"), JSON.stringify(errs), () => errs.map((e) => el("li", e)), "none");
  drawOverlay();
}

// Every part with its state: tracked, in hand (hidden in a hand and moved with it) or not placed yet.
function renderParts(s) {
  const poses = s.poses || {};
  const carried = new Set(s.carried || []);
  const names = state.parts.length ? state.parts : Object.keys(poses);
  const rows = names.map((name) => [name, carried.has(name) ? "in hand" : name in poses ? "tracked" : "not placed"]);
  setListIf($("part-list"), JSON.stringify(rows), () => rows.map(([name, st]) => {
    const li = el("li", `${name}: ${st}`, `part-${st.replace(" ", "-")}`);
    li.dataset.part = name;
    return li;
  }), "–");
  renderHands(s);
}

// Tracked hands (hand tracking on): "hand 1: holding the red cube" (or touching, or just the hand).
function renderHands(s) {
  const hands = (Array.isArray(s.hands) ? s.hands : []).map((h) => [h.id, h.text || "seen", !!(h.holding && h.holding.length)]);
  const list = $("hand-list");
  list.classList.toggle("hidden", hands.length === 0);
  const key = JSON.stringify(hands);
  if (list.dataset.key === key) return;
  list.dataset.key = key;
  list.replaceChildren(...hands.map(([id, text, holding]) => {
    const li = el("li", `hand ${id}: ${text}`, holding ? "hand-holding" : "hand");
    li.dataset.hand = String(id);
    return li;
  }));
}

$("btn-auto-place").addEventListener("click", async () => {
  const btn = $("btn-auto-place");
  btn.disabled = true;
  showMessage("box-message", "looking for parts…");
  $("auto-place-results").replaceChildren();
  try {
    const part = $("box-part").value;  // a chosen part is found again; "by colour": every untracked part
    const body = part ? { names: [part] } : {};
    const r = await api("/api/parts/auto-place", { method: "POST", body: JSON.stringify(body) });
    const entries = Object.entries(r.results);
    const found = entries.filter(([, v]) => !v.error).length;
    showMessage("box-message", entries.length
      ? `found ${found} of ${entries.length} part${entries.length === 1 ? "" : "s"} (frame ${r.frame_index})`
      : "every part is already tracked", found < entries.length);
    $("auto-place-results").replaceChildren(...entries.map(([name, v]) => {
      const li = el("li", v.error ? `${name}: not found: ${v.error}` : `${name}: placed (fit ${v.residual_mm.toFixed(1)} mm)`,
        v.error ? "error" : "ok");
      li.dataset.part = name;
      return li;
    }));
  } catch (e) {
    showMessage("box-message", e.message, true);
  } finally {
    btn.disabled = false;
  }
});

// ------------------------------------------------------------------ colour image and overlay
const PART_COLORS = {
  red: "#d21e23", green: "#28aa3c", blue: "#2346c8", yellow: "#ebcd1e", orange: "#f07814",
  purple: "#8232aa", cyan: "#1eb4c8", pink: "#eb6eaa",
};

// The overlay's size follows the image's shown size (kept by a ResizeObserver, so drawing a frame never makes
// the browser compute the layout in the middle of the frame).
const shownSize = { w: 0, h: 0 };
new ResizeObserver((entries) => {
  const box = entries[entries.length - 1].contentRect;
  shownSize.w = Math.round(box.width);
  shownSize.h = Math.round(box.height);
  drawOverlay();
}).observe($("color-image"));

function drawOverlay() {
  const canvas = $("overlay");
  const { w, h } = shownSize;
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, w, h);
  const [iw, ih] = state.imageSize;
  const sx = w / iw, sy = h / ih;
  const s = state.snap;
  if (s) {
    if ($("show-detections").checked) {
      for (const [name, d] of Object.entries(s.detections || {})) {
        if (!d.bbox) continue;
        ctx.setLineDash([4, 3]);
        ctx.strokeStyle = PART_COLORS[name] || "#fff";
        ctx.lineWidth = 1.5;
        ctx.strokeRect(d.bbox[0] * sx, d.bbox[1] * sy, d.bbox[2] * sx, d.bbox[3] * sy);
        if (d.center) { ctx.beginPath(); ctx.arc(d.center[0] * sx, d.center[1] * sy, 3, 0, 2 * Math.PI); ctx.stroke(); }
      }
    }
    if ($("show-boxes").checked) {
      ctx.setLineDash([]);
      const labels = [];
      for (const [name, b] of Object.entries(s.boxes || {})) {
        if (b.some((v) => v === null)) continue;
        ctx.strokeStyle = "#fff";
        ctx.lineWidth = 2;
        ctx.strokeRect(b[0] * sx, b[1] * sy, (b[2] - b[0]) * sx, (b[3] - b[1]) * sy);
        labels.push([name, b[0] * sx, b[1] * sy, b[3] * sy]);
      }
      for (const [name, p] of Object.entries(s.identical_parts || {})) {
        if (!p.bbox) continue;
        ctx.setLineDash(p.seen ? [] : [3, 3]);
        ctx.strokeStyle = PART_COLORS[name.split(" #")[0]] || "#fff";
        ctx.lineWidth = 2;
        ctx.strokeRect(p.bbox[0] * sx, p.bbox[1] * sy, p.bbox[2] * sx, p.bbox[3] * sy);
        labels.push([name, p.bbox[0] * sx, p.bbox[1] * sy, (p.bbox[1] + p.bbox[3]) * sy]);
      }
      drawLabels(ctx, labels, w, h);
    }
    if ($("show-hands").checked) {
      ctx.setLineDash([]);
      ctx.lineWidth = 2;
      ctx.font = "bold 12px sans-serif";
      ctx.textBaseline = "bottom";
      for (const hnd of s.hands || []) {
        const b = hnd.box;
        if (!Array.isArray(b) || b.length !== 4) continue;
        ctx.strokeStyle = "#ffb070";
        ctx.strokeRect(b[0] * sx, b[1] * sy, (b[2] - b[0]) * sx, (b[3] - b[1]) * sy);
        const label = `hand ${hnd.id}${hnd.text ? ": " + hnd.text : ""}`;
        const tw = ctx.measureText(label).width + 8;
        const x = Math.max(0, Math.min(b[0] * sx, w - tw)), y = Math.max(15, b[1] * sy);
        ctx.fillStyle = "rgba(20, 20, 20, 0.75)";
        ctx.fillRect(x, y - 15, tw, 15);
        ctx.fillStyle = "#ffb070";
        ctx.fillText(label, x + 4, y - 1);
      }
    }
  }
  const r = state.drag || state.lastBox;
  if (r) {
    ctx.setLineDash(state.drag ? [6, 4] : []);
    ctx.strokeStyle = "#00e5ff";
    ctx.lineWidth = 2;
    ctx.strokeRect(r.x * sx, r.y * sy, r.w * sx, r.h * sy);
  }
}

// Part names on dark tags (legible on any background), above their box or, when that place is taken by
// a neighbour's tag, below it.
function drawLabels(ctx, labels, w, h) {
  ctx.font = "bold 12px sans-serif";
  ctx.textBaseline = "middle";
  const taken = [];
  const overlaps = (r) => taken.some((t) => r.x < t.x + t.w && t.x < r.x + r.w && r.y < t.y + t.h && t.y < r.y + r.h);
  for (const [name, x0, top, bottom] of labels) {
    const tw = ctx.measureText(name).width + 16;
    const x = Math.max(0, Math.min(x0, w - tw));
    let r = { x, y: Math.max(0, top - 17), w: tw, h: 15 };
    if (overlaps(r)) r = { x, y: Math.min(h - 15, bottom + 2), w: tw, h: 15 };
    taken.push(r);
    ctx.fillStyle = "rgba(20, 20, 20, 0.75)";
    ctx.fillRect(r.x, r.y, r.w, r.h);
    ctx.fillStyle = PART_COLORS[name.split(" #")[0]] || "#fff";
    ctx.fillRect(r.x + 3, r.y + 4, 7, 7);
    ctx.fillStyle = "#fff";
    ctx.fillText(name, r.x + 13, r.y + r.h / 2 + 1);
  }
}

// The image and everything drawn or listed beside it come from the same frame: the websocket sends each
// snapshot followed by the JPEG of that frame (/ws?image=1), and the panel shows a snapshot only together with
// its image, once the image has loaded. While one image loads, newer frames replace the one waiting, so a slow
// browser skips frames instead of falling behind.
function showFrame(s, blob) {
  if (state.imgBusy) { state.waiting = [s, blob]; return; }
  state.imgBusy = true;
  const url = URL.createObjectURL(blob);
  const img = $("color-image");
  const done = (ok) => {
    URL.revokeObjectURL(url);
    if (ok) {
      img.classList.remove("loading");
      $("image-wrap").classList.remove("loading");
      img.dataset.frame = String(s.frame_index);
      renderSnapshot(s);
    }
    state.imgBusy = false;
    const next = state.waiting;
    state.waiting = null;
    if (next) showFrame(...next);
  };
  img.onload = () => done(true);
  img.onerror = () => done(false);
  img.src = url;
}

function imageCoords(ev) {
  const canvas = $("overlay");
  const rect = canvas.getBoundingClientRect();
  const [iw, ih] = state.imageSize;
  return [((ev.clientX - rect.left) / rect.width) * iw, ((ev.clientY - rect.top) / rect.height) * ih];
}

$("overlay").addEventListener("mousedown", (ev) => {
  const [x, y] = imageCoords(ev);
  state.drag = { x0: x, y0: y, x, y, w: 0, h: 0 };
});
window.addEventListener("mousemove", (ev) => {
  if (!state.drag) return;
  const [x, y] = imageCoords(ev);
  const d = state.drag;
  d.x = Math.max(0, Math.min(x, d.x0));
  d.y = Math.max(0, Math.min(y, d.y0));
  d.w = Math.abs(x - d.x0);
  d.h = Math.abs(y - d.y0);
  drawOverlay();
});
window.addEventListener("mouseup", async () => {
  const d = state.drag;
  state.drag = null;
  if (!d) return;
  if (d.w < 4 || d.h < 4) { drawOverlay(); return; }
  const body = {
    x: d.x, y: d.y, w: d.w, h: d.h, action: $("box-action").value, part: $("box-part").value || null,
  };
  state.lastBox = { x: d.x, y: d.y, w: d.w, h: d.h };
  drawOverlay();
  if (body.action === "identical") { addIdentical(body); return; }
  showMessage("box-message", "sending box…");
  try {
    const r = await api("/api/boxes", { method: "POST", body: JSON.stringify(body) });
    const what = r.action === "track" ? "tracking" : "colour calibrated for";
    showMessage("box-message", `${what} ${r.part} (frame ${r.frame_index})`);
  } catch (e) {
    state.lastBox = null;  // a refused box is not kept on the image
    drawOverlay();
    showMessage("box-message", `box refused: ${e.message}`, true);
  }
  refreshCalibrations();
});

// Identical parts: one box per part of the chosen colour; the server tells them apart in every frame.
async function addIdentical(body) {
  if (!body.part) {
    state.lastBox = null;
    drawOverlay();
    showMessage("box-message", "choose the identical parts' colour in the part list first", true);
    return;
  }
  try {
    const r = await api("/api/identical-parts", {
      method: "POST", body: JSON.stringify({ colour: body.part, x: body.x, y: body.y, w: body.w, h: body.h }),
    });
    showMessage("box-message", `telling apart ${r.parts.join(", ")}`);
  } catch (e) {
    showMessage("box-message", `box refused: ${e.message}`, true);
  }
  state.lastBox = null;
  drawOverlay();
}

$("btn-clear-identical").addEventListener("click", async () => {
  try {
    await api("/api/identical-parts", { method: "DELETE" });
    showMessage("box-message", "identical parts no longer told apart");
  } catch (e) {
    showMessage("box-message", e.message, true);
  }
});

function renderIdentical(s) {
  const parts = Object.entries(s.identical_parts || {}).map(([name, p]) => [name, !!p.seen]);
  $("identical-box").classList.toggle("hidden", parts.length === 0);
  setListIf($("identical-list"), JSON.stringify(parts), () => parts.map(([name, seen]) => {
    const li = el("li", `${name}: ${seen ? "seen" : "hidden (box grows where it was)"}`);
    li.dataset.part = name;
    return li;
  }), "");
}

// The colour calibrations in force: "Undo calibration" restores the range before the newest one.
async function refreshCalibrations() {
  try {
    const r = await api("/api/calibration");
    const btn = $("btn-undo-calibration");
    const n = r.calibrations.length;
    btn.disabled = n === 0;
    btn.textContent = n ? `Undo calibration (${r.calibrations[n - 1].part})` : "Undo calibration";
  } catch (_e) { /* the next refresh tries again */ }
}

$("btn-undo-calibration").addEventListener("click", async () => {
  try {
    const before = (await api("/api/calibration")).calibrations;
    await api("/api/calibration/undo", { method: "POST" });
    showMessage("box-message", `calibration of ${before[before.length - 1].part} undone`);
  } catch (e) {
    showMessage("box-message", e.message, true);
  }
  refreshCalibrations();
});

// ------------------------------------------------------------------ websocket
function connect() {
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws?image=1`);
  let pending = null;  // the snapshot whose JPEG comes next
  ws.onmessage = (ev) => {
    if (typeof ev.data !== "string") {
      if (pending) showFrame(pending, ev.data);
      pending = null;
      return;
    }
    const s = JSON.parse(ev.data);
    s.round = s.source && s.source.round;
    pending = s;
    if (s.worker) setText($("worker-state"), s.worker.state);
  };
  ws.onclose = () => { $("worker-state").textContent = "reconnecting"; setTimeout(connect, 1000); };
}

refreshStatus();
refreshSources().catch(() => {});
refreshCalibrations();
refreshModes().catch((e) => showMessage("mode-message", e.message, true));
setInterval(refreshStatus, 2000);
connect();
