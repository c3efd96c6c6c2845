// rwpend console page: live plots (canvas), controls, gains panel, lights, bags, lab overview.
// No libraries, no network beyond the console itself. Served by rwpend_console.web.
'use strict';

const Q = new URLSearchParams(location.search);
// the controller's modes (rwpend_control.supervisor.MODES); /api/modes says which it can take
const MODES = ['off', 'wheel_velocity', 'wheel_angle', 'balance', 'swingup', 'auto', 'law'];
const LAW_COLORS = { off: '#e6e6e6', wheel_velocity: '#d6e6ff', wheel_angle: '#e6dcff',
  balance: '#d3f5d3', swingup: '#ffe7c2', catch: '#c9f0ef', brake: '#ffd0d0', law: '#f3dcf0' };
const U_SENT_COLOR = '#1756a9', U_APPLIED_COLOR = '#e0600b';
// the plotted signals: label, unit, column of a state row (or 'u'), minimal span of the y axis
const SIGNALS = [
  { key: 'theta', label: '\u03b8 \u2212 \u03c0', unit: 'rad', col: 1, span: 0.2 },
  { key: 'theta_dot', label: '\u03b8\u0307', unit: 'rad/s', col: 2, span: 1 },
  { key: 'wheel_rate', label: 'wheel rate', unit: 'rad/s', col: 3, span: 10 },
  { key: 'u', label: 'u', unit: 'control units', col: 'u', span: 2 },   // sent and applied
  { key: 'energy', label: 'scaled energy E', unit: '(0 down, 2 up)', col: 4, span: 0.5 },
];
const MAX_PENDING = 3;   // other requests at once: the e-stop always finds a free connection
const STATUS_TIMEOUT_MS = 3000;   // no status for this long (it comes every 0.5 s): the console is lost
const LOST = 'no answer: the page lost the console (its connection was refused or dropped) -- is ' +
  './rwpend console still running? The rig\'s state is unknown until it answers again';

// ------------------------------------------------------------------ numbers
// as rwpend_console.fmt writes them (its EXAMPLES: the same text for the same number)
const SIGNAL_ZERO = 1e-9;

function trimZeros(t) { return t.includes('.') ? t.replace(/0+$/, '').replace(/\.$/, '') : t; }

function fmtNumber(v, digits = 6) {
  if (typeof v !== 'number') return String(v);
  if (Number.isNaN(v)) return 'NaN';
  if (!Number.isFinite(v)) return v > 0 ? '\u221e' : '-\u221e';
  if (v === 0) return '0';
  const [m, ex] = v.toExponential(digits - 1).split('e');
  const e = parseInt(ex, 10);
  if (e >= -4 && e < digits) return trimZeros(v.toFixed(Math.max(0, digits - 1 - e)));
  return trimZeros(m) + 'e' + e;
}

// a signal: |v| < 1e-9 is exactly 0 (the motor's current lag decays through 5e-324)
function fmtSignal(v, digits = 4) {
  if (typeof v !== 'number') return '-';
  return fmtNumber(Math.abs(v) < SIGNAL_ZERO ? 0 : v, digits);
}

window.rwpendFormat = { number: fmtNumber, signal: fmtSignal };

const S = {
  rig: Q.get('rig') || '', token: Q.get('token') || sessionStorage.getItem('rwpend-token') || '',
  window: 20, gen: null, state: [], u: [], applied: [], bands: [], node: 'controller',
  lastStatusMs: 0, lost: false,
  newest: null, arrivalMs: 0, speed: 1, lastDrawnT: null,
  stats: { frames: 0, fps: 0, samples: 0, frames_window: [], latency_ms: [], latency_kind: '', laws_seen: [] },
};
window.rwpendStats = S.stats;
window.rwpendPage = S;          // for tests and the curious: the page's data
if (S.token) sessionStorage.setItem('rwpend-token', S.token);

// ------------------------------------------------------------------ requests
let pending = 0;
const queue = [];

function headers() {
  const h = { 'Content-Type': 'application/json' };
  if (S.token) h['X-Rwpend-Token'] = S.token;
  return h;
}

// every answer is an object: a refusal {ok: false, error, status}, a request the console never
// answered {ok: false, lost: true, error: LOST} (never the browser's "TypeError: Failed to fetch")
function api(path, body) {
  return new Promise((resolve) => {
    queue.push(() => fetch(path, body === undefined ? { headers: headers() }
      : { method: 'POST', headers: headers(), body: JSON.stringify(body) })
      .then((r) => r.json()
        .then((j) => (r.ok ? j : { ...j, ok: false, status: r.status }))
        .catch(() => ({ ok: false, status: r.status, error: `HTTP ${r.status} without an answer` })))
      .catch(() => { setLost(true); return { ok: false, lost: true, error: LOST }; })
      .then((j) => { pending--; pump(); resolve(j); }));
    pump();
  });
}

