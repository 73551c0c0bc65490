// The 3D views of the pitch and hand pages: a three.js scene in the capture's world frame (z up),
// orbit controls, and the pieces both pages draw (camera frusta, points, lines, ellipsoids).
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

/** A scene drawn into `canvas`, re-rendered on demand (controls, resize, or view.render()).
 *  preserveDrawingBuffer keeps the last frame readable (tests read its pixels back). */
export function createView(canvas) {
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setClearColor(0xf4f5f7, 1);
  const scene = new THREE.Scene();
  const camera = new THREE.PerspectiveCamera(40, 1, 0.01, 500);
  camera.up.set(0, 0, 1);
  camera.position.set(5, -5, 5);
  scene.add(new THREE.AmbientLight(0xffffff, 1.6));
  const sun = new THREE.DirectionalLight(0xffffff, 1.8);
  sun.position.set(3, -4, 10);
  scene.add(sun);
  const content = new THREE.Group();
  scene.add(content);
  const controls = new OrbitControls(camera, canvas);
  const view = { THREE, renderer, scene, camera, controls, content, canvas };
  view.render = () => {
    const w = canvas.clientWidth || 300, h = canvas.clientHeight || 200;
    if (canvas.width !== Math.round(w * renderer.getPixelRatio()) || canvas.height !== Math.round(h * renderer.getPixelRatio())) {
      renderer.setSize(w, h, false);
      camera.aspect = w / h;
      camera.updateProjectionMatrix();
    }
    renderer.render(scene, camera);
  };
  controls.addEventListener("change", view.render);
  new ResizeObserver(view.render).observe(canvas);
  view.clear = () => {
    for (const child of [...content.children]) {
      content.remove(child);
      child.traverse?.((o) => { o.geometry?.dispose?.(); o.material?.dispose?.(); });
    }
  };
  /** Point the camera at the box of what is drawn, from `direction` (world), and render. */
  view.frame = (direction = [1, -1.2, 0.8], objects = content) => {
    const box = new THREE.Box3().setFromObject(objects);
    if (box.isEmpty()) { view.render(); return; }
    const center = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3()).length() || 1;
    const dir = new THREE.Vector3(...direction).normalize();
    // far enough for the box's bounding sphere to fit the narrower of the two fields of view
    const vfov = THREE.MathUtils.degToRad(camera.fov);
    const hfov = 2 * Math.atan(Math.tan(vfov / 2) * camera.aspect);
    const distance = (size / 2) / Math.sin(Math.min(vfov, hfov) / 2);
    camera.position.copy(center).addScaledVector(dir, distance * 1.05);
    camera.near = size / 1000;
    camera.far = size * 20;
    camera.updateProjectionMatrix();
    controls.target.copy(center);
    controls.update();
    view.render();
  };
  return view;
}

/** Line segments through `points` ([[x, y, z], ...]) in one colour. */
export function polyline(points, color, { dashed = false } = {}) {
  const geom = new THREE.BufferGeometry().setFromPoints(points.map((p) => new THREE.Vector3(...p)));
  const mat = dashed ? new THREE.LineDashedMaterial({ color, dashSize: 0.1, gapSize: 0.06 })
                     : new THREE.LineBasicMaterial({ color });
  const line = new THREE.Line(geom, mat);
  if (dashed) line.computeLineDistances();
  return line;
}

/** A camera's frustum: lines from its centre to the four image corners and around them, and its name. */
export function frustum(cam, color = 0x555555) {
  const g = new THREE.Group();
  const c = cam.center, k = cam.corners;
  const segs = [];
  for (let i = 0; i < 4; i++) segs.push(c, k[i], k[i], k[(i + 1) % 4]);
  const geom = new THREE.BufferGeometry().setFromPoints(segs.map((p) => new THREE.Vector3(...p)));
  g.add(new THREE.LineSegments(geom, new THREE.LineBasicMaterial({ color })));
  // the image's top edge marked, so that up and down can be told apart
  g.add(polyline([k[0], [(k[0][0] + k[1][0]) / 2 + (k[0][0] - k[3][0]) * 0.2, (k[0][1] + k[1][1]) / 2 + (k[0][1] - k[3][1]) * 0.2,
                        (k[0][2] + k[1][2]) / 2 + (k[0][2] - k[3][2]) * 0.2], k[1]], color));
  g.userData = { kind: "camera", name: cam.name };
  return g;
}

/** A sphere of radius `r` at `p`. */
export function sphere(p, r, color, userData = {}) {
  const m = new THREE.Mesh(new THREE.SphereGeometry(r, 16, 12), new THREE.MeshStandardMaterial({ color, roughness: 0.6 }));
  m.position.set(...p);
  m.userData = userData;
  return m;
}

/** An error ellipsoid at `p` with semi-axes `axes` (three vectors, m), magnified by `scale`. */
export function ellipsoid(p, axes, scale, color) {
  const m = new THREE.Mesh(new THREE.SphereGeometry(1, 20, 14),
    new THREE.MeshStandardMaterial({ color, transparent: true, opacity: 0.35, depthWrite: false }));
  const [a, b, c] = axes.map((v) => new THREE.Vector3(...v).multiplyScalar(scale));
  const basis = new THREE.Matrix4().makeBasis(a, b, c);
  basis.setPosition(new THREE.Vector3(...p));
  m.matrixAutoUpdate = false;
  m.matrix.copy(basis);
  m.userData = { kind: "ellipsoid" };
  return m;
}

/** A grid on the ground plane (z = 0) around (cx, cy). */
export function ground(cx, cy, size, step) {
  const grid = new THREE.GridHelper(size, Math.max(1, Math.round(size / step)), 0xbbbbbb, 0xdddddd);
  grid.rotation.x = Math.PI / 2;
  grid.position.set(cx, cy, 0);
  grid.userData = { kind: "ground" };
  return grid;
}

/** Objects of `view.content` with userData.kind === kind. */
export function objectsOfKind(view, kind) {
  const out = [];
  view.content.traverse((o) => { if (o.userData?.kind === kind) out.push(o); });
  return out;
}

/** Mean and variance of the canvas's last frame (a blank view has variance 0). */
export function frameStatistics(view) {
  const gl = view.renderer.getContext();
  const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
  const px = new Uint8Array(w * h * 4);
  gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
  let s = 0, s2 = 0, n = 0;
  const colours = new Set();
  for (let i = 0; i < px.length; i += 4) {
    const v = 0.299 * px[i] + 0.587 * px[i + 1] + 0.114 * px[i + 2];
    s += v; s2 += v * v; n++;
    if (i % 64 === 0) colours.add((px[i] << 16) | (px[i + 1] << 8) | px[i + 2]);
  }
  const mean = s / n;
  return { width: w, height: h, mean, variance: s2 / n - mean * mean, colours: colours.size };
}
