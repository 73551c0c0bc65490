// The puppet workflow page: project, camera, the 12 angles, the processed view with hand
// corrections, 3D (three.js) and export. Talks to /api/puppet (src/stillcap/gui/puppet.py).
import { api, followJob, progressInto, status, download } from "./common.js";
import { createScene } from "./puppet3d.js";

const $ = (id) => document.getElementById(id);
const P = "/api/puppet";
let state = null;        // GET /state
let current = null;      // the shown view's JSON (GET /view/{name})
let photo = null;        // its decoded photo (ImageBitmap)
let selected = null;     // the selected bead's name
let stream = null;       // the browser camera's MediaStream
const scene3d = createScene($("three-wrap"), (pick) => {
  $("pick-info").textContent = pick ? describePick(pick) : "click a marker to pick it";
});
window.stillcapPuppet = { scene3d, get state() { return state; }, get view() { return current; } };  // for tests

function describePick(m) {
  if (m.kind === "joint") return `joint ${m.name}: angles ${m.angles_deg.map((a) => a.toFixed(1)).join(", ")} deg`;
  if (m.kind === "camera") return `camera ${m.name}`;
  const p = m.position.map((v) => (v * 1000).toFixed(1)).join(", ");
  return `marker ${m.name}: (${p}) mm, ${m.n_views} views, reprojection ${m.reproj_error_px?.toFixed(2) ?? "-"} px` +
    (m.weak ? " — fewer than two whole views" : "");
}

// --- project -------------------------------------------------------------------------------
async function refresh() {
  state = await api(`${P}/state`);
  const sel = $("open-select");
  sel.replaceChildren(...state.projects.map((p) => new Option(p === "." ? "(this folder)" : p, p)));
  const p = state.project;
  $("project-name").textContent = p ? `${p.name} — ${p.views.length} photos, marker set ${p.markerset.name}` : "no project open";
  $("take-btn").disabled = !p || !p.turntable;
  const caps = state.captures ?? [];
  $("import-row").hidden = !caps.length || (p && p.views.length > 0);
  $("import-select").replaceChildren(...caps.map((c) => new Option(c === "." ? "(this folder)" : c, c)));
  if (!p) { $("angles").replaceChildren(); return; }
  const angleSel = $("angle-select");
  const keep = angleSel.value;
  // a rig project (an imported capture) takes no photos: its cameras are the capture's
  angleSel.replaceChildren(...(p.turntable ? p.angles : []).map((a) => new Option(`${fmt(a.angle_deg)} (${a.status})`, a.angle_deg)));
  $("angles").classList.toggle("rig", !p.turntable);
  const next = p.angles.find((a) => a.status !== "taken");
  if (p.turntable) angleSel.value = keep && p.angles.some((a) => String(a.angle_deg) === keep) ? keep : String((next ?? p.angles[0]).angle_deg);
  $("angles").replaceChildren(...p.angles.map((a) => {
    const b = document.createElement("button");
    b.className = a.status + (current && a.view === current.name ? " current" : "");
    b.textContent = a.label ?? `${fmt(a.angle_deg)}°`;  // a rig project's tiles: its cameras' views
    b.title = a.view ? `${a.view}: ${a.identified} markers identified (${a.status})` : "missing";
    if (a.angle_deg != null) b.dataset.angle = a.angle_deg;
    if (a.view) b.dataset.view = a.view;
    b.dataset.status = a.status;
    b.onclick = () => { angleSel.value = String(a.angle_deg); if (a.view) showView(a.view); };
    return b;
  }));
  const names = p.markerset.markers.map((m) => m.name);
  for (const id of ["place-select", "relabel-select"]) {
    const s = $(id);
    if (s.options.length !== names.length) s.replaceChildren(...names.map((n) => new Option(n, n)));
  }
  const ex = $("exports");
  if (!ex.children.length) {
    ex.append(...Object.entries(state.export_formats).map(([fmt, what]) => {
      const b = document.createElement("button");
      b.textContent = `.${fmt}`;
      b.title = `Export: ${what}`;
      b.dataset.format = fmt;
      b.onclick = () => run(async () => {
        await download(`${P}/export/${fmt}`, `pose.${fmt}`);
        status(`exported ${what} (exports/pose.${fmt} in the project)`);
      });
      return b;
    }));
  }
}