window.rwpendApi = api;

function pump() {
  while (pending < MAX_PENDING && queue.length) { pending++; queue.shift()(); }
}

function $(id) { return document.getElementById(id); }

function say(id, text, ok) {
  const el = $(id);
  el.textContent = text;
  el.className = 'msg ' + (ok === undefined ? '' : ok ? 'ok' : 'refused');
}

function reasonOf(j) { return j.error || j.reason || j.message || ''; }

// why a request did not do what was asked: the console lost, the rig not answering (503), or
// the refusal with its reason
function failText(j) {
  if (j.lost) return j.error;
  if (j.status === 503) return 'no answer from the rig: ' + reasonOf(j);
  return 'refused: ' + reasonOf(j);
}

// the page lost the console (a request or the stream got no answer), or has it again
function setLost(lost) {
  if (lost === S.lost) return;
  S.lost = lost;
  document.body.classList.toggle('lost', lost);
  if (lost) {
    $('conn').textContent = 'lost the console: reconnecting';
    $('conn').title = LOST;
    showEstop({ state: 'unknown', pending: '', text: 'e-stop state unknown: ' + LOST });
    for (const el of document.querySelectorAll('#lights .light')) {
      el.className = 'light lv-stale';
      el.dataset.level = 'stale';
    }
  } else {
    $('conn').title = '';
  }
}

// ------------------------------------------------------------------ e-stop (never queued)
// The button shows the rig's e-stop as its plant reports it (rwpend_console.estop: raised,
// clear or unknown, who changed it, a request of this page not yet reported), whoever raised
// or cleared it; 'sent' only from the click until the console answers.
function showEstop(st) {
  const b = $('estop');
  b.dataset.state = st.state;
  b.dataset.pending = st.pending || '';
  b.classList.toggle('raised', st.state === 'raised');
  b.classList.toggle('unknown', st.state === 'unknown');
  b.classList.toggle('pending', !!st.pending);
  b.classList.toggle('unconfirmed', !!st.unconfirmed);
  b.textContent = st.state === 'raised' ? 'E-STOP RAISED' : 'E-STOP';
  const el = $('estop-state');
  el.textContent = st.text;
  el.className = 'st-' + st.state + (st.pending ? ' st-pending' : '') + (st.unconfirmed ? ' st-unconfirmed' : '');
  $('estop-clear').disabled = st.state === 'clear' && !st.pending;
  window.rwpendEstopState = st;
}

function estop(ev) {
  if (ev) ev.preventDefault();
  const clicked = Date.now();
  $('estop').classList.add('sent');
  $('estop-msg').textContent = 'E-STOP sent';
  fetch('/api/estop', { method: 'POST', keepalive: true, headers: { 'Content-Type': 'application/json' },
    body: JSON.stringify({ rig: S.rig, clicked_ms: clicked }) })
    .then((r) => r.json().catch(() => ({ ok: false, error: `HTTP ${r.status} without an answer` })))
    .then((j) => {
      $('estop').classList.remove('sent');
      const a = (j.answers || []).map((x) => `${x.service}: ${x.message}`).join('; ');
      $('estop-msg').textContent = j.ok ? `E-STOP sent in ${Date.now() - clicked} ms; ${a || 'no plant service answered'}`
        : 'E-STOP refused: ' + reasonOf(j);
      if (j.estop) showEstop(j.estop);
      window.rwpendEstop = { clicked_ms: clicked, answer: j };
    })
    .catch(() => {
      $('estop').classList.remove('sent');
      setLost(true);
      $('estop-msg').textContent = 'E-STOP NOT SENT: the page lost the console -- stop the rig by hand';
      window.rwpendEstop = { clicked_ms: clicked, answer: { ok: false, lost: true, error: LOST } };
    });
}

function clearEstop() {
  api('/api/estop/clear', { rig: S.rig }).then((j) => {
    $('estop-msg').textContent = j.ok ? 'e-stop cleared' : failText(j);
    if (j.estop) showEstop(j.estop);
  });
}

