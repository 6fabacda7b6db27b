// Jobs: the token's jobs (every job for an admin token) with their state and progress, refreshed while any runs;
// one job polled as its Retry-After says, with the problem's text when it failed and a link to its set when done.
import { explain, getJson, getWithHeaders, q, retryAfter } from '../api.js';
import { badge, clear, facts, h, when } from '../dom.js';
import { status } from '../shared.js';

const ACTIVE = new Set(['queued', 'running']);

function stateBadge(state) {
  const kind = { succeeded: 'released', failed: 'withdrawn', cancelled: 'stale', running: 'current', queued: 'current' }[state];
  return badge(state, kind ?? 'current');
}

function progress(job) {
  return h('progress', { max: 1, value: job.progress ?? 0, 'aria-label': `progress of job ${job.id}` }, `${Math.round((job.progress ?? 0) * 100)} %`);
}

function problemText(error) {
  if (!error) return null;
  return [error.title, error.detail].filter(Boolean).join(': ') || JSON.stringify(error);
}

/** Wait `seconds`, unless the page is left first (then false). */
function sleep(main, seconds) {
  return new Promise((resolve) => {
    const t = setTimeout(() => resolve(true), seconds * 1000);
    main.addEventListener('page:leave', () => (clearTimeout(t), resolve(false)), { once: true });
  });
}

export async function jobsPage(main, params) {
  const statusEl = h('div');
  const listEl = h('div', { class: 'table-wrap' });
  const stateSelect = h(
    'select',
    { id: 'job-state' },
    ['', 'queued', 'running', 'succeeded', 'failed', 'cancelled'].map((s) => h('option', { value: s }, s || 'any state')),
  );
  stateSelect.value = params.get('state') ?? '';
  stateSelect.addEventListener('change', () => {
    location.hash = `#/jobs${stateSelect.value ? `?state=${stateSelect.value}` : ''}`;
  });
  let left = false;
  main.addEventListener('page:leave', () => (left = true), { once: true });
  clear(
    main,
    h('h1', {}, 'Jobs'),
    h('p', { class: 'lead' }, 'The jobs submitted with your token (all jobs for an admin token), newest first.'),
    h('form', { class: 'filters', onsubmit: (e) => e.preventDefault() }, h('label', { for: 'job-state' }, 'State'), stateSelect),
    statusEl,
    listEl,
  );
  while (!left) {
    let page;
    try {
      page = await getJson(`/v1/jobs${q({ state: stateSelect.value, limit: 50 })}`);
    } catch (err) {
      status(statusEl, explain(err), 'error');
      return;
    }
    clear(
      listEl,
      page.items.length
        ? h(
            'table',
            { class: 'jobs' },
            h('caption', {}, `${page.items.length}${page.next_cursor ? '+' : ''} jobs`),
            h('thead', {}, h('tr', {}, ['Job', 'Kind', 'Object × gripper', 'State', 'Progress', 'Submitted', 'Result'].map((c) => h('th', { scope: 'col' }, c)))),
            h(
              'tbody',
              {},
              page.items.map((j) =>
                h(
                  'tr',
                  {},
                  h('td', {}, h('a', { href: `#/jobs/${j.id}` }, j.id.slice(0, 8))),
                  h('td', {}, j.kind),
                  h('td', {}, j.object ? `${j.object} × ${j.gripper}` : '–'),
                  h('td', {}, stateBadge(j.state), j.stage ? ` ${j.stage}` : ''),
                  h('td', {}, progress(j)),
                  h('td', {}, when(j.created_at), h('br'), j.created_by),
                  h(
                    'td',
                    {},
                    j.grasp_set ? h('a', { href: `#/set/${j.grasp_set}` }, `set ${j.grasp_set}`) : problemText(j.error) ?? '–',
                  ),
                ),
              ),
            ),
          )
        : h('p', { class: 'empty' }, 'No jobs.'),
    );
    if (!page.items.some((j) => ACTIVE.has(j.state)) || !(await sleep(main, 2))) return;
  }
}

export async function jobPage(main, id) {
  const body = h('div', { 'aria-live': 'polite' });
  const statusEl = h('div');
  clear(main, h('p', { class: 'crumbs' }, h('a', { href: '#/jobs' }, 'Jobs'), ' › job'), h('h1', {}, `Job ${id}`), statusEl, body);
  for (;;) {
    let job;
    let headers;
    try {
      ({ body: job, headers } = await getWithHeaders(`/v1/jobs/${encodeURIComponent(id)}`));
    } catch (err) {
      status(statusEl, explain(err), 'error');
      return;
    }
    const wait = retryAfter(headers);
    clear(
      body,
      h('p', { class: 'job-state' }, stateBadge(job.state), job.stage ? ` stage: ${job.stage} ` : ' ', progress(job), ` ${Math.round(job.progress * 100)} %`),
      job.state === 'failed' ? h('p', { class: 'status error', role: 'alert' }, `The job failed: ${problemText(job.error)}`) : null,
      job.grasp_set ? h('p', {}, h('a', { href: `#/set/${job.grasp_set}`, class: 'button-link primary' }, `Review grasp set ${job.grasp_set}`)) : null,
      facts([
        ['kind', job.kind],
        job.object && ['object', `${job.object} v${job.object_version}`],
        job.gripper && ['gripper', `${job.gripper} v${job.gripper_version}`],
        ['submitted', when(job.created_at)],
        ['started', when(job.started_at)],
        ['finished', when(job.finished_at)],
        ['attempts', String(job.attempts)],
        job.params && ['parameters', JSON.stringify(job.params)],
        ACTIVE.has(job.state) && ['next update', `in ${wait} s (the server's Retry-After)`],
      ]),
    );
    if (!ACTIVE.has(job.state) || !(await sleep(main, wait))) return;
  }
}
