// The 3D view of grasp sets: the part, the gripper's real geometry at every exported grasp (instanced, coloured by a
// margin or by set), the selected grasp highlighted with its contacts, normals and its other free rolls as ghosts,
// and the candidate cloud. Rendered on demand (controls, data), not in a loop: an idle page costs nothing.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { gripperParts, poseAtRoll, rollAxis } from './gripper.js';

const BACKGROUND = 0xf3f4f6;
const HIGHLIGHT = 0xff5a1f;

/** A three.js colour from sRGB components in 0..1 (three's working space is linear). */
function srgb([r, g, b]) {
  return new THREE.Color().setRGB(r, g, b, THREE.SRGBColorSpace);
}

function matrix4(T) {
  const m = new THREE.Matrix4();
  m.set(...T[0], ...T[1], ...T[2], ...T[3]);
  return m;
}

function shapeGeometry(part, meshes) {
  if (part.shape === 'box') return new THREE.BoxGeometry(1, 1, 1);
  if (part.shape === 'mesh') {
    const g = meshes?.get(part.path);
    if (!g) throw new Error(`gripper mesh ${part.path} was not loaded`);
    return g;
  }
  // cylinder and frustum: three's axis is +Y with radiusTop at +Y; turned so that it is +Z
  const g = new THREE.CylinderGeometry(part.radiusTop, part.radiusBottom, part.height, 32, 1, false);
  g.rotateX(Math.PI / 2);
  return g;
}

/** The matrix that places a part's shape: T, and the box's size as a scale (a unit box is shared). */
function partMatrix(pose, part) {
  const m = matrix4(pose).multiply(matrix4(part.T));
  if (part.shape === 'box') m.multiply(new THREE.Matrix4().makeScale(...part.size));
  return m;
}

// Lambert shading: enough to read shapes, and its shaders compile in a fraction of the time of physically based
// ones on software GL (a plant PC without a GPU), where compiling dominates the first frame
function partMaterial() {
  return new THREE.MeshLambertMaterial({ color: 0x8b95a5, side: THREE.DoubleSide });
}

/** The grippers' material: white, tinted per instance (InstancedMesh colours), see-through below opacity 1. */
function gripperMaterial(opacity) {
  return new THREE.MeshLambertMaterial({ color: 0xffffff, transparent: opacity < 1, opacity });
}

let software = null;

/**
 * Whether WebGL runs on a software rasteriser (SwiftShader, llvmpipe: a plant PC without a GPU, a headless
 * browser). There multisampling costs more than the whole scene, so the viewer draws without it.
 */
export function softwareRendering() {
  if (software === null) {
    const gl = document.createElement('canvas').getContext('webgl2');
    const info = gl?.getExtension('WEBGL_debug_renderer_info');
    const name = info ? String(gl.getParameter(info.UNMASKED_RENDERER_WEBGL)) : '';
    software = /swiftshader|llvmpipe|softpipe|software/i.test(name);
    gl?.getExtension('WEBGL_lose_context')?.loseContext();
  }
  return software;
}