// ------------------------------------------------------------------ the stream
function connect() {
  const es = new EventSource('/api/stream?rig=' + encodeURIComponent(S.rig));
  es.addEventListener('frame', (e) => takeFrame(JSON.parse(e.data)));
  es.addEventListener('status', (e) => takeStatus(JSON.parse(e.data)));
  es.onopen = () => { setLost(false); $('conn').textContent = 'live'; };
  es.onerror = () => { setLost(true); };
  // a console that hangs sends nothing and closes nothing: lost too
  setInterval(() => {
    if (S.lastStatusMs && Date.now() - S.lastStatusMs > STATUS_TIMEOUT_MS) setLost(true);
  }, 1000);
}

function takeFrame(f) {
  if (f.reset || f.gen !== S.gen) {
    S.state = []; S.u = []; S.applied = []; S.bands = []; S.newest = null; S.gen = f.gen;
  }
  const now = Date.now();
  for (const r of f.s) S.state.push(r);
  for (const r of f.u) S.u.push(r);
  for (const r of f.a || []) S.applied.push(r);
  for (const r of f.b) {
    S.bands.push(r);
    if (!S.stats.laws_seen.includes(r[2])) S.stats.laws_seen.push(r[2]);   // every law shown since the page opened
  }
  S.stats.samples += f.s.length;
  const last = f.s.length ? f.s[f.s.length - 1][0] : null;
  if (last !== null) {
    if (S.newest !== null && now > S.arrivalMs) {
      const v = (last - S.newest) / ((now - S.arrivalMs) / 1e3);
      if (v > 0 && v < 100) S.speed = 0.8 * S.speed + 0.2 * v;
    }
    S.newest = last; S.arrivalMs = now;
  }
  trim();
}

function trim() {
  if (S.newest === null) return;
  const t0 = S.newest - S.window - 2;
  let i = 0;
  while (i < S.state.length && S.state[i][0] < t0) i++;
  if (i) S.state.splice(0, i);
  i = 0;
  while (i < S.u.length && S.u[i][0] < t0) i++;
  if (i) S.u.splice(0, i);
  i = 0;
  while (i < S.applied.length && S.applied[i][0] < t0) i++;
  if (i) S.applied.splice(0, i);
  while (S.bands.length > 1 && S.bands[1][0] < t0) S.bands.shift();
}

function takeStatus(st) {
  S.lastStatusMs = Date.now();
  setLost(false);
  if (st.error) {
    $('conn').textContent = st.error;
    showEstop({ state: 'unknown', pending: '', text: 'e-stop state unknown: ' + st.error });
    return;
  }
  $('conn').textContent = 'live';
  const r = st.rig;
  if (r.estop) showEstop(r.estop);
  $('rig-name').textContent = r.id;
  const sm = r.summary || {};
  $('mode-law').textContent = `mode ${sm.mode || '-'} / law ${sm.law || '-'}`;
  for (const b of document.querySelectorAll('#modes button')) {
    b.classList.toggle('current', b.dataset.mode === sm.mode);
  }
  drawLights(r.lights || []);
  drawRigs(st.overview.rigs || []);
  drawNodeTabs(r.nodes || []);
  const rec = r.recording;
  if (rec && rec.running) say('rec-msg', `recording ${rec.bag} (${rec.seconds} s)`, true);
}

function drawLights(lights) {
  const box = $('lights');
  box.textContent = '';
  for (const l of lights) {
    const el = document.createElement('span');
    el.className = 'light lv-' + l.level;
    el.dataset.key = l.key;
    el.dataset.level = l.level;
    el.title = l.facts && Object.keys(l.facts).length ? JSON.stringify(l.facts) : '';
    el.innerHTML = '<i></i><b></b><span class="why"></span>';
    el.querySelector('b').textContent = l.label;
    el.querySelector('.why').textContent = l.message;   // the reason, on the page (not a tooltip)
    box.appendChild(el);
  }
}

function drawRigs(rigs) {
  const body = document.querySelector('#rigs tbody');
  body.textContent = '';
  for (const g of rigs) {
    const tr = document.createElement('tr');
    tr.innerHTML = `<td></td><td></td><td><span class="light lv-${g.level}"><i></i>${g.level}` +
      `${g.estop ? ' E-STOP' : ''}</span></td><td><a>open</a></td>`;
    tr.children[0].textContent = g.id + (g.id === S.rig ? ' (open)' : '');
    tr.children[1].textContent = `${g.mode || '-'} / ${g.law || '-'}`;
    tr.querySelector('a').href = '?' + new URLSearchParams({ rig: g.id, ...(S.token ? { token: S.token } : {}) });
    body.appendChild(tr);
  }
}

// ------------------------------------------------------------------ plots
const canvas = $('plots');
const ctx = canvas.getContext('2d');

