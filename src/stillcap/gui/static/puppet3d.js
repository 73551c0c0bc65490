// The puppet's 3D view (three.js): markers, skeleton, cameras and turntable; orbit, zoom, pick.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

export function createScene(container, onPick) {
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });  // readable pixels
  renderer.setPixelRatio(window.devicePixelRatio);
  container.append(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0x20242a);
  const camera = new THREE.PerspectiveCamera(40, 1, 0.005, 20);
  camera.position.set(0.45, 0.35, 0.45);
  const controls = new OrbitControls(camera, renderer.domElement);
  controls.target.set(0, 0.08, 0);
  controls.enableDamping = false;
  scene.add(new THREE.HemisphereLight(0xffffff, 0x404040, 2.5));
  const grid = new THREE.GridHelper(0.6, 12, 0x666666, 0x3a3f46);
  scene.add(grid);
  const content = new THREE.Group();
  scene.add(content);
  const pickables = [];

  function resize() {
    const w = container.clientWidth || 400, h = container.clientHeight || 300;
    renderer.setSize(w, h);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
  }
  new ResizeObserver(() => { resize(); render(); }).observe(container);
  function render() { renderer.render(scene, camera); }
  controls.addEventListener("change", render);

  const raycaster = new THREE.Raycaster();
  let down = null;
  renderer.domElement.addEventListener("pointerdown", (e) => { down = [e.clientX, e.clientY]; });
  renderer.domElement.addEventListener("pointerup", (e) => {
    if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 4) return;  // a drag orbits, a click picks
    const r = renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(((e.clientX - r.left) / r.width) * 2 - 1, -((e.clientY - r.top) / r.height) * 2 + 1);
    raycaster.setFromCamera(ndc, camera);
    const hit = raycaster.intersectObjects(pickables, false)[0];
    for (const o of pickables) o.material.emissive?.setHex(0x000000);
    if (hit) hit.object.material.emissive?.setHex(0x555555);
    render();
    onPick(hit ? hit.object.userData : null);
  });

  function clear() {
    for (const o of [...content.children]) {
      content.remove(o);
      o.traverse((x) => { x.geometry?.dispose(); x.material?.dispose?.(); });
    }
    pickables.length = 0;
  }

  function show(result) {
    clear();
    const v = (p) => new THREE.Vector3(p[0], p[1], p[2]);
    for (const m of result.markers) {  // markers: spheres in their colour; flagged ones with a red ring
      if (!m.position) continue;
      const mesh = new THREE.Mesh(new THREE.SphereGeometry(0.006, 16, 12),
        new THREE.MeshStandardMaterial({ color: m.color, roughness: 0.6 }));
      mesh.position.copy(v(m.position));
      mesh.userData = { kind: "marker", ...m };
      content.add(mesh);
      pickables.push(mesh);
      if (m.weak) {
        const ring = new THREE.Mesh(new THREE.TorusGeometry(0.011, 0.0015, 8, 24), new THREE.MeshBasicMaterial({ color: 0xff3b30 }));
        ring.position.copy(mesh.position);
        content.add(ring);
      }
    }
    const bones = [];  // skeleton: a line per bone, a small sphere per joint
    for (const j of result.joints) {
      if (j.parent >= 0) bones.push(v(result.joints[j.parent].position), v(j.position));
      const s = new THREE.Mesh(new THREE.SphereGeometry(0.004, 10, 8), new THREE.MeshStandardMaterial({ color: 0xf0f0f0 }));
      s.position.copy(v(j.position));
      s.userData = { kind: "joint", ...j };
      content.add(s);
      pickables.push(s);
    }
    content.add(new THREE.LineSegments(new THREE.BufferGeometry().setFromPoints(bones),
      new THREE.LineBasicMaterial({ color: 0xffffff })));
    for (const c of result.cameras) {  // cameras: small frustums looking along their +z
      const R = c.rotation, C = v(c.center), d = 0.04;
      const th = Math.tan((c.fov_y_deg * Math.PI) / 360) * d, tw = th * c.aspect;
      const toWorld = (x, y, z) => new THREE.Vector3(  // camera frame -> world: R^T (x, y, z) + C
        R[0][0] * x + R[1][0] * y + R[2][0] * z, R[0][1] * x + R[1][1] * y + R[2][1] * z,
        R[0][2] * x + R[1][2] * y + R[2][2] * z).add(C);
      const corners = [[-tw, -th], [tw, -th], [tw, th], [-tw, th]].map(([x, y]) => toWorld(x, y, d));
      const pts = [];
      for (let i = 0; i < 4; i++) pts.push(C, corners[i], corners[i], corners[(i + 1) % 4]);
      content.add(new THREE.LineSegments(new THREE.BufferGeometry().setFromPoints(pts),
        new THREE.LineBasicMaterial({ color: 0x4fa3ff })));
      const dot = new THREE.Mesh(new THREE.SphereGeometry(0.006, 8, 6), new THREE.MeshBasicMaterial({ color: 0x4fa3ff }));
      dot.position.copy(C);
      dot.userData = { kind: "camera", name: c.name };
      content.add(dot);
      pickables.push(dot);
    }
    if (result.turntable) {  // the turntable: a disc on the platform (y = 0)
      const disc = new THREE.Mesh(new THREE.CircleGeometry(result.turntable.radius_m, 48),
        new THREE.MeshStandardMaterial({ color: 0x8a6d4b, side: THREE.DoubleSide, transparent: true, opacity: 0.5 }));
      disc.rotation.x = -Math.PI / 2;
      content.add(disc);
    }
    const box = new THREE.Box3().setFromPoints(result.markers.filter((m) => m.position).map((m) => v(m.position)));
    if (!box.isEmpty()) controls.target.copy(box.getCenter(new THREE.Vector3()));
    controls.update();
    resize();
    render();
  }

  resize();
  render();
  return { show, render, renderer, camera, controls, scene };
}
