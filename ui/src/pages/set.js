// One grasp set in 3D with its numbers: the part, the gripper at every grasp coloured by a margin, the candidate
// cloud, the selected grasp's numbers and free rolls, the criteria funnel, coverage, parameters, timings, and release
// or withdraw. Performance marks gg:set:drawn, gg:set:candidates and gg:set:complete time the load (bench/bench_ui.py).
import { explain, getJson } from '../api.js';
import { MEASURES } from '../colour.js';
import { badge, clear, facts, h, mm, num, table, when } from '../dom.js';
import { quaternionXyzw } from '../gripper.js';
import {
  confirmChange,
  graspColours,
  legend,
  cloudColours,
  loadCandidates,
  loadSet,
  servedBy,
  setSummary,
  stateBadges,
  status,
} from '../shared.js';
import { GraspViewer, softwareRendering } from '../viewer.js';
import { historyTable } from './pair.js';

/** How long the first frame waits for the candidate cloud and the side pane's requests once the part is in (ms, on
 * software GL, where a frame is expensive). */
const FIRST_FRAME_WAIT_MS = 250;

export function funnel(stats) {
  const total = stats.pairs_total ?? stats.pairs ?? null;
  const rows = [];
  const bar = (v) => {
    const share = total ? Math.log10(v + 1) / Math.log10(total + 1) : 0;
    return h('span', { class: 'bar', style: `width: ${(share * 100).toFixed(1)}%` });
  };
  let left = total;
  if (total !== null) rows.push(['pairs (all)', '–', num(total), bar(total)]);
  for (const [criterion, rejected] of Object.entries(stats.rejected ?? {})) {
    if (left !== null) left -= rejected;
    rows.push([criterion, num(rejected), left === null ? '–' : num(left), left === null ? '' : bar(left)]);
  }
  if (stats.candidates !== undefined) {
    rows.push([h('strong', {}, 'candidates (NPZ)'), '–', num(stats.candidates), bar(stats.candidates)]);
  }
  return table('Criteria funnel: pairs removed by each criterion, in order', ['Criterion', 'Rejected', 'Left', ''], rows, {
    class: 'funnel',
  });
}

export function coverage(stats) {
  const c = stats.coverage;
  if (!c) return h('p', { class: 'muted' }, 'No coverage figures in this set.');
  return facts([
    ...(c.levels ?? []).map((l) => [
      `within ${mm(l.radius, 0)} and ${l.angle_deg}°`,
      `${(l.share * 100).toFixed(1)} % of candidates near a grasp`,
    ]),
    ['closest two grasps', `${mm(c.min_pair_translation, 3)}, ${num(c.min_pair_angle_deg, 2)}°`],
    ['selected / candidates', `${num(c.selected)} / ${num(c.candidates)}`],
  ]);
}

function kv(object, caption) {
  return table(
    caption,
    ['Name', 'Value'],
    Object.entries(object ?? {}).map(([k, v]) => [k, typeof v === 'object' && v !== null ? JSON.stringify(v) : num(v, 4)]),
    { class: 'kv' },
  );
}

export function graspNumbers(grasp, index, count) {
  const T = grasp.pose;
  const quat = quaternionXyzw(T);
  return h(
    'div',
    {},
    h('h3', {}, `Grasp ${index + 1} of ${count}`),
    facts([
      grasp.width !== undefined && ['width', `${mm(grasp.width)} (${num(grasp.width, 5)} m)`],
      ['friction margin', `${num(grasp.friction_margin_deg, 2)}°`],
      grasp.hold_margin !== undefined && ['hold margin', `${num(grasp.hold_margin, 3)} × the load`],
      grasp.quality && ['quality score', num(grasp.quality.score, 3)],
      [
        'free rolls',
        `${(grasp.free_rolls_deg ?? []).length}: ${(grasp.free_rolls_deg ?? []).map((r) => `${r}°`).join(', ')}`,
      ],
      grasp.roll_deg !== undefined && ['drawn at roll', `${grasp.roll_deg}°`],
      ['cluster', `[${(grasp.cluster ?? []).join(', ')}] (translation, direction)`],
      ['cluster size', `${num(grasp.cluster_size)} candidates`],
      grasp.candidate !== undefined && ['candidate', `row ${grasp.candidate} of the NPZ`],
      ['position', `[${T.slice(0, 3).map((r) => num(r[3], 5)).join(', ')}] m`],
      ['quaternion xyzw', `[${quat.map((v) => num(v, 5)).join(', ')}]`],
    ]),
    table(
      'pose T_object_grasp (4x4, metres)',
      ['', 'c0', 'c1', 'c2', 'c3'],
      T.map((r, i) => [`r${i}`, ...r.map((v) => num(v, 5))]),
      { class: 'pose' },
    ),
  );
}