function rightEdge(nowMs) {
  if (S.newest === null) return 0;
  return S.newest + Math.min((nowMs - S.arrivalMs) / 1e3, 0.2) * S.speed;
}

const FRAME_MS = 1000 / 30;   // at most 30 frames/s: smooth scrolling at half a 60 Hz display's cost
let lastFrame = 0;

function frame(t) {
  if (t - lastFrame >= FRAME_MS - 2) {
    lastFrame = t;
    const nowMs = Date.now();
    draw(nowMs);
    countFrame(nowMs);
  }
  requestAnimationFrame(frame);
}

function countFrame(nowMs) {
  const w = S.stats.frames_window;
  S.stats.frames++;
  w.push(nowMs);
  while (w.length && w[0] < nowMs - 1000) w.shift();
  S.stats.fps = w.length;
  if (S.newest !== null && S.newest !== S.lastDrawnT) {
    S.lastDrawnT = S.newest;
    const row = S.state[S.state.length - 1];
    // real time: the stamps are this clock, the latency is sample -> screen; lockstep (sim
    // time): console receive -> screen
    const wall = Math.abs(row[0] * 1e3 - row[5]) < 5000;
    S.stats.latency_kind = wall ? 'sample stamp to frame' : 'console receive to frame';
    S.stats.latency_ms.push(nowMs - (wall ? row[0] * 1e3 : row[5]));
    if (S.stats.latency_ms.length > 2000) S.stats.latency_ms.shift();
  }
  if (S.stats.frames % 5 === 0) showReadouts();
  if (S.stats.frames % 30 === 0) {
    const l = S.stats.latency_ms.slice().sort((a, b) => a - b);
    const med = l.length ? l[Math.floor(l.length / 2)].toFixed(0) : '-';
    $('stats').textContent = `${S.stats.fps} frames/s, latency ${med} ms (${S.stats.latency_kind}), ` +
      `${S.stats.samples} samples, x${S.speed.toFixed(2)}`;
  }
}

// the newest u the controller sent and the motor got, as text (|u| < 1e-9: exactly 0)
function showReadouts() {
  const u = S.u.length ? S.u[S.u.length - 1][1] : null;
  const a = S.applied.length ? S.applied[S.applied.length - 1][1] : null;
  $('readout-u').textContent = u === null ? '-' : fmtSignal(u);
  $('readout-applied').textContent = a === null ? '-' : fmtSignal(a);
}

function value(sig, row) {
  if (sig.key !== 'theta') return row[sig.col];
  if (!$('theta-rel').checked) return row[1];
  const x = row[1] - Math.PI;
  return x - 2 * Math.PI * Math.floor((x + Math.PI) / (2 * Math.PI));
}

function draw(nowMs) {
  const dpr = window.devicePixelRatio || 1;
  const W = canvas.clientWidth, H = canvas.clientHeight;
  if (canvas.width !== Math.round(W * dpr) || canvas.height !== Math.round(H * dpr)) {
    canvas.width = Math.round(W * dpr); canvas.height = Math.round(H * dpr);
  }
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, W, H);
  const tR = rightEdge(nowMs), tL = tR - S.window;
  const ph = (H - 18) / SIGNALS.length;
  SIGNALS.forEach((sig, i) => drawPanel(sig, 0, i * ph, W, ph - 4, tL, tR));
  drawTimeAxis(W, H, tL, tR);
}

// the series of a panel: [{rows, value(row), color, label}]; u: what the controller sent and
// what the motor got (zero while the e-stop or the command timeout holds it)
function seriesOf(sig) {
  if (sig.col !== 'u') return [{ rows: S.state, value: (r) => value(sig, r), color: U_SENT_COLOR, label: '' }];
  return [{ rows: S.u, value: (r) => r[1], color: U_SENT_COLOR, label: 'sent (controller)' },
    { rows: S.applied, value: (r) => r[1], color: U_APPLIED_COLOR, label: 'applied (motor)' }];
}

