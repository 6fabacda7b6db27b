// One pair: what the catalogue serves, every version (grasp set) with release and withdraw, the history of
// releases and withdrawals, and a choice of two versions to compare.
import { explain, getJson, hasToken, q, seg } from '../api.js';
import { badge, clear, h, table, when } from '../dom.js';
import { confirmChange, servedBy, status } from '../shared.js';

export async function historyTable(object, gripper, limit = 20) {
  const body = await getJson(`/v1/catalogue/${seg(object)}/${seg(gripper)}/history${q({ limit })}`);
  if (!body.items.length) return h('p', { class: 'empty' }, 'No release or withdrawal yet.');
  return table(
    'History: releases and withdrawals, newest first',
    ['When', 'Action', 'Set', 'By', 'Replaced'],
    body.items.map((e) => [
      when(e.at),
      e.action === 'release' ? badge('release', 'released') : badge('withdraw', 'withdrawn'),
      h('a', { href: `#/set/${e.grasp_set}` }, `set ${e.grasp_set} · v${e.version}`),
      e.by,
      e.replaced ? h('a', { href: `#/set/${e.replaced}` }, `set ${e.replaced}`) : '–',
    ]),
    { class: 'history' },
  );
}

function paramsText(p) {
  return ['points', 'k1', 'k2', 'rolls', 'friction', 'seed']
    .filter((k) => p?.[k] !== undefined)
    .map((k) => `${k} ${p[k]}`)
    .join(', ');
}

export async function pairPage(main, object, gripper) {
  const statusEl = h('div', { class: 'change-status' });
  const servedEl = h('div');
  const versionsEl = h('div', { class: 'table-wrap' });
  const historyEl = h('section', { 'aria-labelledby': 'history-title' });
  const compareButton = h('button', { type: 'button', disabled: true, class: 'primary' }, 'Compare the two chosen versions');
  const chosen = new Set();
  compareButton.addEventListener('click', () => {
    const [a, b] = [...chosen].sort((x, y) => x - y);
    location.hash = `#/compare/${a}/${b}`;
  });

  async function refresh() {
    try {
      const [served, sets, hist] = await Promise.all([
        servedBy(object, gripper),
        getJson(`/v1/grasp-sets${q({ object, gripper, limit: 100 })}`),
        historyTable(object, gripper),
      ]);
      clear(
        servedEl,
        served
          ? h(
              'p',
              { class: 'served' },
              'The catalogue serves ',
              h('a', { href: `#/set/${served.id}` }, `set ${served.id}`),
              ' to robots: ',
              served.released ? badge('released', 'released') : badge('not released: newest for the newest versions', 'current'),
              served.stale ? [' ', badge('stale: made for an older object or gripper version', 'stale')] : null,
            )
          : h('p', { class: 'served' }, badge('serves nothing', 'withdrawn'), ' No set is released or made for the newest object and gripper versions.'),
      );
      chosen.clear();
      compareButton.disabled = true;
      clear(
        versionsEl,
        table(
          `Versions of ${object} × ${gripper}${sets.next_cursor ? ' (newest 100)' : ''}`,
          ['Compare', 'Version', 'Set', 'Made for', 'Grasps', 'Parameters', 'Created', 'State', 'Actions'],
          sets.items.map((s) => {
            const box = h('input', {
              type: 'checkbox',
              id: `cmp-${s.id}`,
              'aria-label': `choose version ${s.version} (set ${s.id}) to compare`,
            });
            box.addEventListener('change', () => {
              if (box.checked) chosen.add(s.id);
              else chosen.delete(s.id);
              compareButton.disabled = chosen.size !== 2;
            });
            const isServed = served && served.id === s.id;
            const state = [];
            if (s.withdrawn_at) state.push(badge('withdrawn', 'withdrawn'));
            if (isServed) state.push(served.released ? badge('released', 'released') : badge('current', 'current'));
            if (isServed && served.stale) state.push(badge('stale', 'stale'));
            const actions = [h('a', { href: `#/set/${s.id}`, class: 'button-link' }, 'Review')];
            if (!(isServed && served.released) || s.withdrawn_at) {
              actions.push(
                h('button', { type: 'button', onclick: () => change('release', s) }, `Release v${s.version}`),
              );
            }
            if (!s.withdrawn_at) {
              actions.push(
                h('button', { type: 'button', class: 'danger', onclick: () => change('withdraw', s) }, `Withdraw v${s.version}`),
              );
            }
            return [
              box,
              `v${s.version}`,
              h('a', { href: `#/set/${s.id}` }, `set ${s.id}`),
              `object v${s.object_version} · gripper v${s.gripper_version}`,
              String(s.grasp_count),
              paramsText(s.params),
              `${when(s.created_at)}`,
              state,
              h('div', { class: 'actions' }, actions),
            ];
          }),
          { class: 'versions' },
        ),
      );
      clear(historyEl, h('h2', { id: 'history-title' }, 'History'), hist);
    } catch (err) {
      status(statusEl, explain(err), 'error');
    }
  }

  function change(action, summary) {
    confirmChange(action, summary, statusEl, refresh);
  }

  clear(
    main,
    h('p', { class: 'crumbs' }, h('a', { href: '#/' }, 'Catalogue'), ' › pair'),
    h('h1', {}, `${object} × ${gripper}`),
    hasToken() ? null : h('p', {}, 'Enter a token to see this pair.'),
    servedEl,
    statusEl,
    h('h2', {}, 'Versions'),
    h('p', { class: 'muted' }, 'Choose two versions to compare them; releasing and withdrawing need a token with the write scope.'),
    versionsEl,
    compareButton,
    historyEl,
  );
  await refresh();
}