const fmt = (a) => (Math.round(a * 10) / 10).toString();

async function run(fn) {
  try { await fn(); } catch (e) { status(e.message, true); }
}

$("new-btn").onclick = () => run(async () => {
  await api(`${P}/new`, { method: "POST", json: { path: $("new-path").value, distance_mm: +$("new-distance").value,
    height_mm: +$("new-height").value } });
  current = null; await refresh(); drawPhoto(); status("project created");
});
$("open-btn").onclick = () => run(async () => {
  await api(`${P}/open`, { method: "POST", json: { path: $("open-select").value } });
  current = null; await refresh(); await showFirst(); status("project opened");
});
$("import-btn").onclick = () => run(async () => {
  $("import-btn").disabled = true;
  $("import-progress").hidden = false;
  try {
    const job = await api(`${P}/import`, { method: "POST", json: { capture: $("import-select").value } });
    const r = await followJob(job, progressInto($("import-progress"), $("progress-text")), $("import-cancel"));
    current = null; await refresh(); await showFirst();
    status(r.imported ? `capture imported into the project folder “${r.project}” (${r.views} views)` : `opened the project folder “${r.project}”`);
  } finally { $("import-btn").disabled = false; }
});
$("save-btn").onclick = () => run(async () => { const r = await api(`${P}/save`, { method: "POST" }); status(`saved ${r.saved}`); });

// --- camera --------------------------------------------------------------------------------
$("camera-source").onchange = () => { $("server-index").hidden = $("camera-source").value !== "server"; };
$("camera-btn").onclick = () => run(startCamera);

async function startCamera() {
  const [w, h] = state?.project?.camera?.image_size ?? [640, 480];
  if ($("camera-source").value === "server") {
    const img = $("server-live");
    img.hidden = false; $("live").hidden = true;
    const blob = await (await api(`${P}/server-camera/frame?source=${+$("server-index").value}`, { raw: true })).blob();
    img.src = URL.createObjectURL(blob);
    status("server camera: preview of one frame (Take photo grabs a new one)");
    return;
  }
  $("server-live").hidden = true; $("live").hidden = false;
  if (stream) stream.getTracks().forEach((t) => t.stop());
  stream = await navigator.mediaDevices.getUserMedia({ video: { width: { ideal: w }, height: { ideal: h } }, audio: false });
  $("live").srcObject = stream;
  await $("live").play();
  status(`camera on (${$("live").videoWidth}x${$("live").videoHeight})`);
}

$("take-btn").onclick = () => run(async () => {
  const angle = $("angle-select").value;
  const taken = state.project.angles.find((a) => String(a.angle_deg) === angle);
  const replace = taken && taken.view ? "&replace=1" : "";
  let view;
  $("take-btn").disabled = true;
  try {
    if ($("camera-source").value === "server") {
      view = await api(`${P}/server-camera?source=${+$("server-index").value}&angle=${angle}${replace}`, { method: "POST" });
    } else {
      const v = $("live");
      if (!v.videoWidth) throw new Error("start the camera first");
      const c = document.createElement("canvas");
      c.width = v.videoWidth; c.height = v.videoHeight;
      c.getContext("2d").drawImage(v, 0, 0);
      const blob = await new Promise((r) => c.toBlob(r, "image/png"));
      const form = new FormData();
      form.append("file", blob, `angle_${angle}.png`);
      view = await api(`${P}/photo?angle=${angle}${replace}`, { method: "POST", body: form });
    }
  } finally { $("take-btn").disabled = false; }
  await refresh();
  await showView(view.name, view);
  const next = state.project.angles.find((a) => a.status === "missing");
  if (next) $("angle-select").value = String(next.angle_deg);
  status(`photo at ${fmt(+angle)} deg: ${view.markers.length} markers identified`);
});