function drawPanel(sig, x0, y0, W, h, tL, tR) {
  const series = seriesOf(sig);
  const left = 64, w = W - left - 6;
  const X = (t) => left + (t - tL) / (tR - tL) * w;
  drawBands(X, y0, h, tL, tR, left, w);
  let lo = Infinity, hi = -Infinity;
  for (const s of series) {
    for (const r of s.rows) {
      if (r[0] < tL) continue;
      const v = s.value(r);
      if (v === null) continue;
      if (v < lo) lo = v;
      if (v > hi) hi = v;
    }
  }
  if (!isFinite(lo)) { lo = -sig.span / 2; hi = sig.span / 2; }
  if (hi - lo < sig.span) { const m = (hi + lo) / 2; lo = m - sig.span / 2; hi = m + sig.span / 2; }
  const pad = (hi - lo) * 0.08;
  lo -= pad; hi += pad;
  const Y = (v) => y0 + h - (v - lo) / (hi - lo) * h;
  ctx.strokeStyle = '#bbb'; ctx.lineWidth = 1;
  ctx.strokeRect(left, y0, w, h);
  if (lo < 0 && hi > 0) { ctx.beginPath(); ctx.moveTo(left, Y(0)); ctx.lineTo(left + w, Y(0)); ctx.stroke(); }
  ctx.fillStyle = '#333'; ctx.font = '11px system-ui, sans-serif';
  ctx.fillText(sig.key === 'theta' && !$('theta-rel').checked ? '\u03b8' : sig.label, 4, y0 + 12);
  ctx.fillStyle = '#888';
  ctx.fillText(sig.unit, 4, y0 + 24);
  ctx.fillText(fmtNumber(hi, 3), 4, y0 + 36);
  ctx.fillText(fmtNumber(lo, 3), 4, y0 + h - 2);
  ctx.save();
  ctx.beginPath(); ctx.rect(left, y0, w, h); ctx.clip();
  // the applied command under what was sent, wider: where the two agree both stay visible
  for (const s of series.slice().reverse()) {
    ctx.strokeStyle = s.color; ctx.lineWidth = series.length > 1 && s.color === U_APPLIED_COLOR ? 2.6 : 1.3;
    ctx.beginPath();
    let started = false, prev = null;
    for (const r of s.rows) {
      if (r[0] < tL - 0.1) continue;
      const v = s.value(r);
      if (v === null) { started = false; continue; }
      // theta - pi wraps at +-pi: no line across the plot
      const jump = sig.key === 'theta' && prev !== null && Math.abs(v - prev) > Math.PI;
      if (!started || jump) ctx.moveTo(X(r[0]), Y(v)); else ctx.lineTo(X(r[0]), Y(v));
      started = true; prev = v;
    }
    ctx.stroke();
  }
  ctx.restore();
  if (series.length > 1) {     // the panel's legend with the newest values
    let x = left + 8;
    ctx.font = '11px system-ui, sans-serif';
    for (const s of series) {
      const last = s.rows.length ? s.rows[s.rows.length - 1] : null;
      const text = `u ${s.label} ${last ? fmtSignal(s.value(last)) : '-'}`;
      ctx.fillStyle = 'rgba(255,255,255,0.85)';
      ctx.fillRect(x - 3, y0 + 3, ctx.measureText(text).width + 22, 14);
      ctx.fillStyle = s.color; ctx.fillRect(x, y0 + 8, 12, 3);
      ctx.fillStyle = '#222'; ctx.fillText(text, x + 16, y0 + 14);
      x += ctx.measureText(text).width + 34;
    }
  }
}

function drawBands(X, y0, h, tL, tR, left, w) {
  for (let i = 0; i < S.bands.length; i++) {
    const a = Math.max(S.bands[i][0], tL);
    const b = i + 1 < S.bands.length ? S.bands[i + 1][0] : tR;
    if (b < tL || a > tR) continue;
    ctx.fillStyle = LAW_COLORS[S.bands[i][2]] || '#eee';
    ctx.fillRect(Math.max(X(a), left), y0, Math.min(X(b), left + w) - Math.max(X(a), left), h);
  }
}

function drawTimeAxis(W, H, tL, tR) {
  const left = 64, w = W - left - 6;
  ctx.fillStyle = '#555'; ctx.font = '11px system-ui, sans-serif';
  const step = S.window > 30 ? 10 : S.window > 12 ? 5 : 2;
  for (let t = Math.ceil(tL / step) * step; t <= tR; t += step) {
    const x = left + (t - tL) / (tR - tL) * w;
    ctx.fillText(`${(t - tR).toFixed(0)} s`, x - 8, H - 4);
  }
}

function drawLegend() {
  const box = $('legend');
  for (const [law, c] of Object.entries(LAW_COLORS)) {
    const el = document.createElement('span');
    el.style.background = c; el.textContent = law;
    box.appendChild(el);
  }
}

