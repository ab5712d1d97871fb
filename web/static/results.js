// Teacher's learner results: filters (task, station), a chart of the mean time per step (bars, seconds) and the
// error rate per step (dots, % of attempts with a wrong placement), tables per step, station, task and session,
// and the CSV export link. Shown only to a logged-in teacher (the API answers 401 otherwise).
// Every value from the server is inserted with textContent or as an SVG attribute, never as HTML.
"use strict";

(function () {
  const $ = (id) => document.getElementById(id);
  const SVG = "http://www.w3.org/2000/svg";

  function el(tag, text, cls) {
    const e = document.createElement(tag);
    if (text !== undefined && text !== null) e.textContent = String(text);
    if (cls) e.className = cls;
    return e;
  }

  function svg(tag, attrs, text) {
    const e = document.createElementNS(SVG, tag);
    for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, String(v));
    if (text !== undefined) e.textContent = String(text);
    return e;
  }

  const fmt = (x, digits = 1) => (x === null || x === undefined ? "–" : Number(x).toFixed(digits));
  const pct = (x) => (x === null || x === undefined ? "–" : `${Math.round(100 * x)} %`);
  const when = (t) => (t ? new Date(t * 1000).toLocaleString() : "–");

  function query() {
    const p = new URLSearchParams();
    if ($("r-task").value) p.set("task", $("r-task").value);
    if ($("r-station").value) p.set("station", $("r-station").value);
    const q = p.toString();
    return q ? `?${q}` : "";
  }

  function fillSelect(id, values, allLabel) {
    const sel = $(id);
    const keep = sel.value;
    sel.replaceChildren(el("option", allLabel));
    sel.firstChild.value = "";
    for (const v of values) {
      const o = el("option", v);
      o.value = v;
      sel.appendChild(o);
    }
    sel.value = values.includes(keep) ? keep : "";
  }

  function table(id, headers, rows) {
    const t = $(id);
    const head = el("tr");
    for (const h of headers) head.appendChild(el("th", h));
    const thead = el("thead");
    thead.appendChild(head);
    const body = el("tbody");
    for (const r of rows) {
      const tr = el("tr");
      for (const c of r) tr.appendChild(el("td", c));
      body.appendChild(tr);
    }
    t.replaceChildren(thead, body);
  }

  // Bars: mean time per step (left axis, seconds); dots joined by a line: error rate (right axis, 0-100 %).
  function chart(steps) {
    const W = 440, H = 220, L = 44, R = 44, T = 14, B = 34;
    const box = svg("svg", { viewBox: `0 0 ${W} ${H}`, role: "img", id: "r-chart-svg", class: "results-chart" });
    box.appendChild(svg("title", {}, "Mean time per step (bars, seconds) and error rate per step (dots, %)"));
    if (!steps.length) {
      box.appendChild(svg("text", { x: W / 2, y: H / 2, "text-anchor": "middle", class: "axis" }, "no steps recorded yet"));
      return box;
    }
    const tmax = Math.max(1, ...steps.map((s) => s.mean_time_s || 0));
    const pw = W - L - R, ph = H - T - B, slot = pw / steps.length;
    const y = (v) => T + ph - (ph * v) / tmax;
    const ye = (r) => T + ph - ph * r;
    box.appendChild(svg("line", { x1: L, y1: T + ph, x2: W - R, y2: T + ph, class: "axis-line" }));
    for (const f of [0, 0.5, 1]) {
      box.appendChild(svg("text", { x: L - 4, y: y(f * tmax) + 4, "text-anchor": "end", class: "axis" }, fmt(f * tmax)));
      box.appendChild(svg("text", { x: W - R + 4, y: ye(f) + 4, class: "axis axis-error" }, `${Math.round(100 * f)}%`));
    }
    box.appendChild(svg("text", { x: 4, y: T + 4, class: "axis" }, "s"));
    const points = [];
    steps.forEach((s, i) => {
      const x = L + i * slot;
      const h = s.mean_time_s === null ? 0 : T + ph - y(s.mean_time_s);
      const bar = svg("rect", { x: x + slot * 0.2, y: T + ph - h, width: slot * 0.6, height: h, class: "bar",
        "data-step": s.step, "data-time": s.mean_time_s === null ? "" : s.mean_time_s });
      bar.appendChild(svg("title", {}, `step ${s.step}: ${fmt(s.mean_time_s)} s on average over ${s.n} attempt(s)`));
      box.appendChild(bar);
      box.appendChild(svg("text", { x: x + slot / 2, y: H - B + 16, "text-anchor": "middle", class: "axis" }, s.step));
      points.push([x + slot / 2, ye(s.error_rate), s]);
    });
    box.appendChild(svg("polyline", { points: points.map((p) => `${p[0]},${p[1]}`).join(" "), class: "error-line" }));
    for (const [px, py, s] of points) {
      const dot = svg("circle", { cx: px, cy: py, r: 4, class: "error-dot", "data-step": s.step,
        "data-error-rate": s.error_rate });
      dot.appendChild(svg("title", {}, `step ${s.step}: wrong placement in ${pct(s.error_rate)} of attempts`));
      box.appendChild(dot);
    }
    box.appendChild(svg("text", { x: L + pw / 2, y: H - 4, "text-anchor": "middle", class: "axis" }, "step"));
    return box;
  }

  async function refresh() {
    const res = await fetch(`/api/results${query()}`);
    if (!res.ok) {
      $("r-message").textContent = res.status === 503 ? "The database is unavailable." : "";
      return;
    }
    const data = await res.json();
    fillSelect("r-task", data.tasks, "all tasks");
    fillSelect("r-station", data.stations, "all stations");
    $("r-csv").href = `/api/results.csv${query()}`;
    $("r-message").textContent = data.sessions.length ? "" : "No sessions recorded for this choice yet.";
    $("r-chart").replaceChildren(chart(data.steps));
    table("r-steps", ["Step", "Attempts", "Mean time (s)", "Error rate", "Hints"],
      data.steps.map((s) => [s.step, s.n, fmt(s.mean_time_s), pct(s.error_rate), s.hints]));
    table("r-stations", ["Station", "Sessions", "Completed", "Mean step time (s)", "Error rate", "Wrong", "Hints"],
      data.by_station.map((g) => [g.station, g.sessions, g.completed, fmt(g.mean_step_time_s), pct(g.error_rate),
        g.wrong_placements, g.hints]));
    table("r-tasks", ["Task", "Sessions", "Completed", "Mean step time (s)", "Error rate", "Wrong", "Hints"],
      data.by_task.map((g) => [g.task, g.sessions, g.completed, fmt(g.mean_step_time_s), pct(g.error_rate),
        g.wrong_placements, g.hints]));
    table("r-sessions", ["Started", "Station", "Mode", "Task", "Steps", "Time (s)", "Wrong", "Hints", "Completed"],
      data.sessions.slice(0, 50).map((s) => [when(s.started_at), s.station || "–", s.mode, s.task,
        `${s.steps_done}/${s.steps_total ?? "?"}`, fmt(s.time_s), s.wrong_placements, s.hints,
        s.completed_at ? "yes" : "no"]));
  }

  // called by teacher.js whenever the login state changes
  window.refreshResults = async function (loggedIn) {
    $("results-card").classList.toggle("hidden", !loggedIn);
    if (loggedIn) await refresh();
  };

  $("r-task").addEventListener("change", refresh);
  $("r-station").addEventListener("change", refresh);
  $("r-reload").addEventListener("click", refresh);
})();
