// The hand page: the labelled glove markers per flash, relabelled by hand into the label overrides
// file, and the hand's skeleton with the ball scrubbed over time.
import { api, followJob, progressInto, status } from "./common.js";
import { createView, frameStatistics, frustum, objectsOfKind, sphere } from "./viewer3d.js";

const GLOVE = { red: 0xe53935, yellow: 0xfdd835, green: 0x43a047, blue: 0x1e88e5 };
const BALL_RADIUS = 0.0369;
const $ = (id) => document.getElementById(id);
const state = { items: [], path: null, view: null, flash: 0, selected: null, overrides: [], saved: [], t: 0 };
let view3d = null, playing = null;

function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v; else if (k.startsWith("data-")) e.setAttribute(k, v); else e[k] = v;
  }
  for (const c of children) e.append(c);
  return e;
}
const fmt = (v, d = 3) => (v === null || v === undefined ? "–" : Number(v).toFixed(d));
const near = (a, b) => Math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]) < 5e-4;

// ---------------------------------------------------------------------------------------------
async function loadItems() {
  const info = await api("/api/info");
  $("folder").textContent = info.root;
  const { items } = await api("/api/hand/items");
  state.items = items;
  $("items").replaceChildren(...items.map((it) => {
    const li = el("li", { "data-path": it.path }, it.name, el("span", { class: "kind" }, it.kind + (it.kind === "capture" && !it.analysed ? " · not analysed" : "")));
    li.onclick = () => openItem(it.path);
    return li;
  }));
  if (!items.length) status("No hand capture or result in the opened folder.", true);
  return items;
}

async function openItem(path, { analyseIfNeeded = true } = {}) {
  state.path = path;
  for (const li of $("items").children) li.classList.toggle("here", li.dataset.path === path);
  history.replaceState(null, "", `?item=${encodeURIComponent(path)}`);
  status("loading …");
  const v = await api(`/api/hand/view?path=${encodeURIComponent(path)}`);
  state.view = v;
  $("title").textContent = v.name;
  const item = state.items.find((i) => i.path === path);
  $("analyse").hidden = !(item && item.kind === "capture");
  $("analyse").textContent = v.analysed ? "Analyse again" : "Analyse";
  $("analyse").onclick = () => analyse(path);
  if (!v.analysed) {
    $("hand-view").hidden = true;
    if (analyseIfNeeded) return analyse(path);
    status("Not analysed yet: press Analyse.");
    return;
  }
  await loadOverrides();
  showView(v);
  status(v.notes.join(" · "));
}

async function analyse(path) {
  $("analyse").disabled = true;
  $("progress").hidden = false;
  try {
    const job = await api("/api/hand/analyse", { method: "POST", json: { path } });
    await followJob(job, progressInto($("progress"), $("progress-text")), $("cancel-job"));
    await loadItems();
    await openItem(path, { analyseIfNeeded: false });
  } catch (e) {
    status(e.message, true);
  } finally {
    $("analyse").disabled = false;
    $("progress").hidden = true;
  }
}

async function loadOverrides() {
  const o = await api(`/api/hand/overrides?path=${encodeURIComponent(state.path)}`);
  state.saved = o.overrides;
  state.overrides = o.overrides.map((e) => ({ ...e }));
  $("overrides-file").textContent = o.file + (o.exists ? "" : " (not written yet)");
  showOverrides();
}

// ---------------------------------------------------------------------------------------------
function showView(v) {
  $("hand-view").hidden = false;
  $("flash").replaceChildren(...v.flashes.map((f) => el("option", { value: f.flash },
    `${f.order} (${fmt(f.time_s * 1e3, 1)} ms${f.reconstructed ? "" : ", no pose"})`)));
  $("flash").onchange = () => selectFlash(Number($("flash").value));
  $("show-all-flashes").onchange = () => drawScene(true);
  $("frame-hand").onclick = () => drawScene(true);
  const times = timeline(v);
  state.t0 = times[0]; state.t1 = times[1];
  $("time").oninput = () => setTime(state.t0 + (state.t1 - state.t0) * $("time").value / 1000, false);
  $("play").onclick = togglePlay;
  showRelease(v);
  state.framed = false;
  if (!view3d) {
    view3d = createView($("view3d"));
    window.stillcapHand = { view: view3d, objectsOfKind: (k) => objectsOfKind(view3d, k), frameStatistics: () => frameStatistics(view3d), selectFlash, setTime, state };
    view3d.canvas.addEventListener("click", pick);
  }
  selectFlash(Math.min(state.flash, v.flashes.length - 1), { frame: true });
}

