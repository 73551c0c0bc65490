// The pitch page: captures, results and sessions of the opened folder; photos with what was found
// on them, the flight in 3D, metrics, self-checks, plate view, and pitches compared.
import { api, followJob, progressInto, status } from "./common.js";
import { createView, ellipsoid, frameStatistics, frustum, ground, objectsOfKind, polyline, sphere } from "./viewer3d.js";

const PAIR_COLOURS = [0x1f6feb, 0xe65100, 0x2e7d32, 0x6a1b9a];
const SESSION_COLOURS = ["#1f6feb", "#e65100", "#2e7d32", "#6a1b9a", "#c62828", "#00838f", "#5d4037", "#827717"];
const MARKER_COLOURS = { red: "#ff1744", green: "#00e676", blue: "#2979ff", black: "#000", yellow: "#ffea00", white: "#fff" };
const $ = (id) => document.getElementById(id);
const state = { items: [], current: null, view: null, photo: null };
let view3d = null, session3d = null;

/** A number as the tables show it: 3 decimals (sigmas: 2 significant digits). */
export function fmt(v, digits = 3) {
  if (v === null || v === undefined) return "–";
  if (typeof v === "string") return v;
  return Number(v).toFixed(digits);
}
function fmtSigma(v) {
  if (v === null || v === undefined) return "–";
  return Math.abs(v) >= 100 ? v.toFixed(0) : Number(v.toPrecision(2)).toString();
}
function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v; else if (k.startsWith("data-")) e.setAttribute(k, v); else e[k] = v;
  }
  for (const c of children) e.append(c);
  return e;
}
function svgEl(tag, attrs = {}, text) {
  const e = document.createElementNS("http://www.w3.org/2000/svg", tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}
const photoUrl = (file, w) => `/api/pitch/photo?path=${encodeURIComponent(file)}${w ? `&w=${w}` : ""}`;

// ---------------------------------------------------------------------------------------------
// items
// ---------------------------------------------------------------------------------------------
async function loadItems() {
  const info = await api("/api/info");
  $("folder").textContent = info.root;
  const { items } = await api("/api/pitch/items");
  state.items = items;
  const ul = $("items");
  ul.replaceChildren(...items.map((it) => {
    const li = el("li", { "data-path": it.path }, it.name, el("span", { class: "kind" }, it.kind + (it.kind === "capture" && !it.analysed ? " · not analysed" : "")));
    li.onclick = () => openItem(it.path);
    return li;
  }));
  if (!items.length) status("No pitch capture or result in the opened folder.", true);
  return items;
}

async function openItem(path) {
  state.current = path;
  for (const li of $("items").children) li.classList.toggle("here", li.dataset.path === path);
  $("session-view").hidden = true;
  history.replaceState(null, "", `?item=${encodeURIComponent(path)}`);
  status("loading …");
  try {
    const v = await api(`/api/pitch/view?path=${encodeURIComponent(path)}`);
    state.view = v;
    showView(v);
    status(v.notes.join(" · "));
  } catch (e) {
    status(e.message, true);
  }
}

async function analyse(path) {
  $("analyse").disabled = true;
  $("progress").hidden = false;
  try {
    const job = await api("/api/pitch/analyse", { method: "POST", json: { path } });
    await followJob(job, progressInto($("progress"), $("progress-text")), $("cancel-job"));
    await loadItems();
    await openItem(path);
  } catch (e) {
    status(e.message, true);
  } finally {
    $("analyse").disabled = false;
    $("progress").hidden = true;
  }
}

// ---------------------------------------------------------------------------------------------
// one pitch
// ---------------------------------------------------------------------------------------------
function showView(v) {
  $("pitch-view").hidden = false;
  $("title").textContent = v.name;
  $("description").textContent = v.description ?? "";
  const item = state.items.find((i) => i.path === v.path);
  $("analyse").hidden = !(item && item.kind === "capture");
  $("analyse").textContent = v.analysed ? "Analyse again" : "Analyse";
  $("analyse").onclick = () => analyse(v.path);
  showMetrics(v);
  showChecks(v);
  drawPlate($("plate-svg"), $("movement-svg"), v.analysed ? [{ plate: v.plate, colour: "#1f6feb" }] : []);
  $("plate-text").textContent = v.plate ? plateText(v.plate) : "";
  draw3d(v);
  showPhotos(v);
}

function plateText(p) {
  const s = (k, d = 2) => `${fmt(p.values[k], d)} ± ${fmtSigma(p.sigmas[k])}`;
  return `plate x ${s("plate_x_ft")} ft, z ${s("plate_z_ft")} ft; horizontal break ${s("horizontal_break_in", 1)} in, ` +
         `induced vertical break ${s("induced_vertical_break_in", 1)} in; the zone drawn is a typical one (1.5–3.5 ft): the batter's own sets it.`;
}

function showMetrics(v) {
  const body = $("metrics-table").tBodies[0];
  body.replaceChildren(...(v.metrics ?? []).map((m) => el("tr", { "data-key": m.key },
    el("td", {}, m.key), el("td", { class: "value" }, fmt(m.value)), el("td", { class: "sigma" }, fmtSigma(m.sigma)),
    el("td", {}, m.unit))));
  if (!v.analysed) body.append(el("tr", {}, el("td", { colSpan: 4 }, "Not analysed yet: press Analyse.")));
}

function showChecks(v) {
  const body = $("checks-table").tBodies[0];
  const checks = v.self_checks ?? [];
  body.replaceChildren(...checks.map((c) => el("tr", { class: c.passed ? "passed" : "failed", "data-name": c.name },
    el("td", {}, c.passed ? "✓" : "✗"), el("td", {}, c.name), el("td", {}, c.subject ?? ""),
    el("td", {}, `${fmt(c.value)} ${c.unit ?? ""}`), el("td", {}, `${fmt(c.limit)} ${c.unit ?? ""}`), el("td", {}, c.message))));
  if (!checks.length) body.append(el("tr", {}, el("td", { colSpan: 6, class: "muted" }, v.analysed ? "This result carries no self-checks." : "")));
  $("messages").replaceChildren(...(v.messages ?? []).map((m) => el("li", {}, m)));
}

function draw3d(v) {
  if (!view3d) {
    view3d = createView($("view3d"));
    for (const [id, dir] of [["view-side", [1, 0, 0.05]], ["view-top", [0, 0.01, 1]], ["view-catcher", [0, -1, 0.15]]]) {
      $(id).onclick = () => view3d.frame(dir, flightGroup ?? view3d.content);
    }
    $("show-ellipsoids").onchange = () => draw3d(state.view);
    $("ellipsoid-scale").onchange = () => draw3d(state.view);
    $("show-cameras").onchange = () => draw3d(state.view);
    window.stillcapPitch = { view: view3d, objectsOfKind: (k) => objectsOfKind(view3d, k), frameStatistics: () => frameStatistics(view3d) };
  }
  view3d.clear();
  const THREE = view3d.THREE;
  flightGroup = new THREE.Group();
  const all = [];
  const scale = Number($("ellipsoid-scale").value);
  (v.pairs ?? []).forEach((p, i) => {
    p.positions.forEach((x, k) => {
      all.push(x);
      flightGroup.add(sphere(x, 0.037, PAIR_COLOURS[i % PAIR_COLOURS.length], { kind: "position", pair: p.name, flash: p.flash_index[k] }));
      const ax = p.ellipsoid_axes_m?.[k];
      if (ax && $("show-ellipsoids").checked) flightGroup.add(ellipsoid(x, ax, scale, PAIR_COLOURS[i % PAIR_COLOURS.length]));
    });
  });
  if (v.trajectory) {
    const line = polyline(v.trajectory.positions, 0x222222);
    line.userData = { kind: "trajectory" };
    flightGroup.add(line);
    all.push(...v.trajectory.positions);
  }
  if (v.spin && v.spin.at) {
    const arrow = new THREE.ArrowHelper(new THREE.Vector3(...v.spin.axis), new THREE.Vector3(...v.spin.at), 0.6, 0xd81b60, 0.12, 0.06);
    arrow.userData = { kind: "spin-axis" };
    flightGroup.add(arrow);
  }
  view3d.content.add(flightGroup);
  // home plate (the pentagon, 17 in wide, at the field origin) and the ground
  const ft = 0.3048, w = 17 / 24 * ft;
  const plate = polyline([[-w, 17 / 12 * ft, 0], [w, 17 / 12 * ft, 0], [w, 8.5 / 12 * ft, 0], [0, 0, 0], [-w, 8.5 / 12 * ft, 0], [-w, 17 / 12 * ft, 0]], 0x333333);
  plate.userData = { kind: "plate" };
  view3d.content.add(plate);
  if ($("show-cameras").checked) for (const c of v.cameras ?? []) view3d.content.add(frustum(c));
  const ys = all.map((p) => p[1]);
  const cy = ys.length ? (Math.min(...ys, 0) + Math.max(...ys)) / 2 : 0;
  view3d.content.add(ground(0, cy, Math.max(20, (ys.length ? Math.max(...ys) : 0) + 4), 1));
  view3d.frame([1, -0.6, 0.5], all.length ? flightGroup : view3d.content);
}
let flightGroup = null;

// ---------------------------------------------------------------------------------------------
// photos, zoomable, with the balls and markers over them
// ---------------------------------------------------------------------------------------------
function showPhotos(v) {
  const thumbs = $("thumbs");
  thumbs.replaceChildren(...(v.photos ?? []).map((ph, i) => {
    const fig = el("figure", { "data-file": ph.file }, el("img", { src: photoUrl(ph.file, 240), alt: ph.camera }),
      el("figcaption", {}, `${ph.camera} · ${ph.balls.length} balls${ph.markers.length ? ` · ${ph.markers.length} markers` : ""}`));
    fig.onclick = () => showPhoto(ph);
    return fig;
  }));
  $("zoom").hidden = !(v.photos ?? []).length;
  if ((v.photos ?? []).length) showPhoto(v.photos[0]);
}

const zoom = { s: 1, x: 0, y: 0, photo: null, full: false };
function applyZoom() {
  $("zoom-inner").style.transform = `translate(${zoom.x}px, ${zoom.y}px) scale(${zoom.s})`;
  if (zoom.photo && !zoom.full && zoom.s * $("zoom-img").width > 1.2 * Math.min(1600, zoom.photo.width)) {
    zoom.full = true;  // close up: the photo at its own resolution
    $("zoom-img").src = photoUrl(zoom.photo.file);
  }
}
function showPhoto(ph) {
  state.photo = ph;
  for (const f of $("thumbs").children) f.classList.toggle("here", f.dataset.file === ph.file);
  const img = $("zoom-img"), svg = $("zoom-svg"), box = $("zoom");
  zoom.photo = ph; zoom.full = false;
  img.src = photoUrl(ph.file, Math.min(1600, ph.width));
  img.width = ph.width; img.height = ph.height;   // CSS size in photo pixels: the overlay shares them
  svg.setAttribute("width", ph.width); svg.setAttribute("height", ph.height);
  svg.setAttribute("viewBox", `0 0 ${ph.width} ${ph.height}`);
  const parts = [];
  for (const b of ph.balls) {
    parts.push(svgEl("circle", { cx: b.x, cy: b.y, r: b.r ?? 10, fill: "none", stroke: "#00e5ff", "stroke-width": 2, "vector-effect": "non-scaling-stroke", class: "ball" }));
    if (b.flash !== null) parts.push(svgEl("text", { x: b.x, y: b.y - (b.r ?? 10) - 4, fill: "#ffeb3b", "font-size": Math.max(12, (b.r ?? 10) * 0.9), "text-anchor": "middle", class: "flash" }, String(b.flash)));
  }
  for (const m of ph.markers) {
    const c = MARKER_COLOURS[m.type] ?? "#ff00ff", r = 3;
    parts.push(svgEl("path", { d: `M${m.x - r},${m.y - r}L${m.x + r},${m.y + r}M${m.x - r},${m.y + r}L${m.x + r},${m.y - r}`, stroke: c, "stroke-width": 1.5, "vector-effect": "non-scaling-stroke", class: "marker" }));
  }
  svg.replaceChildren(...parts);
  // fit the photo's width into the box
  zoom.s = (box.clientWidth || 800) / ph.width;
  zoom.x = 0; zoom.y = Math.max(0, ((box.clientHeight || 520) - ph.height * zoom.s) / 2);
  applyZoom();
}
function setupZoom() {
  const box = $("zoom");
  box.addEventListener("wheel", (e) => {
    e.preventDefault();
    const r = box.getBoundingClientRect(), mx = e.clientX - r.left, my = e.clientY - r.top;
    const f = Math.exp(-e.deltaY * 0.0015), s = Math.min(Math.max(zoom.s * f, 0.05), 20);
    zoom.x = mx - (mx - zoom.x) * (s / zoom.s); zoom.y = my - (my - zoom.y) * (s / zoom.s); zoom.s = s;
    applyZoom();
  }, { passive: false });
  let drag = null;
  box.addEventListener("pointerdown", (e) => { drag = { x: e.clientX - zoom.x, y: e.clientY - zoom.y }; box.classList.add("dragging"); box.setPointerCapture(e.pointerId); });
  box.addEventListener("pointermove", (e) => { if (drag) { zoom.x = e.clientX - drag.x; zoom.y = e.clientY - drag.y; applyZoom(); } });
  box.addEventListener("pointerup", () => { drag = null; box.classList.remove("dragging"); });
}
/** Zoom the photo so that its point (x, y) (photo pixels) is in the middle at scale s (scripts, screenshots). */
function zoomTo(x, y, s) {
  const box = $("zoom");
  zoom.s = s; zoom.x = box.clientWidth / 2 - x * s; zoom.y = box.clientHeight / 2 - y * s;
  applyZoom();
}

// ---------------------------------------------------------------------------------------------
// plate and movement
// ---------------------------------------------------------------------------------------------
function drawPlate(plateSvg, moveSvg, entries) {
  // catcher's view: x to the right (ft, the catcher's right), z up
  const W = 260, H = 300, sx = W / 5, x0 = W / 2, z0 = H - 20, sz = (H - 40) / 5;
  const X = (x) => x0 + x * sx, Z = (z) => z0 - z * sz;
  const p = [];
  p.push(svgEl("line", { x1: 0, y1: Z(0), x2: W, y2: Z(0), stroke: "#aaa" }));
  const zone = entries[0]?.plate?.zone_ft ?? { left: -17 / 24, right: 17 / 24, bottom: 1.5, top: 3.5 };
  p.push(svgEl("rect", { x: X(zone.left), y: Z(zone.top), width: (zone.right - zone.left) * sx, height: (zone.top - zone.bottom) * sz, fill: "#f1f5fb", stroke: "#555", "stroke-dasharray": "4 3", class: "zone" }));
  p.push(svgEl("path", { d: `M${X(zone.left)},${Z(0) + 6}H${X(zone.right)}`, stroke: "#333", "stroke-width": 4 }));
  for (const z of [1, 2, 3, 4]) p.push(svgEl("text", { x: 4, y: Z(z) + 4, "font-size": 10, fill: "#888" }, `${z} ft`));
  for (const e of entries) {
    const v = e.plate?.values ?? e.plate;
    if (v?.plate_x_ft == null || v?.plate_z_ft == null) continue;
    p.push(svgEl("circle", { cx: X(v.plate_x_ft), cy: Z(v.plate_z_ft), r: 0.1208 * sx, fill: e.colour, "fill-opacity": 0.7, stroke: "#000", class: "crossing" }));
  }
  plateSvg.replaceChildren(...p);
  // movement: horizontal break (in, catcher's view: + to the catcher's right) and induced vertical break
  const M = 300, c = M / 2, s = (M - 30) / 60;
  const q = [svgEl("line", { x1: 0, y1: c, x2: M, y2: c, stroke: "#ccc" }), svgEl("line", { x1: c, y1: 0, x2: c, y2: M, stroke: "#ccc" })];
  for (const t of [-20, -10, 10, 20]) {
    q.push(svgEl("text", { x: c + t * s, y: c + 12, "font-size": 9, fill: "#999", "text-anchor": "middle" }, String(t)));
    q.push(svgEl("text", { x: c + 3, y: c - t * s + 3, "font-size": 9, fill: "#999" }, String(t)));
  }
  q.push(svgEl("text", { x: M - 4, y: c - 4, "font-size": 10, fill: "#666", "text-anchor": "end" }, "HB in"));
  q.push(svgEl("text", { x: c + 4, y: 12, "font-size": 10, fill: "#666" }, "IVB in"));
  for (const e of entries) {
    const v = e.plate?.values ?? e.plate;
    if (v?.horizontal_break_in == null || v?.induced_vertical_break_in == null) continue;
    q.push(svgEl("circle", { cx: c + v.horizontal_break_in * s, cy: c - v.induced_vertical_break_in * s, r: 5, fill: e.colour, stroke: "#000", class: "movement" }));
  }
  moveSvg.replaceChildren(...q);
}

// ---------------------------------------------------------------------------------------------
// the session: pitches compared
// ---------------------------------------------------------------------------------------------
async function showSession() {
  $("pitch-view").hidden = true;
  $("session-view").hidden = false;
  $("title").textContent = "Session";
  $("analyse").hidden = true;
  history.replaceState(null, "", "?session=1");
  for (const li of $("items").children) li.classList.remove("here");
  const s = await api("/api/pitch/session?path=");
  const head = $("session-table").tHead, body = $("session-table").tBodies[0];
  head.replaceChildren(el("tr", {}, el("th", {}, ""), el("th", {}, "pitch"), el("th", {}, "balls"),
    ...s.columns.map((c) => el("th", {}, c.label)), el("th", {}, "failed checks")));
  const analysed = s.rows.filter((r) => r.analysed);
  body.replaceChildren(...s.rows.map((r) => {
    const i = analysed.indexOf(r);
    const tr = el("tr", { class: "clickable", "data-path": r.path },
      el("td", {}, i >= 0 ? el("span", { class: "sw", style: `background:${SESSION_COLOURS[i % SESSION_COLOURS.length]}` }) : ""),
      el("td", {}, r.name), el("td", {}, r.analysed ? String(r.n_positions) : (r.error ?? "not analysed")),
      ...s.columns.map((c) => el("td", { "data-key": c.key }, r.analysed ? `${fmt(r.metrics[c.key].value, 2)} ± ${fmtSigma(r.metrics[c.key].sigma)}` : "")),
      el("td", {}, r.analysed ? String(r.failed_checks) : ""));
    tr.onclick = () => openItem(r.path);
    return tr;
  }));
  const pending = s.rows.filter((r) => r.kind === "capture" && !r.analysed).length;
  $("analyse-all").disabled = !pending;
  $("analyse-all").textContent = pending ? `Analyse all (${pending})` : "All analysed";
  $("analyse-all").onclick = async () => {
    $("progress").hidden = false;
    try {
      const job = await api("/api/pitch/session/analyse", { method: "POST", json: { path: "" } });
      const res = await followJob(job, progressInto($("progress"), $("progress-text")), $("cancel-job"));
      if (res.failed.length) status(res.failed.map((f) => `${f.path}: ${f.error}`).join(" · "), true);
      await loadItems();
      await showSession();
    } catch (e) { status(e.message, true); } finally { $("progress").hidden = true; }
  };
  if (!session3d) {
    session3d = createView($("session3d"));
    window.stillcapSession = { view: session3d, objectsOfKind: (k) => objectsOfKind(session3d, k), frameStatistics: () => frameStatistics(session3d) };
  }
  session3d.clear();
  const group = new session3d.THREE.Group();
  analysed.forEach((r, i) => {
    if (!r.trajectory) return;
    const line = polyline(r.trajectory.positions, SESSION_COLOURS[i % SESSION_COLOURS.length]);
    line.userData = { kind: "trajectory", path: r.path };
    group.add(line);
  });
  session3d.content.add(group);
  session3d.content.add(ground(0, 9, 22, 1));
  session3d.frame([0.15, -1, 0.2], group.children.length ? group : session3d.content);
  drawPlate($("session-plate"), $("session-movement"), analysed.map((r, i) => ({ plate: r.plate, colour: SESSION_COLOURS[i % SESSION_COLOURS.length] })));
}

// ---------------------------------------------------------------------------------------------
async function main() {
  setupZoom();
  $("show-session").onclick = () => showSession().catch((e) => status(e.message, true));
  window.stillcapPitchPage = { openItem, showSession, zoomTo, state };
  try {
    const items = await loadItems();
    const q = new URLSearchParams(location.search);
    if (q.get("session")) await showSession();
    else if (q.get("item") !== null) await openItem(q.get("item"));
    else if (items.length === 1) await openItem(items[0].path);
    else if (items.length > 1) await showSession();
  } catch (e) {
    status(e.message, true);
  }
  document.body.dataset.ready = "1";
}
main();
