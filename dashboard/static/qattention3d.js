// "What Q-attention attends to": the latest snapshot as one three.js view per depth (the paper's Figure 2).
// Each view: the coloured occupied voxels the network saw, its top-Q voxels coloured by Q, the chosen
// voxel (magenta outline), the grid's bounds (grey), the next depth's zoomed-in cube (orange, in the
// coarser view) and the chosen gripper pose as an x/y/z axis triad. Rendered on demand (drag to orbit).
import * as THREE from "three";
import { OrbitControls } from "three/addons/OrbitControls.js";
import { esc, num } from "./format.js";

const Q_STOPS = ["#313695", "#4575b4", "#74add1", "#fee090", "#f46d43", "#a50026"];  // low -> high Q
const HEIGHT = 340;

function qColour(t) {
  const x = Math.min(1, Math.max(0, t)) * (Q_STOPS.length - 1), i = Math.min(Q_STOPS.length - 2, Math.floor(x));
  return new THREE.Color(Q_STOPS[i]).lerp(new THREE.Color(Q_STOPS[i + 1]), x - i);
}

const v3 = (a, i = 0) => new THREE.Vector3(a[i], a[i + 1], a[i + 2]);

function boxLines(bounds, colour) {
  const lo = v3(bounds), hi = v3(bounds, 3), size = hi.clone().sub(lo);
  const lines = new THREE.LineSegments(new THREE.EdgesGeometry(new THREE.BoxGeometry(size.x, size.y, size.z)),
    new THREE.LineBasicMaterial({ color: colour }));
  lines.position.copy(lo.add(hi).multiplyScalar(0.5));
  return lines;
}

function instanced(geometry, material, positions, colourAt) {
  const n = positions.length / 3, mesh = new THREE.InstancedMesh(geometry, material, Math.max(1, n));
  const m = new THREE.Matrix4();
  mesh.count = n;
  for (let i = 0; i < n; i++) {
    mesh.setMatrixAt(i, m.makeTranslation(positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]));
    mesh.setColorAt(i, colourAt(i));
  }
  mesh.instanceMatrix.needsUpdate = true;
  if (mesh.instanceColor) mesh.instanceColor.needsUpdate = true;
  return mesh;
}

/** The three.js scene of one depth of a snapshot. */
function depthScene(snap, d) {
  const depth = snap.depths[d], e = depth.voxel_edge, scene = new THREE.Scene();
  scene.background = new THREE.Color("#f8fafc");
  scene.add(new THREE.HemisphereLight(0xffffff, 0x667788, 2.2));
  const sun = new THREE.DirectionalLight(0xffffff, 1.2);
  sun.position.set(2, 1, 3);
  scene.add(sun);
  const rgb = depth.occupied.rgb, colour = new THREE.Color();
  scene.add(instanced(new THREE.BoxGeometry(e[0] * 0.92, e[1] * 0.92, e[2] * 0.92), new THREE.MeshLambertMaterial(),
    depth.occupied.centres, i => colour.setRGB(rgb[3 * i] / 255, rgb[3 * i + 1] / 255, rgb[3 * i + 2] / 255, THREE.SRGBColorSpace)));
  const q = depth.top.q, lo = Math.min(...q), hi = Math.max(...q);
  scene.add(instanced(new THREE.BoxGeometry(e[0] * 1.08, e[1] * 1.08, e[2] * 1.08),
    new THREE.MeshBasicMaterial({ transparent: true, opacity: 0.55, depthWrite: false }),
    depth.top.centres, i => qColour(hi > lo ? (q[i] - lo) / (hi - lo) : 1)));
  const chosen = new THREE.LineSegments(new THREE.EdgesGeometry(new THREE.BoxGeometry(e[0] * 1.4, e[1] * 1.4, e[2] * 1.4)),
    new THREE.LineBasicMaterial({ color: 0xd946ef }));
  chosen.position.copy(v3(depth.chosen.centre));
  scene.add(chosen);
  scene.add(boxLines(depth.bounds, 0x94a3b8));
  if (d + 1 < snap.depths.length) scene.add(boxLines(snap.depths[d + 1].bounds, 0xf97316));
  const size = depth.bounds[3] - depth.bounds[0];
  const triad = new THREE.AxesHelper(size * 0.25);
  triad.position.copy(v3(snap.action));
  triad.quaternion.set(snap.action[3], snap.action[4], snap.action[5], snap.action[6]).normalize();
  scene.add(triad);
  return { scene, lo, hi };
}

export class AttentionView {
  constructor(root) {
    this.root = root;
    this.views = [];  // {renderer, camera, controls, canvas}, reused across snapshots
    this.stats = { rendered: false, views: [] };
    window.c2farm.qattention = this.stats;
  }