// ------------------------------------------------------------------ controls
function setupControls() {
  const box = $('modes');
  for (const m of MODES) {
    const b = document.createElement('button');
    b.type = 'button'; b.textContent = m; b.dataset.mode = m; b.className = 'mode-btn';
    b.onclick = () => api('/api/mode', { rig: S.rig, mode: m }).then((j) => {
      say('mode-msg', j.ok ? j.message : failText(j), !!j.ok);
      if (!j.ok && !j.lost) loadModes();
    });
    box.appendChild(b);
  }
  const tap = (sign) => api('/api/tap', { rig: S.rig, dv: sign * parseFloat($('tap-dv').value) })
    .then((j) => say('tap-msg', j.ok ? j.message : failText(j), !!j.ok));
  $('tap-btn').onclick = () => tap(1);
  $('tap-neg').onclick = () => tap(-1);
  $('rec-name').value = 'run_' + new Date().toISOString().slice(0, 19).replace(/[-:]/g, '').replace('T', '_');
  $('rec-start').onclick = () => api('/api/record', { rig: S.rig, action: 'start', name: $('rec-name').value })
    .then((j) => say('rec-msg', j.ok ? `recording ${j.bag}` : failText(j), !!j.ok));
  $('rec-stop').onclick = () => api('/api/record', { rig: S.rig, action: 'stop' })
    .then((j) => { say('rec-msg', j.ok ? `${j.bag} closed` : failText(j), !!j.ok); loadBags(); });
  $('estop').addEventListener('pointerdown', estop);
  $('estop').addEventListener('keydown', (e) => { if (e.key === 'Enter' || e.key === ' ') estop(e); });
  document.addEventListener('keydown', (e) => { if (e.key === 'Escape') estop(e); });
  $('estop-clear').onclick = clearEstop;
  $('token-set').onclick = () => {
    S.token = $('token-input').value.trim();
    sessionStorage.setItem('rwpend-token', S.token);
    $('token-bar').hidden = true;
  };
}

// which modes the controller takes: 'law' only with a law file (the reason shown under the
// buttons when it has none)
function loadModes() {
  if (!S.rig) return;
  api('/api/modes?' + new URLSearchParams({ rig: S.rig })).then((j) => {
    if (j.ok === false) return;   // the controller not there yet: the buttons stay as they are
    const notes = [];
    for (const m of j.modes) {
      const b = document.querySelector(`#modes button[data-mode="${m.mode}"]`);
      if (!b) continue;
      b.disabled = m.usable === false;
      b.title = m.help;
      b.dataset.usable = String(m.usable);
      if (m.usable !== true) notes.push(`${m.mode}: ${m.help}`);
    }
    $('mode-note').textContent = notes.join(' ');
  });
}

// ------------------------------------------------------------------ gains panel
let tabsKey = '';

function drawNodeTabs(nodes) {
  const key = nodes.join(',');
  if (key === tabsKey) return;
  tabsKey = key;
  const box = $('node-tabs');
  box.textContent = '';
  for (const n of nodes) {
    const b = document.createElement('button');
    b.type = 'button'; b.textContent = n; b.dataset.node = n;
    b.classList.toggle('current', n === S.node);
    b.onclick = () => { S.node = n; tabsKey = ''; drawNodeTabs(nodes); loadParams(); };
    box.appendChild(b);
  }
}

function loadParams() {
  say('gains-msg', `reading ${S.node} ...`);
  api('/api/params?' + new URLSearchParams({ rig: S.rig, node: S.node })).then((j) => {
    if (j.ok === false) { say('gains-msg', j.lost ? j.error : reasonOf(j), false); return; }
    say('gains-msg', `${j.node}: ${j.fields.length} parameters (edit a value, Enter sets it on the node)`);
    drawFields(j.node, j.fields);
  });
}

function drawFields(node, fields) {
  const box = $('fields');
  box.textContent = '';
  const groups = new Map();
  for (const f of fields) {
    if (!groups.has(f.group)) groups.set(f.group, []);
    groups.get(f.group).push(f);
  }
  for (const [g, fs] of groups) {
    const det = document.createElement('details');
    det.open = fs.some((f) => !f.read_only);
    det.innerHTML = `<summary></summary><table></table>`;
    det.querySelector('summary').textContent = (g || 'general') + (det.open ? '' : ' (read-only)');
    const table = det.querySelector('table');
    if (fs.some((f) => f.designs)) {
      const pv = document.createElement('div');
      pv.className = 'preview'; pv.dataset.group = g; pv.textContent = 'design: edit a design value to see the gains it gives';
      det.insertBefore(pv, table);
    }
    for (const f of fs) table.appendChild(fieldRow(node, f, det));
    box.appendChild(det);
  }
}

function show(v) { return Array.isArray(v) ? JSON.stringify(v) : String(v); }

// a field as wide as its whole value (never cut)
function fitInput(input) { input.size = Math.max(8, input.value.length + 2); }

