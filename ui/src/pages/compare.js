// Two versions of a pair (or any two sets) side by side or overlaid, with what changed in the numbers: versions,
// gripper spec, parameters, criteria counts, coverage, grasp count and margins.
import { explain } from '../api.js';
import { clear, h, num, table } from '../dom.js';
import { graspColours, legend, loadSet, status } from '../shared.js';
import { MEASURES } from '../colour.js';
import { GraspViewer } from '../viewer.js';

const TINT = { a: [0.15, 0.39, 0.92], b: [0.96, 0.45, 0.09] };

function summaryOf(values) {
  const v = values.filter((x) => x !== null && Number.isFinite(x)).sort((x, y) => x - y);
  if (!v.length) return null;
  return { min: v[0], median: v[Math.floor(v.length / 2)], max: v[v.length - 1] };
}

function flat(prefix, object, out = {}) {
  for (const [k, v] of Object.entries(object ?? {})) {
    const key = prefix ? `${prefix}.${k}` : k;
    if (v && typeof v === 'object' && !Array.isArray(v)) flat(key, v, out);
    else out[key] = Array.isArray(v) ? JSON.stringify(v) : v;
  }
  return out;
}

function diffRows(a, b, { onlyChanged = false } = {}) {
  const fa = flat('', a);
  const fb = flat('', b);
  const keys = [...new Set([...Object.keys(fa), ...Object.keys(fb)])];
  return keys
    .map((k) => {
      const changed = JSON.stringify(fa[k]) !== JSON.stringify(fb[k]);
      if (onlyChanged && !changed) return null;
      let delta = '';
      if (changed && typeof fa[k] === 'number' && typeof fb[k] === 'number') {
        const d = fb[k] - fa[k];
        delta = `${d > 0 ? '+' : ''}${num(d, 4)}`;
      }
      return h(
        'tr',
        { class: changed ? 'changed' : '' },
        h('th', { scope: 'row' }, k),
        h('td', {}, fa[k] === undefined ? '–' : num(fa[k], 4)),
        h('td', {}, fb[k] === undefined ? '–' : num(fb[k], 4)),
        h('td', {}, changed ? (delta || 'changed') : ''),
      );
    })
    .filter(Boolean);
}

function diffTable(caption, a, b, options) {
  const rows = diffRows(a, b, options);
  if (!rows.length) return h('p', { class: 'muted' }, `${caption}: no difference.`);
  return table(caption, ['', 'A', 'B', 'Change'], rows, { class: 'diff' });
}

function margins(exportJson) {
  const g = exportJson.grasps ?? [];
  const out = { grasps: g.length };
  for (const [key, m] of Object.entries(MEASURES)) {
    const s = summaryOf(g.map(m.of));
    if (s) for (const [k, v] of Object.entries(s)) out[`${key} ${k}`] = v;
  }
  return out;
}

