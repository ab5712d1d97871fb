// Teacher editor: login (or first-run password), list / create / edit / delete sentence tasks.
// Every user-supplied string is inserted with textContent, so "<script>" is displayed as text.
"use strict";

const $ = (id) => document.getElementById(id);
const FIELDS = ["source_sentence", "source_language", "words", "alternatives", "distractors"];
const auth = { configured: false, loggedIn: false };

function el(tag, text, cls) {
  const e = document.createElement(tag);
  if (text !== undefined && text !== null) e.textContent = String(text);
  if (cls) e.className = cls;
  return e;
}

async function call(path, options = {}) {
  const res = await fetch(path, Object.assign({ headers: { "Content-Type": "application/json" } }, options));
  let body = null;
  try { body = await res.json(); } catch (_e) { body = null; }
  return { ok: res.ok, status: res.status, body };
}

function splitWords(text) {
  const t = text.trim();
  if (!t) return [];
  return (t.includes("|") ? t.split("|") : t.split(/\s+/)).map((w) => w.trim());
}

function joinWords(words) {
  return words.some((w) => /\s/.test(w)) ? words.join(" | ") : words.join(" ");
}

function setMessage(id, text, isError) {
  $(id).textContent = text;
  $(id).classList.toggle("error", !!isError);
}

// ------------------------------------------------------------------ auth
async function refreshAuth() {
  const r = await call("/api/auth");
  auth.configured = r.body.configured;
  auth.loggedIn = r.body.logged_in;
  $("login-title").textContent = auth.configured ? "Teacher login" : "Set the teacher password";
  $("login-hint").textContent = auth.configured
    ? "Enter the teacher password to create or edit tasks. Learners can only read them."
    : "No teacher password exists yet. Choose one (at least 10 characters; only on the server machine itself); it is stored hashed.";
  $("btn-login").textContent = auth.configured ? "Log in" : "Set password";
  $("btn-login").disabled = false; // enabled once the page knows whether to log in or to set the password
  $("login-form").classList.toggle("hidden", auth.loggedIn);
  $("btn-logout").classList.toggle("hidden", !auth.loggedIn);
  if (auth.loggedIn) setMessage("login-message", "Logged in as teacher.");
  $("btn-save").disabled = !auth.loggedIn;
  await refreshTasks();
  if (window.refreshResults) await window.refreshResults(auth.loggedIn); // results.js: the learner results view
}

$("login-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const password = $("password").value;
  const path = auth.configured ? "/api/auth/login" : "/api/auth/setup";
  const r = await call(path, { method: "POST", body: JSON.stringify({ password }) });
  $("password").value = "";
  if (!r.ok) {
    const d = r.body && r.body.detail;
    const msg = Array.isArray(d) ? d.map((x) => x.msg).join("; ") : d || `error ${r.status}`;
    setMessage("login-message", r.status === 401 ? "Wrong password." : msg, true);
    return;
  }
  setMessage("login-message", "Logged in as teacher.");
  await refreshAuth();
});

$("btn-logout").addEventListener("click", async () => {
  await call("/api/auth/logout", { method: "POST" });
  setMessage("login-message", "Logged out.");
  await refreshAuth();
});

// ------------------------------------------------------------------ task list
async function refreshTasks() {
  const r = await call("/api/tasks");
  const list = $("task-list");
  if (!r.ok) { list.replaceChildren(el("li", "cannot load tasks", "muted")); return; }
  const items = r.body.tasks.map((rec) => {
    const li = el("li");
    li.dataset.taskId = rec.id;
    const text = el("span", null, "text");
    text.appendChild(el("span", rec.task.source_sentence, "sentence-line"));
    text.appendChild(el("span", rec.task.words.join(" "), "words-line"));
    li.appendChild(text);
    if (auth.loggedIn) {
      const edit = el("button", "Edit");
      edit.type = "button";
      edit.addEventListener("click", () => loadIntoForm(rec));
      const del = el("button", "Delete");
      del.type = "button";
      del.addEventListener("click", () => deleteTask(rec.id));
      li.append(edit, del);
    }
    return li;
  });
  list.replaceChildren(...(items.length ? items : [el("li", "no teacher tasks yet", "muted")]));
}

async function deleteTask(id) {
  if (!window.confirm(`Delete task ${id}?`)) return;
  const r = await call(`/api/tasks/${id}`, { method: "DELETE" });
  setMessage("save-message", r.ok ? `Task ${id} deleted.` : (r.body && r.body.detail) || "delete failed", !r.ok);
  await refreshTasks();
}

// ------------------------------------------------------------------ editor
function clearErrors() {
  for (const f of FIELDS) $(`err-${f}`).textContent = "";
  $("err-form").textContent = "";
}

function resetForm() {
  $("task-id").value = "";
  $("editor-title").textContent = "New sentence task";
  for (const f of FIELDS) $(`f-${f}`).value = f === "source_language" ? "el" : "";
  clearErrors();
}

function loadIntoForm(rec) {
  resetForm();
  $("task-id").value = rec.id;
  $("editor-title").textContent = `Edit task ${rec.id}`;
  const t = rec.task;
  $("f-source_sentence").value = t.source_sentence;
  $("f-source_language").value = t.source_language;
  $("f-words").value = joinWords(t.words);
  $("f-alternatives").value = t.alternatives.map(joinWords).join("\n");
  $("f-distractors").value = joinWords(t.distractors);
}

$("btn-new").addEventListener("click", resetForm);

$("task-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  clearErrors();
  const body = {
    source_sentence: $("f-source_sentence").value.trim(),
    source_language: $("f-source_language").value.trim() || "el",
    target_language: "es",
    words: splitWords($("f-words").value),
    alternatives: $("f-alternatives").value.split("\n").map(splitWords).filter((a) => a.length),
    distractors: splitWords($("f-distractors").value),
  };
  const id = $("task-id").value;
  const r = await call(id ? `/api/tasks/${id}` : "/api/tasks", { method: id ? "PUT" : "POST", body: JSON.stringify(body) });
  if (r.ok) {
    resetForm();
    await refreshTasks();
    setMessage("save-message", `Saved task ${r.body.id} (${r.body.ref}).`);
    return;
  }
  const d = r.body && r.body.detail;
  if (r.status === 422 && Array.isArray(d)) {
    for (const e of d) {
      const loc = (e.loc || []).filter((x) => x !== "body");
      const field = FIELDS.includes(loc[0]) ? loc[0] : "form";
      const where = loc.length > 1 ? `${loc.slice(1).map((x) => (typeof x === "number" ? `#${x + 1}` : x)).join(" ")}: ` : "";
      const msg = String(e.msg).replace(/^Value error, /, "");
      const target = $(`err-${field}`);
      target.textContent = (target.textContent ? target.textContent + " " : "") + where + msg;
    }
    setMessage("save-message", "Please fix the marked fields.", true);
  } else {
    setMessage("save-message", r.status === 401 || r.status === 403 ? `Not allowed: ${d}` : d || `error ${r.status}`, true);
  }
});

refreshAuth();