function fieldRow(node, f, det) {
  const tr = document.createElement('tr');
  tr.innerHTML = '<td></td><td></td><td class="range"></td><td><span class="field-msg"></span></td>';
  tr.children[0].textContent = f.name;
  tr.children[0].title = f.description;
  const input = document.createElement('input');
  input.dataset.param = f.name;
  input.dataset.node = node;
  if (f.type === 'bool') {
    input.type = 'checkbox'; input.checked = !!f.value;
  } else {
    input.type = 'text'; input.value = f.value_text !== undefined ? f.value_text : show(f.value);
    input.title = input.value;
    fitInput(input);
  }
  input.disabled = f.read_only;
  tr.children[1].appendChild(input);
  // the range as rwpend_console.panel.range_text writes it (6 significant digits, open ends)
  tr.children[2].textContent = [f.range_text, f.notes, f.read_only ? 'read-only' : ''].filter((x) => x).join('; ');
  const msg = tr.querySelector('.field-msg');
  msg.dataset.param = f.name;
  if (!f.read_only) {
    input.addEventListener('keydown', (e) => { if (e.key === 'Enter') commit(node, f, input, msg); });
    input.addEventListener('change', () => { if (f.type === 'bool') commit(node, f, input, msg); });
    input.addEventListener('input', () => {
      input.classList.add('pending');
      if (f.type !== 'bool') fitInput(input);
      if (f.designs) preview(node, f, input, det);
    });
  }
  return tr;
}

function rawValue(f, input) {
  if (f.type === 'bool') return input.checked;
  if (f.type.endsWith('_array')) { try { return JSON.parse(input.value); } catch (e) { return input.value; } }
  return input.value;
}

function commit(node, f, input, msg) {
  msg.textContent = 'setting ...'; msg.className = 'field-msg';
  api('/api/param', { rig: S.rig, node, name: f.name, value: rawValue(f, input) }).then((j) => {
    input.classList.remove('pending');
    if (j.value !== undefined && j.value !== null) {
      if (f.type === 'bool') input.checked = !!j.value;
      else { input.value = j.value_text !== undefined ? j.value_text : show(j.value); input.title = input.value; fitInput(input); }
    }
    msg.textContent = j.ok ? 'set' : failText(j);
    msg.className = 'field-msg ' + (j.ok ? 'ok' : 'refused');
    if (j.ok && f.designs) setTimeout(loadParams, 300);   // the node redesigned the gains
  });
}

let previewTimer = null;
let previewAsked = 0;      // the latest preview asked: only its answer is shown

function preview(node, f, input, det) {
  clearTimeout(previewTimer);
  previewTimer = setTimeout(() => {
    const mine = ++previewAsked;
    const changes = {};
    for (const i of det.querySelectorAll('input.pending')) {
      if (i.dataset.param.includes('.design.')) changes[i.dataset.param] = i.value;
    }
    const pv = det.querySelector('.preview');
    api('/api/design', { rig: S.rig, node, group: f.designs, changes }).then((j) => {
      // the console answers requests in parallel: an earlier edit's answer can come after a
      // later one's, and would show gains for values no longer typed
      if (mine !== previewAsked) return;
      if (!j.ok) { pv.textContent = 'design: ' + (j.lost ? j.error : reasonOf(j)); pv.className = 'preview unstable'; return; }
      const gains = Object.entries(j.gains).map(([k, v]) => `${k} = ${fmtNumber(Number(v))}`).join(', ');
      pv.textContent = `gives ${gains}` + (j.stable === null ? '' : `; ${j.reason}`) + ' (Enter applies it)';
      pv.className = 'preview' + (j.stable === false ? ' unstable' : '');
    });
  }, 250);
}

// ------------------------------------------------------------------ bags
function loadBags() {
  api('/api/bags').then((j) => {
    if (j.ok === false) { say('bags-msg', j.lost ? j.error : reasonOf(j), false); return; }
    $('bags-folder').textContent = j.folder;
    const body = document.querySelector('#bag-list tbody');
    body.textContent = '';
    for (const b of j.bags) body.appendChild(bagRow(b, j.analyses));
  });
}