export class GraspViewer {
  /** `container`: the element the canvas fills; `label`: the canvas' accessible name. */
  constructor(container, { label = '3D view of the grasp set' } = {}) {
    this.container = container;
    // an opaque canvas whose drawing buffer is not preserved: the compositor takes each frame as it is, without a copy
    this.renderer = new THREE.WebGLRenderer({ antialias: !softwareRendering(), preserveDrawingBuffer: false, alpha: false });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    this.renderer.setClearColor(BACKGROUND);
    const canvas = this.renderer.domElement;
    canvas.setAttribute('role', 'img');
    canvas.setAttribute('aria-label', label);
    canvas.tabIndex = 0;
    container.append(canvas);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.0005, 50);
    this.camera.up.set(0, 0, 1); // the object's +Z up, as robot cells are drawn
    this.camera.position.set(0.2, -0.25, 0.18);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.addEventListener('change', () => this.requestRender());
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8090a0, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(1, -1.5, 2);
    this.camera.add(sun);
    this.scene.add(this.camera);
    this.axes = new THREE.AxesHelper(0.02);
    this.scene.add(this.axes);
    // one material for every candidate cloud, and a one-point cloud drawn from the first frame on: when the candidates
    // come after the first frame (they are in it when they arrive in time), their shader program is ready
    this.pointsMaterial = new THREE.PointsMaterial({ size: 3, sizeAttenuation: false, vertexColors: true, depthWrite: false });
    const seed = new THREE.BufferGeometry();
    seed.setAttribute('position', new THREE.Float32BufferAttribute([0, 0, 0], 3));
    seed.setAttribute('color', new THREE.Float32BufferAttribute([0.95, 0.96, 0.96], 3));
    this.scene.add(new THREE.Points(seed, this.pointsMaterial));
    this.layers = new Map();
    this.part = null;
    this.selection = new THREE.Group();
    this.scene.add(this.selection);
    this.selected = null;
    this.selectListeners = new Set();
    this.afterRender = [];
    this.pending = false;
    this.resizeObserver = new ResizeObserver(() => this.resize());
    this.resizeObserver.observe(container);
    canvas.addEventListener('pointerdown', (e) => {
      this.down = [e.clientX, e.clientY];
    });
    canvas.addEventListener('pointerup', (e) => {
      if (this.down && Math.hypot(e.clientX - this.down[0], e.clientY - this.down[1]) < 4) this.pick(e);
    });
    this.resize();
  }

  resize() {
    const w = Math.max(1, this.container.clientWidth);
    const h = Math.max(1, this.container.clientHeight);
    this.renderer.setSize(w, h, true);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.requestRender();
  }

  requestRender() {
    // nothing drawn yet and nobody waiting for a frame: an empty frame would only hold up the thread (on software GL
    // a frame costs 50-150 ms) while the set's requests are answered
    if (this.pending || (!this.part && !this.layers.size && !this.afterRender.length)) return;
    this.pending = true;
    requestAnimationFrame(() => {
      this.pending = false;
      this.renderNow();
    });
  }

  renderNow() {
    this.renderer.render(this.scene, this.camera);
    const done = this.afterRender.splice(0);
    if (done.length) {
      // GL calls return before the GPU (or SwiftShader) has drawn; reading a pixel waits until it has, so whoever
      // awaits rendered() (the performance marks) sees the frame on screen, not merely submitted
      const gl = this.renderer.getContext();
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(4));
    }
    for (const f of done) f();
  }

  /** Resolves once the next frame with everything added so far has been drawn. */
  rendered() {
    return new Promise((resolve) => {
      this.afterRender.push(resolve);
      this.requestRender();
    });
  }

  setPart(geometry, points = false) {
    if (this.part) this.scene.remove(this.part);
    this.part = points
      ? new THREE.Points(geometry, new THREE.PointsMaterial({ color: 0x6b7280, size: 2, sizeAttenuation: false }))
      : new THREE.Mesh(geometry, partMaterial());
    this.part.name = 'part';
    this.scene.add(this.part);
    const r = geometry.boundingSphere?.radius ?? 0.05;
    this.axes.scale.setScalar(Math.max(r * 0.6, 0.005) / 0.02);
    this.requestRender();
  }

  /**
   * Draw a set's grasps as layer `id`: `exportJson` (grasp_set/1), `colours` one [r, g, b] per grasp, `meshes` the
   * gripper's mesh geometries by path (specs with `geometry`). Replaces a layer of the same id.
   */
  setGrasps(id, exportJson, colours, { meshes = null, opacity = 0.92 } = {}) {
    this.removeLayer(id);
    const spec = exportJson.gripper;
    const grasps = exportJson.grasps ?? [];
    const group = new THREE.Group();
    group.name = `grasps-${id}`;
    const layer = { id, group, spec, grasps, meshes, instanced: [], hidden: new Set(), colours };
    if (grasps.length) {
      const partsOf = grasps.map((g) => gripperParts(spec, g.width));
      partsOf[0].forEach((first, k) => {
        const geometry = shapeGeometry(first, meshes);
        const material = gripperMaterial(opacity);
        const mesh = new THREE.InstancedMesh(geometry, material, grasps.length);
        mesh.name = `${id}-${first.role}`;
        grasps.forEach((g, i) => {
          mesh.setMatrixAt(i, partMatrix(g.pose, partsOf[i][k]));
          mesh.setColorAt(i, srgb(colours[i]));
        });
        mesh.instanceMatrix.needsUpdate = true;
        mesh.instanceColor.needsUpdate = true;
        mesh.computeBoundingSphere();
        mesh.userData = { layer: id, parts: partsOf.map((p) => p[k]) };
        group.add(mesh);
        layer.instanced.push(mesh);
      });
    }
    this.layers.set(id, layer);
    this.scene.add(group);
    this.requestRender();
    return layer;
  }

  recolour(id, colours) {
    const layer = this.layers.get(id);
    if (!layer) return;
    layer.colours = colours;
    for (const mesh of layer.instanced) {
      colours.forEach((c, i) => mesh.setColorAt(i, srgb(c)));
      mesh.instanceColor.needsUpdate = true;
    }
    this.requestRender();
  }

  removeLayer(id) {
    const layer = this.layers.get(id);
    if (!layer) return;
    this.scene.remove(layer.group);
    if (layer.candidates) this.scene.remove(layer.candidates);
    for (const m of layer.instanced) m.dispose();
    this.layers.delete(id);
  }

  setLayerVisible(id, visible) {
    const layer = this.layers.get(id);
    if (layer) layer.group.visible = visible;
    this.requestRender();
  }

  /**
   * The candidate cloud of a layer: `positions` (n*3, metres; e.g. the NPZ's midpoints), `colours` (n*3, linear light:
   * colour.js linearRampColours). Drawn as points, at most `limit` of them (an even stride through the array when there
   * are more). Returns how many are drawn.
   */
  setCandidates(id, positions, colours, limit = 60000) {
    const layer = this.layers.get(id);
    if (!layer) return 0;
    if (layer.candidates) {
      this.scene.remove(layer.candidates);
      layer.candidates.geometry.dispose();
    }
    const n = positions.length / 3;
    const stride = Math.max(1, Math.ceil(n / limit));
    const m = Math.ceil(n / stride);
    const p = new Float32Array(m * 3);
    const c = stride === 1 && colours instanceof Float32Array ? colours : new Float32Array(m * 3);
    for (let i = 0, j = 0; i < n; i += stride, j++) {
      p[j * 3] = positions[i * 3];
      p[j * 3 + 1] = positions[i * 3 + 1];
      p[j * 3 + 2] = positions[i * 3 + 2];
      if (c !== colours) {
        c[j * 3] = colours[i * 3];
        c[j * 3 + 1] = colours[i * 3 + 1];
        c[j * 3 + 2] = colours[i * 3 + 2];
      }
    }
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(p, 3));
    geometry.setAttribute('color', new THREE.BufferAttribute(c, 3));
    const points = new THREE.Points(geometry, this.pointsMaterial);
    points.name = `candidates-${id}`;
    layer.candidates = points;
    this.scene.add(points);
    this.requestRender();
    return m;
  }

  setCandidatesVisible(id, visible) {
    const layer = this.layers.get(id);
    if (layer?.candidates) layer.candidates.visible = visible;
    this.requestRender();
  }

  /** Look at everything shown (part, visible grippers, the selected grasp) from the current direction. */
  fit() {
    const box = new THREE.Box3();
    if (this.part) box.expandByObject(this.part);
    for (const layer of this.layers.values()) if (layer.group.visible) box.expandByObject(layer.group);
    if (this.selection.children.length) box.expandByObject(this.selection);
    if (box.isEmpty()) return;
    const sphere = box.getBoundingSphere(new THREE.Sphere());
    const dir = this.camera.position.clone().sub(this.controls.target).normalize();
    const dist = sphere.radius / Math.sin((this.camera.fov * Math.PI) / 360);
    this.controls.target.copy(sphere.center);
    this.camera.position.copy(sphere.center).addScaledVector(dir, dist * 1.05);
    this.camera.near = dist / 100;
    this.camera.far = dist * 10;
    this.camera.updateProjectionMatrix();
    this.controls.update();
    this.requestRender();
  }

  onSelect(f) {
    this.selectListeners.add(f);
  }

  pick(event) {
    const rect = this.renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(
      ((event.clientX - rect.left) / rect.width) * 2 - 1,
      -((event.clientY - rect.top) / rect.height) * 2 + 1,
    );
    const ray = new THREE.Raycaster();
    ray.setFromCamera(ndc, this.camera);
    const targets = [...this.layers.values()].filter((l) => l.group.visible).flatMap((l) => l.instanced);
    // the part is a target too: a gripper behind it is not picked through it
    const hit = ray.intersectObjects(this.part ? [this.part, ...targets] : targets, false)[0];
    if (hit && hit.instanceId !== undefined && hit.object !== this.part) {
      this.select(hit.object.userData.layer, hit.instanceId);
    }
  }

  /** Highlight grasp `index` of layer `id` with its contacts, normals and free rolls (ghosts); null clears. */
  select(id, index) {
    this.selection.clear();
    for (const layer of this.layers.values()) {
      for (const i of layer.hidden) this.showInstance(layer, i, true);
      layer.hidden.clear();
    }
    this.selected = id === null || index === null ? null : { id, index };
    const layer = this.layers.get(id);
    const grasp = layer?.grasps[index];
    if (grasp) {
      this.showInstance(layer, index, false);
      layer.hidden.add(index);
      const parts = gripperParts(layer.spec, grasp.width);
      const solid = new THREE.MeshLambertMaterial({ color: HIGHLIGHT, emissive: 0x662200 });
      const ghost = new THREE.MeshBasicMaterial({ color: 0x2563eb, transparent: true, opacity: 0.16, depthWrite: false });
      const rolls = (grasp.free_rolls_deg ?? []).filter((r) => Math.abs(r - (grasp.roll_deg ?? NaN)) > 1e-9);
      const axis = rollAxis(layer.spec);
      for (const part of parts) {
        const geometry = shapeGeometry(part, layer.meshes);
        const m = new THREE.Mesh(geometry, solid);
        m.applyMatrix4(partMatrix(grasp.pose, part));
        m.name = 'selected';
        this.selection.add(m);
        if (grasp.roll_deg === undefined) continue; // without the drawn roll the others cannot be placed
        for (const psi of rolls) {
          const g = new THREE.Mesh(geometry, ghost);
          g.applyMatrix4(partMatrix(poseAtRoll(grasp.pose, grasp.roll_deg, psi, axis), part));
          g.name = 'ghost';
          this.selection.add(g);
        }
      }
      const size = Math.max(this.part?.geometry.boundingSphere?.radius ?? 0.02, 0.005);
      (grasp.contacts ?? []).forEach((c, k) => {
        const ball = new THREE.Mesh(
          new THREE.SphereGeometry(size * 0.035, 16, 12),
          new THREE.MeshBasicMaterial({ color: k === 0 ? 0xdc2626 : 0x16a34a }),
        );
        ball.position.set(...c);
        this.selection.add(ball);
        const n = grasp.normals?.[k];
        if (n) {
          this.selection.add(
            new THREE.ArrowHelper(new THREE.Vector3(...n).normalize(), ball.position, size * 0.35, 0x111827),
          );
        }
      });
    }
    for (const f of this.selectListeners) f(this.selected);
    this.requestRender();
  }

  showInstance(layer, i, visible) {
    for (const mesh of layer.instanced) {
      const m = visible
        ? partMatrix(layer.grasps[i].pose, mesh.userData.parts[i])
        : new THREE.Matrix4().makeScale(0, 0, 0);
      mesh.setMatrixAt(i, m);
      mesh.instanceMatrix.needsUpdate = true;
    }
  }

  dispose() {
    this.resizeObserver.disconnect();
    this.controls.dispose();
    this.renderer.dispose();
    this.renderer.domElement.remove();
  }
}