function timeline(v) {
  const ts = v.flashes.map((f) => f.time_s);
  if (v.animation) ts.push(...v.animation.times_s);
  if (v.ball) ts.push(...v.ball.times_s.filter((t) => t !== null));
  return [Math.min(...ts), Math.max(...ts)];
}

function selectFlash(k, { frame = false } = {}) {
  state.flash = k;
  state.selected = null;
  $("flash").value = String(k);
  const f = state.view.flashes[k];
  flashHeader(f);
  showPoints();
  setTime(f.time_s, true, frame);
}

function setTime(t, fromFlash = false, frame = false) {
  state.t = t;
  if (!fromFlash) {
    // the flash nearest the time shows its markers
    let best = 0;
    state.view.flashes.forEach((f, i) => { if (Math.abs(f.time_s - t) < Math.abs(state.view.flashes[best].time_s - t)) best = i; });
    if (best !== state.flash) { state.flash = best; $("flash").value = String(best); selectFlashQuiet(best); }
  } else {
    $("time").value = String(Math.round(1000 * (t - state.t0) / ((state.t1 - state.t0) || 1)));
  }
  const rel = state.view.release?.t0_s;
  $("time-text").textContent = `${fmt(t * 1e3, 1)} ms` + (rel !== null && rel !== undefined ? ` (release ${t >= rel ? "+" : "−"}${fmt(Math.abs(t - rel) * 1e3, 1)} ms)` : "");
  drawScene(frame);
}
function flashHeader(f) {
  $("flash-name").textContent = `${f.order}`;
  $("flash-info").textContent = `${fmt(f.time_s * 1e3, 1)} ms · ${f.points.filter((p) => p.label).length} labelled of ${f.points.length} points` +
    (f.reconstructed ? ` · fit RMS ${fmt(f.rms_mm, 2)} mm` : ` · no pose: ${f.skipped}`);
}
function selectFlashQuiet(k) {
  flashHeader(state.view.flashes[k]);
  state.selected = null;
  showPoints();
}

function togglePlay() {
  if (playing) { cancelAnimationFrame(playing); playing = null; $("play").textContent = "▶ play"; return; }
  $("play").textContent = "❚❚ pause";
  const span = state.t1 - state.t0, slow = 40;  // 40x slower than real time
  let last = performance.now();
  const step = (now) => {
    let t = state.t + (now - last) / 1000 / slow;
    last = now;
    if (t > state.t1) t = state.t0;
    $("time").value = String(Math.round(1000 * (t - state.t0) / (span || 1)));
    setTime(t);
    playing = requestAnimationFrame(step);
  };
  playing = requestAnimationFrame(step);
}

/** The joints at time t: the animation's frames (or the flashes' poses) interpolated linearly. */
function jointsAt(v, t) {
  let ts, frames;
  if (v.animation) { ts = v.animation.times_s; frames = v.animation.joints; }
  else {
    const keys = v.flashes.filter((f) => f.joints);
    ts = keys.map((f) => f.time_s); frames = keys.map((f) => f.joints);
  }
  if (!ts.length) return null;
  if (t <= ts[0]) return frames[0];
  if (t >= ts[ts.length - 1]) return frames[frames.length - 1];
  let i = 1;
  while (ts[i] < t) i++;
  const a = (t - ts[i - 1]) / (ts[i] - ts[i - 1]);
  return frames[i - 1].map((p, j) => p.map((x, c) => x + a * (frames[i][j][c] - x)));
}

function ballAt(v, t) {
  const b = v.ball;
  if (!b) return null;
  const idx = b.times_s.map((tt, i) => i).filter((i) => b.times_s[i] !== null && b.positions[i] && b.positions[i].every((x) => x !== null));
  if (!idx.length) return null;
  let k = idx[0];
  for (const i of idx) if (Math.abs(b.times_s[i] - t) < Math.abs(b.times_s[k] - t)) k = i;
  const rel = v.release?.t0_s;
  // between two flashes: linear; outside them: the nearest one
  const before = idx.filter((i) => b.times_s[i] <= t).pop(), after = idx.find((i) => b.times_s[i] >= t);
  let p = b.positions[k];
  if (before !== undefined && after !== undefined && after !== before) {
    const a = (t - b.times_s[before]) / (b.times_s[after] - b.times_s[before]);
    p = b.positions[before].map((x, c) => x + a * (b.positions[after][c] - x));
  }
  const held = rel !== null && rel !== undefined ? t < rel : (b.held ? b.held[k] : true);
  return { p, held };
}

