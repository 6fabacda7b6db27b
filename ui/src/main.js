// The review page: a hash router over the pages, the token form and the header. Every request goes to this
// server's /v1 API (same origin); the token lives in api.js' memory only.
import { explain, getJson, hasToken, onTokenChange, setToken } from './api.js';
import { clear, h } from './dom.js';
import { cataloguePage } from './pages/catalogue.js';
import { comparePage } from './pages/compare.js';
import { jobPage, jobsPage } from './pages/jobs.js';
import { pairPage } from './pages/pair.js';
import { setPage } from './pages/set.js';
import './style.css';

const main = document.getElementById('main');
const tokenButton = document.getElementById('token-button');
const tokenState = document.getElementById('token-state');

function tokenForm({ inline }) {
  const input = h('input', {
    id: inline ? 'token-inline' : 'token-input',
    type: 'password',
    autocomplete: 'off',
    spellcheck: 'false',
    required: true,
  });
  const message = h('p', { class: 'status', role: 'status' });
  const form = h(
    'form',
    { class: 'token-form', method: inline ? undefined : 'dialog' },
    h('label', { for: input.id }, 'Access token'),
    input,
    h('button', { type: 'submit', class: 'primary' }, 'Use token'),
    h(
      'p',
      { class: 'muted' },
      'The token is kept in this tab’s memory only: never in the address, a cookie or browser storage; reloading the page forgets it. ' +
        'A read token can look at everything; releasing and withdrawing need a token with the write scope.',
    ),
    message,
  );
  form.addEventListener('submit', async (e) => {
    e.preventDefault();
    const previous = hasToken();
    setToken(input.value.trim());
    try {
      await getJson('/v1/pairs?limit=1');
      input.value = '';
      form.closest('dialog')?.close();
      route();
    } catch (err) {
      if (!previous) setToken(null);
      message.className = 'status error';
      message.textContent = explain(err);
    }
  });
  return { form, input };
}

function askToken() {
  const { form, input } = tokenForm({ inline: false });
  const dialog = h('dialog', { class: 'token', 'aria-labelledby': 'token-title' }, h('h2', { id: 'token-title' }, 'Token'), form,
    h('button', { type: 'button', class: 'secondary', onclick: () => dialog.close() }, 'Cancel'));
  dialog.addEventListener('close', () => dialog.remove());
  document.body.append(dialog);
  dialog.showModal();
  input.focus();
}

tokenButton.addEventListener('click', askToken);
onTokenChange((set) => {
  tokenState.textContent = set ? 'token entered' : 'no token';
});

let routeCount = 0;
let current = null;

async function route() {
  const count = ++routeCount;
  // the page being left stops its polling and frees its WebGL contexts ('page:leave' on its element)
  current?.dispatchEvent(new Event('page:leave'));
  const page = h('div', { class: 'page' });
  current = page;
  clear(main, page);
  const [path, query = ''] = location.hash.replace(/^#/, '').split('?');
  const params = new URLSearchParams(query);
  const parts = path.split('/').filter(Boolean).map(decodeURIComponent);
  for (const a of document.querySelectorAll('header nav a')) {
    a.toggleAttribute('aria-current', a.getAttribute('href') === `#/${parts[0] ?? ''}`);
  }
  if (!hasToken()) {
    const { form, input } = tokenForm({ inline: true });
    clear(page, h('h1', {}, 'graspgen review'), h('p', { class: 'lead' }, 'This server needs a token to read its catalogue.'), form);
    input.focus();
    return;
  }
  try {
    if (parts[0] === 'set' && parts[1]) await setPage(page, Number(parts[1]));
    else if (parts[0] === 'pair' && parts[2]) await pairPage(page, parts[1], parts[2]);
    else if (parts[0] === 'compare' && parts[2]) await comparePage(page, Number(parts[1]), Number(parts[2]), params);
    else if (parts[0] === 'jobs' && parts[1]) await jobPage(page, parts[1]);
    else if (parts[0] === 'jobs') await jobsPage(page, params);
    else await cataloguePage(page, params);
  } catch (err) {
    if (count === routeCount) page.append(h('p', { class: 'status error', role: 'alert' }, explain(err)));
  }
  if (count === routeCount) document.title = `${main.querySelector('h1')?.textContent ?? 'review'} · graspgen`;
}

window.addEventListener('hashchange', route);
route();