// --- processed view ------------------------------------------------------------------------
async function showFirst() {
  const v = state?.project?.views?.[0];
  if (v) await showView(v.name);
}

async function showView(name, data) {
  // Everything is fetched before anything shown changes: a click during the fetch (on the old
  // view) must not be undone by this view's arrival, nor select a bead of a view not drawn yet.
  const view = data ?? await api(`${P}/view/${encodeURIComponent(name)}`);
  const blob = await (await api(`${P}/photo/${encodeURIComponent(name)}`, { raw: true })).blob();
  const bitmap = await createImageBitmap(blob);
  if (!current || current.name !== view.name) selected = null;  // the same view again keeps its selection
  current = view;
  photo = bitmap;
  showSelected();
  $("view-title").textContent = `— ${current.name}`;
  drawPhoto();
  const edits = current.edits.length ? `; ${current.edits.length} hand edits` : "";
  $("view-info").textContent = `${current.markers.length} identified, ${current.rejected.length} rejected` +
    (current.missing.length ? `; not found: ${current.missing.join(", ")}` : "") + edits;
  for (const b of $("angles").children) b.classList.toggle("current", b.dataset.view === current.name);
}

function drawPhoto() {
  const c = $("photo");
  const ctx = c.getContext("2d");
  if (!photo || !current) { c.width = 640; c.height = 480; ctx.clearRect(0, 0, c.width, c.height); return; }
  c.width = photo.width; c.height = photo.height;
  ctx.drawImage(photo, 0, 0);
  ctx.lineWidth = 2;
  ctx.font = "12px system-ui, sans-serif";
  for (const r of current.rejected) {  // rejected candidates: grey dashed circles with a cross
    const [x, y] = [r.xy[0] + 0.5, r.xy[1] + 0.5];
    ctx.setLineDash([3, 3]); ctx.strokeStyle = "#bbb";
    ctx.beginPath(); ctx.arc(x, y, (r.radius ?? 6) + 3, 0, 2 * Math.PI); ctx.stroke();
    ctx.setLineDash([]);
    ctx.beginPath(); ctx.moveTo(x - 4, y - 4); ctx.lineTo(x + 4, y + 4); ctx.moveTo(x + 4, y - 4); ctx.lineTo(x - 4, y + 4); ctx.stroke();
  }
  for (const m of current.markers) {  // identified beads: a ring in the marker's colour, name and confidence
    const [x, y] = [m.xy[0] + 0.5, m.xy[1] + 0.5];
    ctx.strokeStyle = m.name === selected ? "#fff" : m.color;
    ctx.lineWidth = m.name === selected ? 3 : 2;
    ctx.beginPath(); ctx.arc(x, y, 10, 0, 2 * Math.PI); ctx.stroke();
    const label = m.source === "edited" ? `${m.name} (edited)` : `${m.name} ${m.confidence == null ? "" : Math.round(m.confidence * 100) + "%"}`;
    ctx.fillStyle = "rgba(0,0,0,.6)";
    ctx.fillRect(x + 12, y - 8, ctx.measureText(label).width + 6, 15);
    ctx.fillStyle = m.color;
    ctx.fillText(label, x + 15, y + 4);
  }
}

function imageXY(ev) {
  const c = $("photo"), r = c.getBoundingClientRect();
  return [(ev.clientX - r.left) * c.width / r.width - 0.5, (ev.clientY - r.top) * c.height / r.height - 0.5];
}