function bagRow(b, analyses) {
  const tr = document.createElement('tr');
  tr.innerHTML = '<td></td><td></td><td></td><td></td><td><button type="button">analyze</button> <a href="#">plot</a></td>';
  tr.children[0].textContent = b.name;
  tr.children[1].textContent = b.duration_s !== undefined ? b.duration_s.toFixed(1) + ' s' : '';
  tr.children[2].textContent = b.messages || '';
  const running = analyses.running.includes(b.name);
  const err = analyses.errors[b.name];
  tr.children[3].textContent = running ? 'analysing ...' : err ? 'failed: ' + err
    : b.metrics ? Object.entries(b.metrics).map(([k, v]) => `${k} ${typeof v === 'number' ? fmtNumber(v, 3) : v}`).join(', ') : '';
  tr.querySelector('button').onclick = () => api('/api/analyze', { bag: b.name }).then((j) => {
    say('bags-msg', j.ok ? `analysing ${b.name}` : failText(j), !!j.ok);
    setTimeout(loadBags, 1500);
  });
  const a = tr.querySelector('a');
  a.hidden = !b.plot;
  a.onclick = (e) => { e.preventDefault(); const img = $('bag-plot'); img.src = '/api/plot?bag=' + encodeURIComponent(b.name) + '&t=' + Date.now(); img.hidden = false; };
  return tr;
}

// ------------------------------------------------------------------ lab experiments
let labRunning = null;

function loadLab() {
  api('/api/lab').then((j) => {
    if (j.ok === false) { say('lab-msg', j.lost ? j.error : reasonOf(j), false); return; }
    $('lab-folder').textContent = `${j.folder} (domain ${j.domain})`;
    if (j.loading) say('lab-msg', 'loading the list of experiments ...');
    else if ($('lab-msg').textContent.startsWith('loading')) say('lab-msg', '');
    const sel = $('lab-exp');
    if (!sel.options.length) {
      for (const e of j.experiments) {
        const o = document.createElement('option');
        o.value = e.number; o.textContent = `${e.number}. ${e.title} (Section ${e.section})`;
        o.title = 'needs: ' + e.needs.join('; ');
        sel.appendChild(o);
      }
    }
    labRunning = j.running;
    $('lab-stop').disabled = !j.running;
    const body = document.querySelector('#lab-runs tbody');
    body.textContent = '';
    for (const r of j.runs) body.appendChild(labRow(r));
    const shown = j.runs.find((r) => r.name === j.running) || j.runs[0];
    $('lab-log').textContent = shown ? shown.log : '';
  });
}

function labRow(r) {
  const tr = document.createElement('tr');
  tr.innerHTML = '<td></td><td></td><td></td><td><a target="_blank" rel="noopener">report</a></td>';
  tr.children[0].textContent = r.name;
  tr.children[1].textContent = r.running ? 'running ...' : r.passed === true ? 'all pass'
    : r.passed === false ? 'some FAIL' : r.exit !== null && r.exit !== undefined ? `ended (exit ${r.exit})` : r.error || '';
  tr.children[2].textContent = r.quantities.map((q) => `${q.pass ? 'pass' : 'FAIL'} ${q.name}`).join(', ');
  const a = tr.querySelector('a');
  a.hidden = !r.report;
  a.href = '/lab/report?run=' + encodeURIComponent(r.name);
  return tr;
}

function setupLab() {
  $('lab-run').onclick = () => api('/api/lab/run', { experiment: parseInt($('lab-exp').value, 10) })
    .then((j) => { say('lab-msg', j.ok ? `started ${j.run} (domain ${j.domain})` : failText(j), !!j.ok); loadLab(); });
  $('lab-stop').onclick = () => labRunning && api('/api/lab/stop', { run: labRunning })
    .then((j) => { say('lab-msg', j.ok ? `${j.run} stopped` : failText(j), !!j.ok); loadLab(); });
}

// ------------------------------------------------------------------ start
function start() {
  setupControls();
  drawLegend();
  // the first rig the console finds (or the one in the URL); asked again every second until
  // there is one: a page opened while the stack still starts finds it when it comes
  const findRig = () => api('/api/overview').then((j) => {
    if (j.lost) { setTimeout(findRig, 1000); return; }
    setLost(false);
    if (!S.rig && j.rigs && j.rigs.length) S.rig = j.rigs[0].id;
    if (!S.rig) {
      $('conn').textContent = 'no rig found yet: waiting for one';
      setTimeout(findRig, 1000);
      return;
    }
    connect();
    loadParams();
    loadModes();
    setInterval(loadModes, 10000);    // a controller restarted with another law.file
  }, () => setTimeout(findRig, 1000));
  findRig();
  api('/api/info').then((j) => {
    if (j.token_required && !S.token) $('token-bar').hidden = false;
    if (j.window_s) S.window = j.window_s;
  });
  loadBags();
  setInterval(loadBags, 10000);
  setupLab();
  loadLab();
  setInterval(loadLab, 3000);
  requestAnimationFrame(frame);
}

start();