function drawScene(frame = false) {
  const v = state.view, THREE = view3d.THREE;
  view3d.clear();
  const hand = new THREE.Group();
  const flashes = $("show-all-flashes").checked ? v.flashes.map((f, i) => i) : [state.flash];
  for (const k of flashes) {
    v.flashes[k].points.forEach((p, i) => {
      const m = sphere(p.position, p.label ? 0.006 : 0.0045, GLOVE[p.colour] ?? 0x888888, { kind: "marker", flash: k, index: i, label: p.label });
      if (!p.label) { m.material.transparent = true; m.material.opacity = 0.45; }
      if (k === state.flash && i === state.selected) m.scale.setScalar(1.8);
      hand.add(m);
    });
  }
  const joints = jointsAt(v, state.t);
  if (joints && v.parents) {
    const segs = [];
    v.parents.forEach((pa, j) => { if (pa >= 0 && joints[j][0] !== null && joints[pa][0] !== null) segs.push(new THREE.Vector3(...joints[pa]), new THREE.Vector3(...joints[j])); });
    const bones = new THREE.LineSegments(new THREE.BufferGeometry().setFromPoints(segs), new THREE.LineBasicMaterial({ color: 0x333333 }));
    bones.userData = { kind: "skeleton" };
    hand.add(bones);
    joints.forEach((p) => { if (p[0] !== null) hand.add(sphere(p, 0.003, 0x555555, { kind: "joint" })); });
  }
  const ball = ballAt(v, state.t);
  if (ball) hand.add(sphere(ball.p, BALL_RADIUS, ball.held ? 0xffffff : 0xff9800, { kind: "ball", held: ball.held }));
  if (v.ball) for (const p of v.ball.positions) if (p && p.every((x) => x !== null)) hand.add(sphere(p, 0.006, 0xbbbbbb, { kind: "ball-flash" }));
  view3d.content.add(hand);
  if (frame || !state.framed) {
    // frame the hand: the shown flash's labelled markers and the skeleton (unlabelled points can
    // be strays far off, and the whole take spans a metre of throw); with "all flashes", the take
    const box = new THREE.Group();
    const add = (p) => { if (p && p.every((x) => x !== null)) box.add(sphere(p, 0.01, 0, {})); };
    if ($("show-all-flashes").checked) {
      for (const f of v.flashes) for (const p of f.points) add(p.position);
    } else {
      for (const p of v.flashes[state.flash].points) if (p.label) add(p.position);
      if (joints) joints.forEach(add);
      if (box.children.length < 2) for (const p of v.flashes[state.flash].points) add(p.position);
    }
    view3d.frame([0.2, 1, 0.35], box.children.length ? box : hand);
    state.framed = true;
  }
  view3d.render();
}

function pick(e) {
  const THREE = view3d.THREE, r = view3d.canvas.getBoundingClientRect();
  const ndc = new THREE.Vector2(((e.clientX - r.left) / r.width) * 2 - 1, -((e.clientY - r.top) / r.height) * 2 + 1);
  const ray = new THREE.Raycaster();
  ray.setFromCamera(ndc, view3d.camera);
  const hit = ray.intersectObjects(objectsOfKind(view3d, "marker"), false)[0];
  if (!hit) return;
  const { flash, index } = hit.object.userData;
  if (flash !== state.flash) selectFlash(flash);
  selectPoint(index);
}

function selectPoint(i) {
  state.selected = i;
  for (const tr of $("points-table").tBodies[0].rows) tr.classList.toggle("here", Number(tr.dataset.index) === i);
  drawScene();
}

// ---------------------------------------------------------------------------------------------
// relabelling
// ---------------------------------------------------------------------------------------------
function pendingFor(k, p) {
  return state.overrides.find((o) => o.flash === k && near(o.position_m, p.position));
}

