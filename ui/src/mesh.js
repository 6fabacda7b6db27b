// A part's uploaded file (GET /v1/objects/{name}/versions/{version}/file) as three.js geometry in metres: the file's
// own coordinates times its unit (the object record's `units`), as graspgen's loader reads it (no recentring), so
// the exported grasp poses sit on it.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { OBJLoader } from 'three/addons/loaders/OBJLoader.js';
import { PLYLoader } from 'three/addons/loaders/PLYLoader.js';
import { STLLoader } from 'three/addons/loaders/STLLoader.js';
import { UNIT_SCALE } from './gripper.js';
import { readNpzAsync } from './npz.js';

/** Triangles of every mesh under `root` (world transforms applied) as one non-indexed geometry. */
function mergedTriangles(root) {
  root.updateMatrixWorld(true);
  const chunks = [];
  root.traverse((o) => {
    if (!o.isMesh || !o.geometry?.attributes?.position) return;
    const g = (o.geometry.index ? o.geometry.toNonIndexed() : o.geometry.clone()).applyMatrix4(o.matrixWorld);
    chunks.push(g.attributes.position.array);
  });
  const total = chunks.reduce((n, a) => n + a.length, 0);
  const positions = new Float32Array(total);
  let at = 0;
  for (const a of chunks) {
    positions.set(a, at);
    at += a.length;
  }
  const out = new THREE.BufferGeometry();
  out.setAttribute('position', new THREE.BufferAttribute(positions, 3));
  return out;
}

/** ASCII OFF (three.js has no OFF loader): vertices, then polygons fanned into triangles. */
export function parseOff(text) {
  const tokens = text
    .split('\n')
    .map((l) => l.replace(/#.*/, '').trim())
    .filter((l) => l)
    .join(' ')
    .split(/\s+/);
  let i = 0;
  const head = tokens[i++];
  if (!/^C?OFF$/.test(head)) throw new Error('not an OFF file');
  const nv = Number(tokens[i++]);
  const nf = Number(tokens[i++]);
  i++; // edges
  const stride = head === 'COFF' ? 7 : 3;
  const verts = [];
  for (let v = 0; v < nv; v++, i += stride) verts.push([Number(tokens[i]), Number(tokens[i + 1]), Number(tokens[i + 2])]);
  const positions = [];
  for (let f = 0; f < nf; f++) {
    const n = Number(tokens[i++]);
    const idx = tokens.slice(i, i + n).map(Number);
    i += n;
    for (let k = 1; k + 1 < n; k++) positions.push(...verts[idx[0]], ...verts[idx[k]], ...verts[idx[k + 1]]);
  }
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.Float32BufferAttribute(positions, 3));
  return g;
}

/**
 * `{geometry, points}`: the part in metres; `points` is true for a point cloud (PLY without faces, NPZ `points`).
 * `format` is the object version's format (stl, obj, ply, off, glb, npz), `units` its unit.
 */
export async function partGeometry(buffer, format, units) {
  const scale = UNIT_SCALE[units];
  if (scale === undefined) throw new Error(`unknown units ${units}`);
  let geometry;
  let points = false;
  switch (format) {
    case 'stl':
      geometry = new STLLoader().parse(buffer);
      break;
    case 'obj':
      geometry = mergedTriangles(new OBJLoader().parse(new TextDecoder().decode(buffer)));
      break;
    case 'ply':
      geometry = new PLYLoader().parse(buffer);
      points = geometry.index === null;
      break;
    case 'off':
      geometry = parseOff(new TextDecoder().decode(buffer));
      break;
    case 'glb': {
      const gltf = await new GLTFLoader().parseAsync(buffer, '');
      geometry = mergedTriangles(gltf.scene);
      break;
    }
    case 'npz': {
      const { points: p } = await readNpzAsync(buffer, ['points']);
      if (!p) throw new Error('the NPZ has no points array');
      geometry = new THREE.BufferGeometry();
      geometry.setAttribute('position', new THREE.BufferAttribute(Float32Array.from(p.data), 3));
      points = true;
      break;
    }
    default:
      throw new Error(`cannot draw a ${format} file`);
  }
  geometry.scale(scale, scale, scale);
  if (!points) {
    geometry.deleteAttribute('normal');
    geometry.computeVertexNormals();
  }
  geometry.computeBoundingSphere();
  geometry.computeBoundingBox();
  return { geometry, points };
}
