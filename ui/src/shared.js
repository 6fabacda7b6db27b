// What several pages share: loading a grasp set with everything needed to draw it, the release / withdraw dialog,
// status messages.
import * as THREE from 'three';
import { STLLoader } from 'three/addons/loaders/STLLoader.js';
import { explain, getBytes, getJson, getWithHeaders, postJson, q, seg } from './api.js';
import { MEASURES, normalise, ramp, range } from './colour.js';
import { badge, clear, h } from './dom.js';
import { meshPaths } from './gripper.js';
import { partGeometry } from './mesh.js';
import { readNpzAsync } from './npz.js';

/** The summary (GET /v1/grasp-sets list item) of set `id` of the pair, or null. */
export async function setSummary(id, object, gripper) {
  let cursor = null;
  for (let page = 0; page < 200; page++) {
    const body = await getJson(`/v1/grasp-sets${q({ object, gripper, cursor, limit: 200 })}`);
    const hit = body.items.find((s) => s.id === id);
    if (hit) return hit;
    if (!body.next_cursor || body.items.at(-1).id < id) return null;
    cursor = body.next_cursor;
  }
  return null;
}

/** What the catalogue serves for a pair: {id, released, stale} from the headers, or null (404: nothing). */
export async function servedBy(object, gripper) {
  try {
    const { headers } = await getWithHeaders(`/v1/catalogue/${seg(object)}/${seg(gripper)}`, 'HEAD');
    return {
      id: Number(headers.get('Graspgen-Set-Id')),
      released: headers.get('Graspgen-Released') === 'true',
      stale: headers.get('Graspgen-Stale') === 'true',
    };
  } catch (err) {
    if (err.status === 404) return null;
    throw err;
  }
}

const meshCache = new Map();

/** The gripper's mesh files (specs with `geometry`) as geometries in their file units, by path. */
export async function gripperMeshes(spec, gripperVersion) {
  const paths = meshPaths(spec);
  if (!paths.length) return null;
  const out = new Map();
  await Promise.all(
    paths.map(async (path) => {
      const url = `/v1/grippers/${seg(spec.name)}/versions/${gripperVersion}/files/${path.split('/').map(seg).join('/')}`;
      if (!meshCache.has(url)) {
        const format = path.split('.').pop().toLowerCase();
        const bytes = await getBytes(url);
        // the files' own units: the part's transform T of gripper.js carries the unit scale
        const { geometry } =
          format === 'stl'
            ? { geometry: new STLLoader().parse(bytes) }
            : await partGeometry(bytes, format, 'm');
        geometry.computeVertexNormals();
        meshCache.set(url, geometry);
      }
      out.set(path, meshCache.get(url));
    }),
  );
  return out;
}

/** The part of an export's object version: {record, geometry, points}. */
export async function loadPart(exportJson) {
  const { name, version } = exportJson.object;
  const record = await getJson(`/v1/objects/${seg(name)}/versions/${version}`);
  const bytes = await getBytes(record.links.file);
  const { geometry, points } = await partGeometry(bytes, record.format, record.units);
  return { record, geometry, points };
}

/** Everything drawing set `id` needs, loaded in parallel where it can be. */
export async function loadSet(id, afterExport = null) {
  const exportJson = await getJson(`/v1/grasp-sets/${id}`);
  performance.mark(`gg:set:${id}:export`);
  afterExport?.();
  const summaryP = setSummary(id, exportJson.object.name, exportJson.gripper.name);
  const [part, summary] = await Promise.all([loadPart(exportJson), summaryP]);
  const meshes = summary ? await gripperMeshes(exportJson.gripper, summary.gripper_version) : null;
  return { id, exportJson, summary, part, meshes };
}

/** One colour per grasp by `measure` (a key of MEASURES) and the value range used. */
export function graspColours(grasps, measure) {
  const of = MEASURES[measure]?.of ?? MEASURES.friction_margin_deg.of;
  const values = grasps.map(of);
  const r = range(values);
  return { colours: values.map((v) => (v === null ? [0.6, 0.6, 0.6] : ramp(normalise(v, r)))), range: r };
}

/** The candidate NPZ's bytes (started early: the download overlaps drawing the part and the grippers). */
export function downloadCandidates(id) {
  const p = getBytes(`/v1/grasp-sets/${id}/candidates`);
  p.catch(() => {}); // handled where it is awaited
  return p;
}