export async function comparePage(main, idA, idB, params) {
  const statusEl = h('div');
  const viewsEl = h('div', { class: 'compare-views' });
  const numbersEl = h('div');
  const mode = params.get('mode') === 'side' ? 'side' : 'overlay';
  const modeOverlay = h('input', { type: 'radio', name: 'mode', id: 'mode-overlay', value: 'overlay', checked: mode === 'overlay' });
  const modeSide = h('input', { type: 'radio', name: 'mode', id: 'mode-side', value: 'side', checked: mode === 'side' });
  for (const r of [modeOverlay, modeSide]) {
    r.addEventListener('change', () => {
      location.hash = `#/compare/${idA}/${idB}${r.value === 'side' ? '?mode=side' : ''}`;
    });
  }
  clear(
    main,
    h('p', { class: 'crumbs' }, h('a', { href: '#/' }, 'Catalogue'), ' › compare'),
    h('h1', {}, `Compare set ${idA} (A) with set ${idB} (B)`),
    h(
      'fieldset',
      { class: 'mode' },
      h('legend', {}, 'View'),
      h('label', {}, modeOverlay, ' overlaid (A blue, B orange)'),
      h('label', {}, modeSide, ' side by side (coloured by friction margin)'),
    ),
    statusEl,
    viewsEl,
    numbersEl,
  );
  status(statusEl, 'Loading both sets…');
  let a;
  let b;
  try {
    [a, b] = await Promise.all([loadSet(idA), loadSet(idB)]);
  } catch (err) {
    status(statusEl, explain(err), 'error');
    return;
  }
  status(statusEl, null);
  const viewers = [];
  main.addEventListener('page:leave', () => viewers.forEach((v) => v.dispose()), { once: true });
  const label = (s, tag) =>
    `${tag}: set ${s.id}${s.summary ? ` v${s.summary.version}` : ''} · ${s.exportJson.object.name} v${s.exportJson.object.version} × ${s.exportJson.gripper.name}${s.summary ? ` v${s.summary.gripper_version}` : ''} · ${s.exportJson.grasps.length} grasps`;
  if (mode === 'overlay') {
    const el = h('div', { class: 'viewer', dataset: { state: 'loading' } });
    clear(viewsEl, h('div', { class: 'compare-one' }, h('p', {}, h('span', { class: 'swatch a' }), label(a, 'A'), h('br'), h('span', { class: 'swatch b' }), label(b, 'B')), el));
    const v = new GraspViewer(el, { label: `sets ${idA} and ${idB} overlaid` });
    viewers.push(v);
    v.setPart(a.part.geometry, a.part.points);
    v.setGrasps('a', a.exportJson, a.exportJson.grasps.map(() => TINT.a), { meshes: a.meshes, opacity: 0.7 });
    v.setGrasps('b', b.exportJson, b.exportJson.grasps.map(() => TINT.b), { meshes: b.meshes, opacity: 0.7 });
    v.fit();
    await v.rendered();
    el.dataset.state = 'drawn';
  } else {
    const els = [a, b].map(() => h('div', { class: 'viewer', dataset: { state: 'loading' } }));
    clear(
      viewsEl,
      h('div', { class: 'compare-two' }, [a, b].map((s, i) => h('div', {}, h('p', {}, label(s, i ? 'B' : 'A')), els[i]))),
    );
    const ranges = [];
    [a, b].forEach((s, i) => {
      const v = new GraspViewer(els[i], { label: `set ${s.id}` });
      viewers.push(v);
      v.setPart(s.part.geometry, s.part.points);
      const c = graspColours(s.exportJson.grasps, 'friction_margin_deg');
      ranges.push(c.range);
      v.setGrasps('a', s.exportJson, c.colours, { meshes: s.meshes });
      v.fit();
    });
    // turning one view turns the other: the same viewpoint on both
    viewers[0].controls.addEventListener('change', () => {
      viewers[1].camera.position.copy(viewers[0].camera.position);
      viewers[1].controls.target.copy(viewers[0].controls.target);
      viewers[1].controls.update();
    });
    viewsEl.append(legend(ranges[0], `${MEASURES.friction_margin_deg.label}, A; B has its own range`));
    await Promise.all(viewers.map((v) => v.rendered()));
    els.forEach((e) => (e.dataset.state = 'drawn'));
  }
  const versions = (s) => ({
    set: s.id,
    version: s.summary?.version,
    object_version: s.exportJson.object.version,
    object_sha256: s.exportJson.object.sha256?.slice(0, 12),
    gripper_version: s.summary?.gripper_version,
    created_at: s.summary?.created_at,
  });
  const statsOf = (s) => {
    const st = s.exportJson.stats ?? {};
    return {
      pairs_total: st.pairs_total,
      rejected: st.rejected,
      candidates: st.candidates,
      coverage: Object.fromEntries((st.coverage?.levels ?? []).map((l) => [`share within ${l.radius} m / ${l.angle_deg}°`, l.share])),
      timings_total_s: st.timings_s?.total,
    };
  };
  clear(
    numbersEl,
    h('h2', {}, 'What changed'),
    h('p', { class: 'muted' }, 'Rows that differ are marked; numbers show B − A.'),
    h(
      'div',
      { class: 'diff-grid' },
      diffTable('Versions', versions(a), versions(b)),
      diffTable('Grasps and margins', margins(a.exportJson), margins(b.exportJson)),
      diffTable('Parameters', a.exportJson.params, b.exportJson.params),
      diffTable('Criteria and coverage', statsOf(a), statsOf(b)),
      diffTable('Gripper spec (changed fields)', a.exportJson.gripper, b.exportJson.gripper, { onlyChanged: true }),
    ),
  );
}
