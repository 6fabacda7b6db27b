// The catalogue: every object x gripper pair (GET /v1/pairs), filtered by name, gripper and state, paged by the
// server's cursors (never all pairs at once).
import { explain, getJson, q } from '../api.js';
import { badge, clear, h, table, when } from '../dom.js';
import { status } from '../shared.js';

const PAGE = 50;

async function gripperNames() {
  const names = [];
  let cursor = null;
  for (let i = 0; i < 20; i++) {
    const page = await getJson(`/v1/grippers${q({ cursor, limit: 200 })}`);
    names.push(...page.items.map((g) => g.name));
    cursor = page.next_cursor;
    if (!cursor) break;
  }
  return names;
}

function lastChange(item) {
  const e = item.last_event;
  const created = item.current?.created_at;
  if (e && (!created || e.at >= created)) {
    return [when(e.at), h('br'), `${e.action === 'release' ? 'released' : 'withdrew'} v${e.version} · ${e.by}`];
  }
  if (item.current) return [when(created), h('br'), `computed v${item.current.version} · ${item.current.created_by ?? '?'}`];
  return [when(item.updated_at)];
}

function row(item) {
  const pairLink = `#/pair/${encodeURIComponent(item.object)}/${encodeURIComponent(item.gripper)}`;
  const cur = item.current;
  const state = [];
  if (!cur) state.push(badge('serves nothing', 'withdrawn'));
  else state.push(item.released ? badge('released', 'released') : badge('not released', 'current'));
  if (item.stale) state.push(badge('stale', 'stale'));
  return h(
    'tr',
    {},
    h('td', {}, h('a', { href: pairLink }, item.object)),
    h('td', {}, item.gripper),
    h('td', {}, cur ? h('a', { href: `#/set/${cur.id}` }, `set ${cur.id} · v${cur.version}`) : '–'),
    h('td', { class: 'num' }, cur ? String(cur.grasp_count) : '–'),
    h('td', {}, cur ? `object v${cur.object_version} · gripper v${cur.gripper_version}` : '–'),
    h('td', {}, state),
    h('td', {}, lastChange(item)),
  );
}

export async function cataloguePage(main, params) {
  const filters = {
    object_contains: params.get('object') ?? '',
    gripper: params.get('gripper') ?? '',
    released: params.get('released') ?? '',
    stale: params.get('stale') ?? '',
  };
  const cursors = [null]; // cursors[k]: the cursor of page k (the server's, kept for "Previous")
  let pageIndex = 0;
  const statusEl = h('div');
  const tableEl = h('div', { class: 'table-wrap' });
  const pager = h('nav', { class: 'pager', 'aria-label': 'catalogue pages' });

  const objectInput = h('input', {
    id: 'f-object',
    type: 'search',
    value: filters.object_contains,
    placeholder: 'e.g. bracket',
    autocomplete: 'off',
    spellcheck: 'false',
  });
  const gripperSelect = h('select', { id: 'f-gripper' }, h('option', { value: '' }, 'all grippers'));
  const releasedSelect = h(
    'select',
    { id: 'f-released' },
    h('option', { value: '' }, 'any'),
    h('option', { value: 'true' }, 'released'),
    h('option', { value: 'false' }, 'not released'),
  );
  const staleSelect = h(
    'select',
    { id: 'f-stale' },
    h('option', { value: '' }, 'any'),
    h('option', { value: 'true' }, 'stale'),
    h('option', { value: 'false' }, 'up to date'),
  );
  releasedSelect.value = filters.released;
  staleSelect.value = filters.stale;

  async function load() {
    status(statusEl, 'Loading pairs…');
    try {
      const page = await getJson(
        `/v1/pairs${q({
          object_contains: filters.object_contains.toLowerCase().replace(/[^a-z0-9._-]/g, ''),
          gripper: filters.gripper,
          released: filters.released,
          stale: filters.stale,
          cursor: cursors[pageIndex],
          limit: PAGE,
        })}`,
      );
      cursors[pageIndex + 1] = page.next_cursor;
      const first = pageIndex * PAGE + 1;
      const last = pageIndex * PAGE + page.items.length;
      status(statusEl, null);
      clear(
        tableEl,
        page.items.length
          ? table(
              `Pairs ${first}–${last} of ${page.total.toLocaleString('en-US')}`,
              ['Object', 'Gripper', 'Current set', 'Grasps', 'Made for', 'State', 'Last change'],
              page.items.map(row),
              { class: 'catalogue' },
            )
          : h('p', { class: 'empty' }, 'No pair matches these filters.'),
      );
      clear(
        pager,
        h('button', { type: 'button', disabled: pageIndex === 0, onclick: () => go(pageIndex - 1) }, '← Previous'),
        h('span', {}, ` Page ${pageIndex + 1} of ${Math.max(1, Math.ceil(page.total / PAGE))} `),
        h('button', { type: 'button', disabled: !page.next_cursor, onclick: () => go(pageIndex + 1) }, 'Next →'),
      );
    } catch (err) {
      status(statusEl, explain(err), 'error');
    }
  }

  function go(k) {
    pageIndex = k;
    load();
  }

  let timer = null;
  function changed() {
    filters.object_contains = objectInput.value.trim();
    filters.gripper = gripperSelect.value;
    filters.released = releasedSelect.value;
    filters.stale = staleSelect.value;
    const shown = new URLSearchParams(
      Object.entries({
        object: filters.object_contains,
        gripper: filters.gripper,
        released: filters.released,
        stale: filters.stale,
      }).filter(([, v]) => v),
    ).toString();
    history.replaceState(null, '', `#/${shown ? `?${shown}` : ''}`);
    cursors.length = 1;
    pageIndex = 0;
    load();
  }
  objectInput.addEventListener('input', () => {
    clearTimeout(timer);
    timer = setTimeout(changed, 250);
  });
  for (const s of [gripperSelect, releasedSelect, staleSelect]) s.addEventListener('change', changed);

  clear(
    main,
    h('h1', {}, 'Catalogue'),
    h(
      'p',
      { class: 'lead' },
      'Every object × gripper pair with the grasp set the catalogue serves robots for it. Open a pair to see its versions and history, open a set to review it in 3D.',
    ),
    h(
      'form',
      { class: 'filters', role: 'search', onsubmit: (e) => e.preventDefault() },
      h('label', { for: 'f-object' }, 'Object name contains'),
      objectInput,
      h('label', { for: 'f-gripper' }, 'Gripper'),
      gripperSelect,
      h('label', { for: 'f-released' }, 'Released'),
      releasedSelect,
      h('label', { for: 'f-stale' }, 'Stale'),
      staleSelect,
    ),
    statusEl,
    tableEl,
    pager,
  );
  const loading = load();
  try {
    for (const name of await gripperNames()) gripperSelect.append(h('option', { value: name }, name));
    gripperSelect.value = filters.gripper;
  } catch (err) {
    status(statusEl, explain(err), 'error');
  }
  await loading;
}