function showPoints() {
  const v = state.view, k = state.flash, f = v.flashes[k];
  const body = $("points-table").tBodies[0];
  body.replaceChildren(...f.points.map((p, i) => {
    const sel = el("select", { "data-index": i, "aria-label": `relabel point ${i}` },
      el("option", { value: "" }, "—"), ...v.marker_names.map((n) => el("option", { value: n }, n)), el("option", { value: "__delete__" }, "delete"));
    const o = pendingFor(k, p);
    sel.value = o ? (o.delete ? "__delete__" : o.label) : "";
    sel.onchange = () => relabel(k, p, sel.value);
    const tr = el("tr", { "data-index": i, "data-label": p.label ?? "" }, el("td", {}, String(i)),
      el("td", {}, el("span", { class: "swatch", style: `background:#${(GLOVE[p.colour] ?? 0x888888).toString(16).padStart(6, "0")}` }), p.colour),
      el("td", { class: "label" }, p.label ?? "(unlabelled)"), el("td", {}, sel));
    tr.onclick = (e) => { if (e.target.tagName !== "SELECT" && e.target.tagName !== "OPTION") selectPoint(i); };
    return tr;
  }));
}

function relabel(k, p, value) {
  state.overrides = state.overrides.filter((o) => !(o.flash === k && near(o.position_m, p.position)));
  if (value === "__delete__") state.overrides.push({ flash: k, position_m: p.position, delete: true });
  else if (value) state.overrides.push({ flash: k, position_m: p.position, label: value });
  showOverrides();
}

function showOverrides() {
  const saved = JSON.stringify(state.saved);
  $("overrides-table").tBodies[0].replaceChildren(...state.overrides.map((o, i) => {
    const pending = !state.saved.some((s) => JSON.stringify(s) === JSON.stringify(o));
    const rm = el("button", { title: "remove this override" }, "×");
    rm.onclick = () => { state.overrides.splice(i, 1); showOverrides(); showPoints(); };
    return el("tr", { class: pending ? "pending" : "" }, el("td", {}, String(o.flash)),
      el("td", {}, o.position_m.map((x) => x.toFixed(4)).join(", ")), el("td", {}, o.delete ? "deleted" : o.label), el("td", {}, rm));
  }));
  const changed = saved !== JSON.stringify(state.overrides);
  $("save").disabled = !changed;
  $("save").textContent = changed ? "Save overrides" : "Saved";
}

async function save() {
  const o = await api("/api/hand/overrides", { method: "PUT", json: { path: state.path, overrides: state.overrides } });
  state.saved = o.overrides;
  state.overrides = o.overrides.map((e) => ({ ...e }));
  $("overrides-file").textContent = o.file;
  showOverrides();
  status(`saved ${o.overrides.length} override(s) to ${o.file}`);
}

function showRelease(v) {
  const r = v.release;
  const rows = r ? [["release time", `${fmt(r.t0_s * 1e3, 2)} ± ${fmt(r.t0_sigma_s * 1e3, 2)} ms`],
    ["speed", `${fmt(r.speed_mph, 1)} ± ${fmt(r.speed_sigma_mph, 1)} mph`],
    ["direction (horizontal / vertical)", `${fmt(r.horizontal_deg, 1)} / ${fmt(r.vertical_deg, 1)} ± ${fmt(r.direction_sigma_deg, 1)} deg`],
    ["point", r.p0 ? r.p0.map((x) => x.toFixed(3)).join(", ") + " m" : "–"], ["note", r.message || ""]] : [["release", "not estimated"]];
  $("release-table").tBodies[0].replaceChildren(...rows.map(([a, b]) => el("tr", {}, el("th", {}, a), el("td", {}, b))));
  $("messages").replaceChildren(...(v.messages ?? []).map((m) => el("li", {}, m)));
}

// ---------------------------------------------------------------------------------------------
async function main() {
  $("save").onclick = () => save().catch((e) => status(e.message, true));
  $("save-analyse").onclick = async () => {
    try {
      await save();
      const item = state.items.find((i) => i.path === state.path);
      if (item?.kind === "capture") await analyse(state.path);
      else status("saved; this is a result file: analyse its capture to apply the overrides", false);
    } catch (e) { status(e.message, true); }
  };
  try {
    const items = await loadItems();
    const q = new URLSearchParams(location.search);
    if (q.get("item") !== null) await openItem(q.get("item"));
    else if (items.length) await openItem(items[0].path);
  } catch (e) {
    status(e.message, true);
  }
}
main();