  static webglAvailable() {
    try {
      const c = document.createElement("canvas");
      return Boolean(c.getContext("webgl2") || c.getContext("webgl"));
    } catch (_) {
      return false;
    }
  }

  update(snap) {
    if (!snap.available) {
      this.root.innerHTML = `<p class="muted">${esc(snap.reason || "no snapshot yet")}</p>`;
      this.views = [];
      return;
    }
    if (!AttentionView.webglAvailable()) {
      this.root.innerHTML = `<p class="muted">This browser has no WebGL: the 3D view cannot be drawn.</p>`;
      return;
    }
    if (this.views.length !== snap.depths.length) this.layout(snap.depths.length);
    this.stats.views = [];
    const m = snap.meta || {};
    this.root.querySelector(".q-meta").textContent = `weights v${num(m.weights_version)}, ${m.task || ""} seed ${m.seed ?? ""}, ` +
      `first decision of the first evaluation episode${m.end ? ` (it ended: ${m.end})` : ""}`;
    snap.depths.forEach((depth, d) => {
      const view = this.views[d], { scene, lo, hi } = depthScene(snap, d);
      view.scene?.traverse(o => { o.geometry?.dispose(); o.material?.dispose(); });  // the previous snapshot's
      view.scene = scene;
      const b = depth.bounds, centre = new THREE.Vector3((b[0] + b[3]) / 2, (b[1] + b[4]) / 2, (b[2] + b[5]) / 2);
      const size = Math.max(b[3] - b[0], b[4] - b[1], b[5] - b[2]);
      if (!view.placed) {  // keep the user's orbit across refreshes of the same depth
        view.camera.position.copy(centre).add(new THREE.Vector3(1.7, 0.9, 1.1).multiplyScalar(size));
        view.camera.near = size / 100;
        view.camera.far = size * 20;
        view.camera.updateProjectionMatrix();
        view.controls.target.copy(centre);
        view.controls.update();
        view.placed = true;
      }
      this.render(d);
      let meshes = 0;
      scene.traverse(o => { if (o.isMesh || o.isLine) meshes += 1; });
      view.canvas.dataset.meshes = String(meshes);
      view.canvas.dataset.voxels = String(depth.occupied.count);
      this.stats.views.push({ depth: d, meshes, voxels: depth.occupied.count, top: depth.top.q.length });
      view.caption.innerHTML = `<b>depth ${d}</b>: ${num(size)} m cube, ${snap.voxel_size}\u00b3 voxels, ` +
        `${num(depth.occupied.count)} occupied. Chosen voxel Q ${num(depth.chosen.q)}; top ${depth.top.q.length} Q ` +
        `<span class="qbar"></span> ${num(lo)} \u2013 ${num(hi)}`;
    });
    this.stats.rendered = true;
    this.stats.version = m.weights_version;
  }

  layout(n) {
    this.root.innerHTML = `<p class="q-meta muted"></p><div class="q-views"></div>` +
      `<p class="muted legend">Cubes: occupied voxels in their mean colour. Translucent: the top-Q voxels, ` +
      `<span class="qbar"></span> low to high Q. Magenta: the chosen voxel. Orange: the next depth's zoomed-in cube. ` +
      `Axes: the chosen gripper pose (x red, y green, z blue). Drag to orbit, scroll to zoom.</p>`;
    const holder = this.root.querySelector(".q-views");
    this.views.forEach(v => { v.controls.dispose(); v.renderer.dispose(); });
    this.views = [];
    for (let d = 0; d < n; d++) {
      const figure = document.createElement("figure");
      figure.className = "q-view";
      figure.innerHTML = `<canvas id="q-depth-${d}"></canvas><figcaption></figcaption>`;
      holder.appendChild(figure);
      const canvas = figure.querySelector("canvas");
      const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
      renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
      const camera = new THREE.PerspectiveCamera(40, 1, 0.01, 100);
      camera.up.set(0, 0, 1);  // the robot's world is z-up
      const controls = new OrbitControls(camera, canvas);
      const view = { canvas, renderer, camera, controls, caption: figure.querySelector("figcaption"), placed: false };
      controls.addEventListener("change", () => this.render(d));
      this.views.push(view);
    }
    window.addEventListener("resize", () => this.views.forEach((_, d) => this.render(d)));
  }

  render(d) {
    const view = this.views[d];
    if (!view?.scene) return;
    const w = Math.max(200, view.canvas.parentElement.clientWidth);
    view.renderer.setSize(w, HEIGHT, false);
    view.canvas.style.width = "100%";
    view.canvas.style.height = `${HEIGHT}px`;
    view.camera.aspect = w / HEIGHT;
    view.camera.updateProjectionMatrix();
    view.renderer.render(view.scene, view.camera);
  }
}