$("photo").onclick = (ev) => run(async () => {
  if (!current) return;
  const [x, y] = imageXY(ev);
  const scale = $("photo").width / $("photo").getBoundingClientRect().width;
  // the nearest bead within the ring's radius (two rings can overlap: the first found may not be the one clicked)
  let hit = null, best = 12 * Math.max(1, scale);
  for (const m of current.markers) {
    const d = Math.hypot(m.xy[0] - x, m.xy[1] - y);
    if (d < best) { hit = m; best = d; }
  }
  if (hit && !ev.shiftKey) {  // select a bead (shift-click places even on a bead)
    selected = hit.name;
    showSelected();
    drawPhoto();
    return;
  }
  await edit({ op: "move", marker: $("place-select").value, xy: [x, y] });  // add or move a bead
  status(`${$("place-select").value} placed at (${x.toFixed(1)}, ${y.toFixed(1)}) px`);
});

/** The selected bead's panel (hidden when none is selected or the view no longer has it). */
function showSelected() {
  const m = selected && current ? current.markers.find((b) => b.name === selected) : null;
  if (!m) selected = null;
  $("selected-panel").hidden = !m;
  $("selected-name").textContent = m ?
    `${m.name} (${m.source}${m.confidence == null ? "" : ", confidence " + Math.round(m.confidence * 100) + "%"})` : "";
}

async function edit(body) {
  const v = await api(`${P}/view/${encodeURIComponent(current.name)}/edit`, { method: "POST", json: body });
  await showView(v.name, v);
  await refresh();
}

$("delete-btn").onclick = () => run(async () => {
  const name = selected;
  if (!name) throw new Error("click a bead first");
  await edit({ op: "delete", marker: name });
  status(`${name} deleted`);
});
$("relabel-btn").onclick = () => run(async () => {
  const [name, to] = [selected, $("relabel-select").value];
  if (!name) throw new Error("click a bead first");
  selected = to;  // the bead stays selected under its new name
  await edit({ op: "relabel", marker: name, to });
  status(`${name} relabelled as ${to}`);
});
for (const [id, action, msg] of [["redetect-btn", "redetect", "detected again (your edits still apply)"],
  ["clear-btn", "clear-edits", "edits undone"], ["retake-btn", "retake", "marked to retake"]]) {
  $(id).onclick = () => run(async () => {
    if (!current) throw new Error("choose a view first");
    await api(`${P}/view/${encodeURIComponent(current.name)}/${action}`, { method: "POST" });
    await refresh();
    await showView(current.name);
    status(msg);
  });
}

// --- 3D ------------------------------------------------------------------------------------
$("compute-btn").onclick = () => run(async () => {
  $("compute-btn").disabled = true;
  try {
    const job = await api(`${P}/reconstruct`, { method: "POST" });
    const result = await followJob(job, progressInto($("progress"), $("progress-text")), $("compute-cancel"));
    show3D(result);
    status(`3D: ${result.markers.filter((m) => !m.missing).length} of ${result.markers.length} markers`);
  } finally { $("compute-btn").disabled = false; }
});

function show3D(result) {
  scene3d.show(result);
  const flags = $("flags");
  flags.replaceChildren();
  const line = (label, text) => {  // text, not HTML: names come from files
    const d = document.createElement("div");
    if (label) { const s = document.createElement("span"); s.className = "flag"; s.textContent = label + " "; d.append(s); }
    d.append(text);
    flags.append(d);
  };
  if (result.missing.length) line("seen in fewer than two views (no 3D):", result.missing.join(", "));
  if (result.weak.length) line("fewer than two whole views:", result.weak.join(", "));
  line("", `pose fit RMS ${result.pose_fit.rms_mm?.toFixed(2) ?? "-"} mm`);
  const t = $("angles-table");
  t.replaceChildren();
  const head = t.insertRow();
  for (const h of ["joint", "X", "Y", "Z"]) head.insertCell().textContent = h;
  for (const j of result.joints) {
    const r = t.insertRow();
    r.insertCell().textContent = j.name;
    for (const a of j.angles_deg) r.insertCell().textContent = a.toFixed(1);
  }
}

// --- start ---------------------------------------------------------------------------------
run(async () => {
  const info = await api("/api/info");
  $("folder").textContent = info.root;
  await refresh();
  await showFirst();
  if (state.project?.has_result) show3D(await api(`${P}/result`));
});
