// What several pages share: loading a grasp set with everything needed to draw it, the release / withdraw dialog,
// status messages.
import * as THREE from 'three';
import { STLLoader } from 'three/addons/loaders/STLLoader.js';
import { explain, getBytes, getJson, getWithHeaders, postJson, q, seg } from './api.js';
import { MEASURES, linearRampColours, normalise, ramp, range } from './colour.js';
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
  const path = `/v1/objects/${seg(name)}/versions/${version}`;
  // the record (format, units) and the file at once: the file's address is the API's own (GET .../file)
  const [record, bytes] = await Promise.all([getJson(path), getBytes(`${path}/file`)]);
  const { geometry, points } = await partGeometry(bytes, record.format, record.units);
  return { record, geometry, points };
}

/**
 * Everything drawing set `id` needs, loaded in parallel where it can be. `onExport(exportJson, summary)` runs once
 * the export is in and the requests it leads to are on their way (`summary` a promise of the set's summary): the set
 * page starts its other requests and creates its WebGL context there.
 */
export async function loadSet(id, { onExport = null } = {}) {
  const exportJson = await getJson(`/v1/grasp-sets/${id}`);
  performance.mark(`gg:set:${id}:export`);
  const summaryP = setSummary(id, exportJson.object.name, exportJson.gripper.name);
  const partP = loadPart(exportJson);
  partP.catch(() => {}); // awaited below
  summaryP.catch(() => {});
  onExport?.(exportJson, summaryP);
  const [part, summary] = await Promise.all([partP, summaryP]);
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

/** Candidates drawn at most: above this the server sends an even stride through the rows (issue 34: "decimated when
 * large"). */
export const CLOUD_LIMIT = 50000;

const CLOUD_ARRAYS = ['midpoints', 'friction_margin_deg', 'hold_margin'];

/**
 * The candidate cloud of set `id`: `{n, positions, values}` with `positions` (k*3 metres, the midpoints of k <=
 * `limit` candidates), `values` {friction_margin_deg, hold_margin} (k each, or absent) and `n` the set's candidate
 * count. The server sends only these arrays, decimated (GET .../candidates?arrays=...&max_rows=...); a server that
 * sends the whole NPZ is decimated here.
 */
export async function loadCandidates(id, limit = CLOUD_LIMIT) {
  const bytes = await getBytes(
    `/v1/grasp-sets/${id}/candidates${q({ arrays: CLOUD_ARRAYS.join(','), max_rows: limit })}`,
  );
  performance.mark('gg:candidates:fetched');
  const arrays = await readNpzAsync(bytes, [...CLOUD_ARRAYS, 'row_count']);
  performance.mark('gg:candidates:read');
  const mid = arrays.midpoints;
  if (!mid) throw new Error('the candidate NPZ has no midpoints');
  const k = mid.shape[0];
  const stride = Math.max(1, Math.ceil(k / limit));
  const values = {};
  for (const name of ['friction_margin_deg', 'hold_margin']) {
    if (arrays[name]) values[name] = stride === 1 ? arrays[name].data : arrays[name].data.filter((_, i) => i % stride === 0);
  }
  const positions = stride === 1 ? mid.data : mid.data.filter((_, i) => Math.floor(i / 3) % stride === 0);
  const n = arrays.row_count ? Number(arrays.row_count.data[0]) : k;
  return { n, positions, values };
}

/** Linear-light colours (k*3 floats) of a cloud's candidates by `measure` (hold_margin, else the friction margin). */
export function cloudColours(cloud, measure) {
  const values = measure === 'hold_margin' ? cloud.values.hold_margin : cloud.values.friction_margin_deg;
  const r = values ? range(values) : null;
  return { colours: linearRampColours(values ?? null, r, cloud.positions.length / 3), range: r };
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