export async function setPage(main, id) {
  performance.clearMarks();
  performance.clearMeasures();
  performance.mark('gg:set:start');
  const statusEl = h('div');
  const changeStatus = h('div', { class: 'change-status' });
  const viewerEl = h('div', { class: 'viewer', dataset: { state: 'loading' } });
  const legendEl = h('div');
  const selectedEl = h('section', { class: 'selected', 'aria-live': 'polite', 'aria-labelledby': 'sel-title' });
  const graspsEl = h('div', { class: 'table-wrap grasp-list' });
  const headerEl = h('div');
  const historyEl = h('details', { class: 'pair-history' });
  const detailsEl = h('div');
  const candidatesNote = h('span', { class: 'muted' });
  const colourSelect = h('select', { id: 'colour-by' });
  const showCandidates = h('input', { type: 'checkbox', id: 'show-candidates', checked: true });
  const showGrippers = h(
    'select',
    { id: 'show-grippers' },
    h('option', { value: 'all' }, 'at every grasp'),
    h('option', { value: 'selected' }, 'at the selected grasp only'),
  );
  const fitButton = h('button', { type: 'button' }, 'Fit view');

  clear(
    main,
    h(
      'div',
      { class: 'set-layout' },
      h(
        'section',
        { class: 'view-pane', 'aria-label': '3D view' },
        viewerEl,
        h(
          'div',
          { class: 'view-controls' },
          h('label', { for: 'colour-by' }, 'Colour by '),
          colourSelect,
          h('label', { for: 'show-grippers' }, 'Grippers '),
          showGrippers,
          h('label', {}, showCandidates, ' candidates '),
          candidatesNote,
          fitButton,
          legendEl,
        ),
        h(
          'p',
          { class: 'muted hint' },
          'Drag to turn, scroll to zoom, right-drag to pan; click a gripper (or a row of the list) to see its numbers. ' +
            'With the view focused, ← and → step through the grasps.',
        ),
      ),
      h(
        'aside',
        { class: 'side-pane' },
        headerEl,
        changeStatus,
        historyEl,
        statusEl,
        selectedEl,
        h('h2', {}, 'Grasps'),
        graspsEl,
        detailsEl,
      ),
    ),
  );
  clear(selectedEl, h('h2', { id: 'sel-title' }, 'Selected grasp'), h('p', { class: 'muted' }, 'None yet.'));
  status(statusEl, `Loading set ${id}…`);

  let bundle;
  let viewer = null;
  let left = false; // the page was left: nothing more to draw
  main.addEventListener('page:leave', () => ((left = true), viewer?.dispose()), { once: true });
  // the export and beside it the candidate cloud (a decimated view: a few MB at most) at once; the WebGL context once
  // the export is in and the part is on its way (creating it blocks this thread for 50-100 ms on software GL)
  let served; // what the catalogue serves for the pair, history and job: asked for as soon as the export names them
  let history;
  let jobRecord;
  const loading = loadSet(id, {
    onExport: (exportJson, summaryP) => {
      const { name: object } = exportJson.object;
      const { name: gripper } = exportJson.gripper;
      served = servedBy(object, gripper).catch(() => null);
      history = historyTable(object, gripper, 5).catch((err) => h('p', { class: 'status error' }, explain(err)));
      jobRecord = summaryP.then((s) => (s?.job ? getJson(`/v1/jobs/${s.job}`) : null));
      jobRecord.catch(() => {}); // shown below
      if (!left) viewer = new GraspViewer(viewerEl, { label: `3D view of grasp set ${id}` });
    },
  });
  loading.catch(() => {}); // handled below
  const cloudLoading = loadCandidates(id);
  let cloud = null; // the cloud once loaded: {n, positions, values, drawn}
  cloudLoading.then((c) => (cloud = c), () => {}); // errors: drawCandidates() below
  try {
    bundle = await loading;
  } catch (err) {
    status(statusEl, explain(err), 'error');
    viewerEl.dataset.state = 'error';
    return;
  }
  if (left) return;
  const { exportJson, summary, part, meshes } = bundle;
  const grasps = exportJson.grasps ?? [];
  for (const [key, m] of Object.entries(MEASURES)) {
    if (grasps.some((g) => m.of(g) !== null)) colourSelect.append(h('option', { value: key }, m.label));
  }
  const measure = () => colourSelect.value || 'friction_margin_deg';
  let colouring = graspColours(grasps, measure());

  // the grasp list: one real button per grasp (the keyboard's way to select)
  const rows = grasps.map((g, i) =>
    h(
      'tr',
      { dataset: { index: String(i) } },
      h('td', {}, h('button', { type: 'button', class: 'link', onclick: () => viewer.select('a', i) }, `Grasp ${i + 1}`)),
      h('td', { class: 'num' }, g.width !== undefined ? mm(g.width, 1) : '–'),
      h('td', { class: 'num' }, num(g.friction_margin_deg, 1)),
      h('td', { class: 'num' }, g.hold_margin !== undefined ? num(g.hold_margin, 2) : '–'),
      h('td', { class: 'num' }, String((g.free_rolls_deg ?? []).length)),
      h('td', { class: 'num' }, num(g.cluster_size)),
    ),
  );
  clear(
    graspsEl,
    table(
      `${grasps.length} grasps, best first within each translation cluster`,
      ['Grasp', 'Width', 'Friction margin (°)', 'Hold margin', 'Free rolls', 'Cluster size'],
      rows,
      { class: 'grasps' },
    ),
  );
  viewer.onSelect((sel) => {
    rows.forEach((r) => r.removeAttribute('aria-current'));
    if (!sel) return;
    rows[sel.index]?.setAttribute('aria-current', 'true');
    rows[sel.index]?.scrollIntoView({ block: 'nearest' });
    clear(selectedEl, h('h2', { id: 'sel-title' }, 'Selected grasp'), graspNumbers(grasps[sel.index], sel.index, grasps.length));
  });
  viewer.renderer.domElement.addEventListener('keydown', (e) => {
    if (!grasps.length || (e.key !== 'ArrowRight' && e.key !== 'ArrowLeft')) return;
    e.preventDefault();
    const at = viewer.selected?.index ?? -1;
    viewer.select('a', (at + (e.key === 'ArrowRight' ? 1 : grasps.length - 1)) % grasps.length);
  });
  fitButton.addEventListener('click', () => viewer.fit());
  showGrippers.addEventListener('change', () => viewer.setLayerVisible('a', showGrippers.value === 'all'));

  // header, state and actions
  function renderHeader(servedNow) {
    const pairLink = `#/pair/${encodeURIComponent(exportJson.object.name)}/${encodeURIComponent(exportJson.gripper.name)}`;
    clear(
      headerEl,
      h('p', { class: 'crumbs' }, h('a', { href: '#/' }, 'Catalogue'), ' › ', h('a', { href: pairLink }, `${exportJson.object.name} × ${exportJson.gripper.name}`)),
      h('h1', {}, `Grasp set ${id}`, summary ? ` · version ${summary.version}` : ''),
      h(
        'p',
        {},
        `${exportJson.object.name} v${exportJson.object.version} × ${exportJson.gripper.name}`,
        summary ? ` v${summary.gripper_version}` : '',
        ` · ${grasps.length} grasps · ${num(exportJson.stats?.candidates)} candidates `,
        ...stateBadges(summary, servedNow),
      ),
      summary
        ? h(
            'div',
            { class: 'actions' },
            h('button', { type: 'button', class: 'primary', onclick: () => confirmChange('release', summary, changeStatus, after) }, `Release set ${id}`),
            h('button', { type: 'button', class: 'danger', onclick: () => confirmChange('withdraw', summary, changeStatus, after) }, `Withdraw set ${id}`),
            h('a', { href: pairLink, class: 'button-link' }, 'Versions and history'),
          )
        : null,
    );
  }
  function renderHistory(body, open = false) {
    const { name: object } = exportJson.object;
    const { name: gripper } = exportJson.gripper;
    clear(historyEl, h('summary', {}, `Releases and withdrawals of ${object} × ${gripper} (newest 5)`), body);
    historyEl.open = open;
  }
  async function after() {
    const { name: object } = exportJson.object;
    const { name: gripper } = exportJson.gripper;
    const [fresh, servedNow, body] = await Promise.all([
      setSummary(id, object, gripper).catch(() => null),
      servedBy(object, gripper).catch(() => null),
      historyTable(object, gripper, 5).catch((err) => h('p', { class: 'status error' }, explain(err))),
    ]);
    Object.assign(summary, fresh ?? {});
    renderHeader(servedNow);
    renderHistory(body, true);
  }
  renderHeader(null); // the title and actions at once; the catalogue's state when it is in
  const header = Promise.all([served.then(renderHeader), history.then((body) => renderHistory(body))]);

  // details: funnel, coverage, parameters, timings, the job (its times arrive when they do)
  const stats = exportJson.stats ?? {};
  const jobEl = h('div');
  const job = jobRecord
    .then((j) =>
      j
        ? clear(
            jobEl,
            facts([
              ['job', h('a', { href: `#/jobs/${j.id}` }, j.id)],
              ['submitted', `${when(j.created_at)} by ${j.created_by ?? '?'}`],
              ['started', when(j.started_at)],
              ['finished', when(j.finished_at)],
              j.started_at &&
                j.finished_at && ['run time', `${((new Date(j.finished_at) - new Date(j.started_at)) / 1000).toFixed(1)} s`],
            ]),
          )
        : null,
    )
    .catch(() => clear(jobEl, h('p', { class: 'muted' }, 'The job that made this set is not readable with this token.')));
  clear(
    detailsEl,
    h('h2', {}, 'How the set was made'),
    funnel(stats),
    (stats.warnings ?? []).length ? h('ul', { class: 'warnings' }, stats.warnings.map((w) => h('li', {}, w))) : null,
    stats.empty_reason ? h('p', { class: 'status error' }, stats.empty_reason) : null,
    h('h3', {}, 'Coverage'),
    coverage(stats),
    stats.hold ? kv(stats.hold, 'Hold (criterion (e))') : null,
    kv(exportJson.params, 'Parameters'),
    kv(stats.timings_s, 'Timings (seconds)'),
    jobEl,
    kv(exportJson.gripper, `Gripper ${exportJson.gripper.name}`),
  );

  // the candidate cloud: in the first frame when it is in by then (one software-GL frame less), else in a later one
  function showCloud() {
    performance.mark('gg:candidates:start');
    const { colours } = cloudColours(cloud, measure());
    cloud.drawn = viewer.setCandidates('a', cloud.positions, colours);
    viewer.setCandidatesVisible('a', showCandidates.checked);
    candidatesNote.textContent =
      cloud.drawn < cloud.n ? `(${num(cloud.drawn)} of ${num(cloud.n)} drawn)` : `(${num(cloud.n)})`;
  }
  function cloudOnScreen() {
    performance.mark('gg:set:candidates');
    performance.measure('gg:set:candidates', 'gg:set:start', 'gg:set:candidates');
  }
  async function drawCandidates() {
    try {
      await cloudLoading;
      showCloud();
      await viewer.rendered();
    } catch (err) {
      candidatesNote.textContent = err.status === 404 ? '(none stored)' : `(not shown: ${explain(err)})`;
    }
    cloudOnScreen();
  }
  // the first frame, once the side pane is built. On software GL a frame blocks this thread for 100-500 ms, and what
  // arrives meanwhile waits behind it (and behind the compositor's copy of the canvas): there the frame waits for the
  // cloud and the side pane's requests, a quarter of a second at most
  await Promise.race([
    Promise.allSettled([cloudLoading, header, job]),
    new Promise((resolve) => setTimeout(resolve, softwareRendering() ? FIRST_FRAME_WAIT_MS : 0)),
  ]);
  if (left) return;
  viewer.renderer.domElement.setAttribute(
    'aria-label',
    `3D view of grasp set ${id}: ${grasps.length} grasps on ${exportJson.object.name}`,
  );
  viewer.setPart(part.geometry, part.points);
  try {
    viewer.setGrasps('a', exportJson, colouring.colours, { meshes, opacity: 0.8 });
  } catch (err) {
    status(statusEl, `The gripper cannot be drawn: ${err.message}`, 'error');
  }
  viewer.fit();
  clear(legendEl, legend(colouring.range, MEASURES[measure()].label));
  const cloudFirst = cloud !== null;
  if (cloudFirst) showCloud();
  else candidatesNote.textContent = '(loading…)';
  await viewer.rendered();
  performance.mark('gg:set:drawn');
  performance.measure('gg:set:drawn', 'gg:set:start', 'gg:set:drawn');
  if (cloudFirst) cloudOnScreen();
  const candidatesDrawn = cloudFirst ? null : drawCandidates();
  viewerEl.dataset.state = 'drawn';
  status(statusEl, null);

  showCandidates.addEventListener('change', () => viewer.setCandidatesVisible('a', showCandidates.checked));
  colourSelect.addEventListener('change', () => {
    colouring = graspColours(grasps, measure());
    viewer.recolour('a', colouring.colours);
    clear(legendEl, legend(colouring.range, MEASURES[measure()].label));
    if (cloud?.drawn !== undefined) showCloud();
  });
  await candidatesDrawn;
  await Promise.all([header, job]);
  performance.mark('gg:set:complete');
  performance.measure('gg:set:complete', 'gg:set:start', 'gg:set:complete');
  viewerEl.dataset.state = 'complete';
  viewerEl.dataset.candidates = String(cloud?.n ?? 0);
  viewerEl.dataset.drawnCandidates = String(cloud?.drawn ?? 0);
}