/** The candidate NPZ's midpoints and per-candidate values, coloured like the grasps (sRGB bytes). */
export async function loadCandidates(id, measure, graspRange, download = null) {
  const bytes = await (download ?? downloadCandidates(id));
  performance.mark('gg:candidates:fetched');
  const arrays = await readNpzAsync(bytes, ['midpoints', 'friction_margin_deg', 'hold_margin']);
  performance.mark('gg:candidates:inflated');
  const mid = arrays.midpoints;
  if (!mid) throw new Error('the candidate NPZ has no midpoints');
  const n = mid.shape[0];
  const values = measure === 'hold_margin' ? arrays.hold_margin?.data : arrays.friction_margin_deg?.data;
  const r = (values && range(values)) || graspRange;
  const colours = new Uint8Array(n * 3);
  for (let i = 0; i < n; i++) {
    const c = values ? ramp(normalise(values[i], r)) : [0.45, 0.45, 0.5];
    colours[i * 3] = c[0] * 255;
    colours[i * 3 + 1] = c[1] * 255;
    colours[i * 3 + 2] = c[2] * 255;
  }
  performance.mark('gg:candidates:coloured');
  return { n, positions: mid.data, colours, range: r, bytes: bytes.byteLength };
}

export function status(el, text, kind = 'info') {
  clear(el, text ? h('p', { class: `status ${kind}`, role: kind === 'error' ? 'alert' : 'status' }, text) : null);
}

/** Badges of a set's state in its pair. */
export function stateBadges(summary, served) {
  const out = [];
  if (summary?.withdrawn_at) out.push(badge('withdrawn', 'withdrawn'));
  if (served && summary && served.id === summary.id) {
    out.push(badge(served.released ? 'released' : 'current (not released)', served.released ? 'released' : 'current'));
    if (served.stale) out.push(badge('stale', 'stale'));
  }
  return out;
}

/**
 * Ask, then release or withdraw `summary`'s set; `done(result)` after a change. The dialog names the set; errors
 * (401, 403 without the write scope, ...) are explained in `statusEl`.
 */
export function confirmChange(action, summary, statusEl, done) {
  const what = `grasp set ${summary.id} (version ${summary.version}) of ${summary.object} × ${summary.gripper}`;
  const consequence =
    action === 'release'
      ? 'Robots that ask the catalogue for this pair will get this set from now on, until another set is released or this one is withdrawn.'
      : 'The catalogue will never serve this set again; the pair falls back to its newest set for the newest object and gripper versions, if any.';
  const verb = action === 'release' ? 'Release' : 'Withdraw';
  const dialog = h(
    'dialog',
    { class: 'confirm', 'aria-labelledby': 'confirm-title' },
    h(
      'form',
      { method: 'dialog' },
      h('h2', { id: 'confirm-title' }, `${verb} ${what}?`),
      h('p', {}, consequence),
      h(
        'div',
        { class: 'buttons' },
        h('button', { value: 'cancel', type: 'submit', class: 'secondary' }, 'Cancel'),
        h('button', { value: 'ok', type: 'submit', class: action === 'withdraw' ? 'danger' : 'primary' }, `${verb} set ${summary.id}`),
      ),
    ),
  );
  dialog.addEventListener('close', async () => {
    dialog.remove();
    if (dialog.returnValue !== 'ok') return;
    status(statusEl, `${verb.replace(/e$/, '')}ing set ${summary.id}…`);
    try {
      const result = await postJson(`/v1/grasp-sets/${summary.id}/${action}`);
      const verbPast = action === 'release' ? 'Released' : 'Withdrew';
      status(
        statusEl,
        result.changed
          ? `${verbPast} set ${summary.id}. The catalogue now serves ${result.current ? `set ${result.current}${result.released === result.current ? ' (released)' : ''}` : 'nothing'} for ${summary.object} × ${summary.gripper}.`
          : `Nothing changed: set ${summary.id} was already ${action === 'release' ? 'released' : 'withdrawn'}.`,
        'ok',
      );
      await done?.(result);
    } catch (err) {
      status(statusEl, explain(err), 'error');
    }
  });
  document.body.append(dialog);
  dialog.showModal();
}

export function legend(r, label) {
  if (!r) return h('p', { class: 'legend' }, `${label}: not in this set`);
  return h(
    'div',
    { class: 'legend', 'aria-label': `colour scale of ${label}` },
    h('span', {}, r.min.toFixed(2)),
    h('span', { class: 'ramp', 'aria-hidden': 'true' }),
    h('span', {}, r.max.toFixed(2)),
    h('span', { class: 'muted' }, ` ${label}`),
  );
}

export { THREE };
