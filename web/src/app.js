// telehand console: the page telehand-web serves. One WebSocket (/ws) carries JSON frames
// both ways (docs/web.md "Protocol"); live and replay share one view.
import uPlot from 'uplot';
import { Hand } from './hand.js';

const $ = (id) => document.getElementById(id);
const deg = (r) => (r * 180) / Math.PI;
const fmt = (v, d = 1) => (Number.isFinite(v) ? v.toFixed(d) : '–');
const PLOT_S = 10;            // seconds of live history on the plots
const PLOT_MAX = 60 * PLOT_S; // points kept

// What tests read (window.telehand): the last frame shown and how often the plots moved.
const probe = {
  connected: false, mode: null, session: 0, sessions: [], lastHand: null, shownMcpDeg: null,
  handMcpDeg: null, plotUpdates: 0, handFrames: 0, events: [], errors: [], acks: [],
  replay: null, replayT: null, replayMcpDeg: null, records: [],
  replayHand: null, replayHandFrame: null,
  // The 3D model's angle of a joint now, degrees (tests compare it with the gateway's frames).
  jointDeg: (name) => deg(hand.byName.get(name)?.angle ?? NaN),
};
window.telehand = probe;

const hand = new Hand($('hand3d'));
hand.load('hand.urdf');  // the model the gateway's --hand names

let band = [12, 16];
let ws = null;
let rtt = null;          // ms, the browser <-> gateway round trip
let lastHand = null;     // the newest hand frame and when it came (performance.now())
let lastHandAt = 0;
let view = { mode: null, session: 0 };
let replay = null;       // the replay frame being shown
let replayHand = null;   // its hand: HandState frames the gateway computes from the record
let playing = false;
let replayPos = 0;       // seconds into the replay
let replaySpeed = 1;

// --- plots ---
const plotOpts = (title, series, yLabel, w) => ({
  title, width: w, height: 190, scales: { x: { time: false } },
  axes: [{ label: 's' }, { label: yLabel }],
  series: [{}, ...series], legend: { live: false },
});
function plotWidth() { return Math.max(300, ($('plots').clientWidth - 16) / 2); }
function drawCursor(u) {  // replay: where the timeline stands
  if (view.mode !== 'replay' || !replay) return;
  const x = u.valToPos(replayPos, 'x', true);
  const ctx = u.ctx;
  ctx.save();
  ctx.strokeStyle = '#1d2430';
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  ctx.moveTo(x, u.bbox.top);
  ctx.lineTo(x, u.bbox.top + u.bbox.height);
  ctx.stroke();
  ctx.restore();
}
const bandHooks = {
  draw: [drawCursor, (u) => {  // the reference band behind the force
    const ctx = u.ctx;
    const y0 = u.valToPos(band[1], 'y', true);
    const y1 = u.valToPos(band[0], 'y', true);
    ctx.save();
    ctx.fillStyle = 'rgba(42,138,58,0.12)';
    ctx.fillRect(u.bbox.left, y0, u.bbox.width, y1 - y0);
    ctx.restore();
  }],
};
const forcePlot = new uPlot({
  ...plotOpts('applied force vs band (N, reference scale)', [{ label: 'force', stroke: '#c0392b', width: 1.5 }], 'N', plotWidth()),
  scales: { x: { time: false }, y: { range: (u, min, max) => [0, Math.max(20, max + 1)] } },
  hooks: bandHooks,
}, [[], []], $('force-plot'));
const mcpPlot = new uPlot(plotOpts('MCP angles (deg)', [
  { label: 'α flexion', stroke: '#1f5fbf', width: 1.5 },
  { label: 'β abduction', stroke: '#2a8a3a', width: 1 },
  { label: 'γ axial', stroke: '#b8860b', width: 1 }], 'deg', plotWidth()), [[], [], [], []], $('mcp-plot'));
mcpPlot.hooks.draw = [drawCursor];
new ResizeObserver(() => {
  forcePlot.setSize({ width: plotWidth(), height: 190 });
  mcpPlot.setSize({ width: plotWidth(), height: 190 });
}).observe($('plots'));

const live = { t: [], f: [], a: [], b: [], g: [], t0: null };
function resetLive() { Object.assign(live, { t: [], f: [], a: [], b: [], g: [], t0: null }); }
let lastDraw = 0;
function drawLive(force) {
  const now = performance.now();
  if (!force && now - lastDraw < 30) return;  // at most about 30 redraws a second
  lastDraw = now;
  forcePlot.setData([live.t, live.f]);
  mcpPlot.setData([live.t, live.a, live.b, live.g]);
  probe.plotUpdates++;
}

// --- the figures beside the hand ---
function showFigures(mcp, force, extra = {}) {
  $('alpha').textContent = `${fmt(deg(mcp[0]), 2)}°`;
  $('beta').textContent = `${fmt(deg(mcp[1]), 2)}°`;
  $('gamma').textContent = `${fmt(deg(mcp[2]), 2)}°`;
  const inBand = force >= band[0] && force <= band[1];
  $('force').textContent = `${fmt(force, 2)} N`;
  $('force').className = inBand ? 'ok' : force > band[1] ? 'bad' : 'warn';
  for (const k of ['model', 'devhz', 'lost', 'overruns', 'handhz', 'seq']) {
    if (k in extra) $(k).textContent = extra[k];
  }
  probe.shownMcpDeg = deg(mcp[0]);
  probe.handMcpDeg = deg(hand.mcpFlexion() ?? NaN);
}

// --- the web of a massage: each pad's depth and force, and the surface ---
const MASSAGE_BAND = [8, 12];  // the paper's 10 ± 2 N, reference scale
let mobilizationBand = null;
function norm3(v) { return Math.hypot(v[0] || 0, v[1] || 0, v[2] || 0); }
function showWeb(w) {
  if (!mobilizationBand) { mobilizationBand = band; band = MASSAGE_BAND; }
  $('web').hidden = false;
  $('force-label').textContent = 'web force (mean of the pads)';
  const f = [norm3(w.force[0]), norm3(w.force[1])];
  $('web-thumb').textContent = `${fmt(w.depth[0] * 1000, 1)} mm, ${fmt(f[0], 1)} N`;
  $('web-index').textContent = `${fmt(w.depth[1] * 1000, 1)} mm, ${fmt(f[1], 1)} N`;
  const c = $('web-grid');
  const g = c.getContext('2d');
  const n = w.grid.length;
  const cell = c.width / n;
  let deepest = 0;
  for (const row of w.grid) for (const v of row) deepest = Math.max(deepest, Math.abs(v));
  const scale = Math.max(deepest, 0.005);  // 5 mm at least: a light touch stays light
  for (let i = 0; i < n; i++) {
    for (let j = 0; j < n; j++) {
      const u = Math.min(1, Math.abs(w.grid[i][j]) / scale);
      const shade = Math.round(235 - 175 * u);
      g.fillStyle = `rgb(${shade},${Math.round(shade * 0.85)},${Math.round(shade * 0.8)})`;
      // rows along the web's x drawn left to right, its y upwards
      g.fillRect(i * cell, c.height - (j + 1) * cell, cell - 1, cell - 1);
    }
  }
  probe.web = { depth: w.depth, force: f, deepest };
  return (f[0] + f[1]) / 2;
}
function hideWeb() {
  if (mobilizationBand) { band = mobilizationBand; mobilizationBand = null; }
  $('web').hidden = true;
  $('force-label').textContent = 'applied force';
  probe.web = null;
}

// --- the connection ---
function send(msg) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(msg));
}
let backoff = 500;
let openedAt = 0;
function connect() {
  ws = new WebSocket(`${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws`);
  ws.onopen = () => {
    openedAt = Date.now();
    probe.connected = true;
    $('link').textContent = 'connected';
    $('link').className = 'ok';
    send({ op: 'records' });
    if (view.mode === 'live') send({ op: 'watch', session: view.session });
  };
  ws.onclose = (e) => {
    probe.connected = false;
    $('link').textContent = `disconnected${e.reason ? `: ${e.reason}` : ''}; retrying`;
    $('link').className = 'bad';
    // The wait starts short again only after a connection that held: a gateway that closes
    // each connection at once (a reply over its queue bound, a full house) is not asked
    // twice a second.
    if (openedAt && Date.now() - openedAt > 10000) backoff = 500;
    openedAt = 0;
    setTimeout(connect, backoff);
    backoff = Math.min(backoff * 2, 10000);
  };
  ws.onmessage = (e) => {
    let m;
    try { m = JSON.parse(e.data); } catch { return; }
    const h = handlers[m.type];
    if (h) h(m);
  };
}
setInterval(() => send({ op: 'ping', t: performance.now() }), 2000);

const handlers = {
  hello(m) {
    if (mobilizationBand) mobilizationBand = m.band; else band = m.band;
    hand.setDofs(m.dofs);
  },
  pong(m) {
    rtt = performance.now() - m.t;
    $('rtt').textContent = `rtt ${fmt(rtt, 0)} ms`;
  },
  sessions(m) {
    // A session that ended since the last list is in the store now: list the records again.
    const before = new Map(probe.sessions.map((s) => [s.id, s.state]));
    if (m.sessions.some((s) => s.state === 'closed' && before.get(s.id) !== 'closed' && before.size)) {
      send({ op: 'records' });
    }
    probe.sessions = m.sessions;
    $('server').textContent = m.server_matched ? '' : 'no telehand-server seen on this domain and partition';
    // Rows are updated in place (a button under the pointer stays the same element).
    const tb = $('sessions').tBodies[0];
    const rows = new Map([...tb.rows].map((tr) => [+tr.dataset.session, tr]));
    m.sessions.forEach((s, i) => {
      let tr = rows.get(s.id);
      if (!tr) {
        tr = document.createElement('tr');
        tr.dataset.session = s.id;
        tr.innerHTML = '<td></td><td></td><td></td><td></td><td></td><td></td>'
          + '<td><button class="watch">watch</button></td>';
      }
      rows.delete(s.id);
      if (tb.rows[i] !== tr) tb.insertBefore(tr, tb.rows[i] || null);
      tr.className = view.mode === 'live' && view.session === s.id ? 'selected' : '';
      const age = s.age_ms;
      const health = s.state !== 'active' ? '–'
        : age === undefined ? 'no hand yet'
        : `${s.hand_hz}/s ${fmt(s.delay_ms, 0)} ms${s.dev_lost ? ` lost ${s.dev_lost}` : ''}`
          + `${s.overruns ? ` overruns ${s.overruns}` : ''}`;
      const cls = s.state !== 'active' ? 'muted' : age === undefined || age > 1000 ? 'bad'
        : s.dev_lost > 0 || s.delay_ms > 300 ? 'warn' : 'ok';
      const cells = [String(s.id), s.state, s.user, s.case, s.mode, health];
      cells.forEach((text, k) => { if (tr.cells[k].textContent !== text) tr.cells[k].textContent = text; });
      tr.cells[5].className = cls;
    });
    for (const tr of rows.values()) tr.remove();
    showTakeover();
  },
  records(m) {
    probe.records = m.sessions;
    const tb = $('records').tBodies[0];
    const older = (m.total || 0) - m.sessions.length;
    $('records-more').textContent =
      older > 0 ? `the newest ${m.sessions.length} of ${m.total}; telehand-records list shows every one` : '';
    tb.replaceChildren(...m.sessions.slice().reverse().map((s) => {
      const tr = document.createElement('tr');
      tr.dataset.session = s.id;
      // Every cell as text: a record's strings are not the page's markup.
      for (const v of [s.id, s.user, s.case, s.state, s.samples, '']) {
        const td = document.createElement('td');
        td.textContent = v;
        tr.append(td);
      }
      const b = document.createElement('button');
      b.textContent = 'replay';
      b.className = 'replay';
      tr.children[5].append(b);
      return tr;
    }));
  },
  watching(m) {
    $('title').textContent = `Live: session ${m.session}`;
  },
  hand(m) {
    if (view.mode !== 'live' || m.session !== view.session) return;
    lastHand = m;
    lastHandAt = performance.now();
    probe.handFrames++;
    probe.lastHand = {
      seq: m.seq, mcp: m.mcp, joints: m.joints, t_ms: m.t_ms, force: m.force, overruns: m.overruns,
    };
    hand.pose(m);
    // A massage: the plot and the figure are the web's force on the pads, against 10 ± 2 N.
    const press = m.web ? showWeb(m.web) : m.force;
    if (live.t0 === null) live.t0 = m.t_ms;
    live.t.push((m.t_ms - live.t0) / 1000);
    live.f.push(press);
    probe.plotSamples = (probe.plotSamples || 0) + 1;
    live.a.push(deg(m.mcp[0]));
    live.b.push(deg(m.mcp[1]));
    live.g.push(deg(m.mcp[2]));
    if (live.t.length > PLOT_MAX) for (const k of ['t', 'f', 'a', 'b', 'g']) live[k].shift();
    drawLive(false);
    showFigures(m.mcp, press, {
      model: `v${m.model}`, devhz: `${fmt(m.dev_hz, 0)} /s`, lost: `${m.dev_lost}`,
      overruns: `${m.overruns}`,
      seq: `${m.seq} (device ${m.dev_seq})`,
    });
  },
  event(m) {
    if (view.mode !== 'live' || (m.session !== view.session && m.session !== 0)) return;
    addEvent(new Date(m.t_ms).toLocaleTimeString(), m.kind, m.text);
  },
  ack(m) {
    probe.acks.push(m);
    // The typed mark goes only once the gateway took it (a refused one stays to be edited).
    if (m.op === 'mark' && pendingMark !== null && $('mark-text').value.trim() === pendingMark) {
      $('mark-text').value = '';
    }
    if (m.op === 'mark') pendingMark = null;
    $(m.op === 'takeover' ? 'takeover-status' : 'mark-status').textContent = `sent: ${m.text}`;
  },
  error(m) {
    probe.errors.push(m);
    $(lastOp === 'takeover' ? 'takeover-status' : 'mark-status').textContent = `${m.code}: ${m.message}`;
  },
  replay(m) {
    replay = m;
    replayHand = { frames: [], t: [], done: false, ok: true, cut: false, hz: 0, message: '' };
    probe.replayHand = { frames: 0, done: false };
    $('replay-hand').textContent = 'hand: computing…';
    $('replay-hand').className = 'muted';
    probe.replay = { session: m.session, points: m.points, duration: m.t[m.t.length - 1] || 0 };
    $('title').textContent = `Replay: session ${m.session} (${m.info.user}, ${m.info.case}, `
      + `${m.info.mode}), ${fmt(probe.replay.duration, 1)} s`;
    $('replay-bar').hidden = false;
    hand.rest();
    $('timeline').max = probe.replay.duration;
    $('events').replaceChildren();
    for (const e of m.events) addEvent(`${fmt((e.t_ms - m.t0_ms) / 1000, 1)} s`, e.kind, e.text);
    forcePlot.setData([m.t, m.force]);
    mcpPlot.setData([m.t, m.alpha.map(deg), m.beta.map(deg), m.gamma.map(deg)]);
    probe.plotUpdates++;
    seek(0);
  },
  // The replay's hand, as the gateway computes it with the server's own hand code: chunks of
  // frames shaped as live hand frames, then how it ended.
  replay_hand(m) {
    if (!replay || !replayHand || view.mode !== 'replay' || m.session !== replay.session) return;
    if (m.frames.length && m.first !== replayHand.frames.length) return;  // not this replay's
    for (const f of m.frames) {
      replayHand.frames.push(f);
      replayHand.t.push((f.dev_t_ms - replay.t0_ms) / 1000);
    }
    probe.replayHand = { frames: replayHand.frames.length, done: false, done_s: m.done_s };
    $('replay-hand').textContent = m.queued ? 'hand: waiting for the gateway…'
      : `hand: ${fmt(m.done_s, 1)} of ${fmt(probe.replay.duration, 1)} s…`;
    if (!playing) seek(replayPos);
  },
  replay_hand_end(m) {
    if (!replay || !replayHand || view.mode !== 'replay' || m.session !== replay.session) return;
    Object.assign(replayHand, { done: true, ok: m.ok, cut: m.cut, hz: m.hz, message: m.message });
    probe.replayHand = {
      frames: replayHand.frames.length, done: true, ok: m.ok, cut: m.cut, hz: m.hz,
      simulated_s: m.simulated_s, compute_s: m.compute_s, message: m.message,
    };
    $('replay-hand').textContent = m.ok && !m.cut ? `hand: ${m.frames} frames at ${m.hz}/s` : m.message;
    $('replay-hand').title = m.message;
    $('replay-hand').className = !m.ok ? 'bad' : m.cut ? 'warn' : 'muted';
    if (!playing) seek(replayPos);
  },
};

const kMaxEvents = 500;  // the newest; a flood of events does not grow the page without end
function addEvent(when, kind, text) {
  probe.events.push({ kind, text });
  if (probe.events.length > kMaxEvents) probe.events.splice(0, probe.events.length - kMaxEvents);
  const li = document.createElement('li');
  li.className = kind;
  li.textContent = `${when}  ${kind}  ${text}`;
  const box = $('events');
  box.append(li);
  while (box.children.length > kMaxEvents) box.firstElementChild.remove();
  box.scrollTop = box.scrollHeight;  // this list only, never the page
}

function watch(id) {
  view = { mode: 'live', session: id };
  probe.mode = 'live';
  probe.session = id;
  playing = false;
  replay = null;
  replayHand = null;
  $('replay-bar').hidden = true;
  $('events').replaceChildren();
  resetLive();
  hideWeb();
  showTakeover();
  drawLive(true);
  $('title').textContent = `Live: session ${id}`;
  send({ op: 'watch', session: id });
}

function startReplay(id) {
  view = { mode: 'replay', session: id };
  probe.mode = 'replay';
  probe.session = id;
  send({ op: 'watch', session: 0 });  // the live stream stops
  hideWeb();
  $('title').textContent = `Replay: loading session ${id}…`;
  send({ op: 'replay', session: id });
}

// --- replay ---
function indexAt(t) {  // the last sample at or before t
  const ts = replay.t;
  let lo = 0;
  let hi = ts.length - 1;
  while (lo < hi) {
    const mid = (lo + hi + 1) >> 1;
    if (ts[mid] <= t) lo = mid; else hi = mid - 1;
  }
  return lo;
}
function handFrameAt(t) {  // the replay's hand frame nearest t, if its hand reaches t
  const ts = replayHand ? replayHand.t : [];
  if (!ts.length) return null;
  let lo = 0;
  let hi = ts.length - 1;
  while (lo < hi) {  // the last frame at or before t
    const mid = (lo + hi + 1) >> 1;
    if (ts[mid] <= t) lo = mid; else hi = mid - 1;
  }
  if (lo + 1 < ts.length && ts[lo + 1] - t < t - ts[lo]) lo++;
  const gap = ts.length > 1 ? ts[1] - ts[0] : 0.02;
  return Math.abs(ts[lo] - t) <= gap ? { f: replayHand.frames[lo], t: ts[lo] } : null;
}
function seek(t) {
  if (!replay || !replay.t.length) return;
  replayPos = Math.max(0, Math.min(t, replay.t[replay.t.length - 1]));
  const i = indexAt(replayPos);
  const mcp = [replay.alpha[i], replay.beta[i], replay.gamma[i]];
  // The whole hand from the frame nearest this moment, as live; where the hand has not been
  // computed (yet, or past a bound), the index MCP from the record's proxy angles.
  const hf = handFrameAt(replayPos);
  if (hf) {
    hand.pose(hf.f);
  } else {
    hand.rest();
    hand.pose({ mcp });
  }
  probe.replayHandFrame = hf ? { dev_seq: hf.f.dev_seq, t: hf.t, joints: hf.f.joints } : null;
  showFigures(mcp, replay.force[i], {
    seq: `${replay.seq[i]}`, model: hf ? `v${hf.f.model}` : '–', devhz: '–', lost: '–', handhz: '–',
  });
  $('timeline').value = replayPos;
  forcePlot.redraw(false, false);
  mcpPlot.redraw(false, false);
  $('replay-time').textContent = `${fmt(replayPos, 2)} s`;
  probe.replayT = replay.t[i];
  probe.replayMcpDeg = deg(mcp[0]);
  probe.replaySeq = replay.seq[i];
}
window.telehandSeek = seek;
$('timeline').addEventListener('input', (e) => { playing = false; $('play').textContent = '▶'; seek(+e.target.value); });
$('play').onclick = () => {
  playing = !playing;
  $('play').textContent = playing ? '❚❚' : '▶';
  if (playing && replay && replayPos >= replay.t[replay.t.length - 1]) seek(0);
};
$('speed').onchange = (e) => { replaySpeed = +e.target.value; };
let lastTick = performance.now();
function tick(now) {
  const dt = (now - lastTick) / 1000;
  lastTick = now;
  if (playing && replay) {
    seek(replayPos + dt * replaySpeed);
    if (replayPos >= replay.t[replay.t.length - 1]) { playing = false; $('play').textContent = '▶'; }
  }
  requestAnimationFrame(tick);
}
requestAnimationFrame(tick);

// --- the view's age, live ---
const handTimes = [];
setInterval(() => {
  if (view.mode !== 'live' || !lastHand) {
    $('age').textContent = view.mode === 'replay' ? 'replay' : 'age –';
    $('age').className = 'muted';
    return;
  }
  // DDS delay at the gateway + half the round trip to it + time since the frame came.
  const sinceMs = performance.now() - lastHandAt;
  const ageMs = (lastHand.rx_ms - lastHand.t_ms) + (rtt ?? 0) / 2 + sinceMs;
  $('age').textContent = `age ${fmt(ageMs, 0)} ms`;
  $('age').className = ageMs > 1500 ? 'bad' : ageMs > 400 ? 'warn' : 'ok';
  probe.ageMs = ageMs;
  handTimes.push(probe.handFrames);
  if (handTimes.length > 4) handTimes.shift();
  if (handTimes.length === 4) $('handhz').textContent = `${fmt((handTimes[3] - handTimes[0]) / 0.75, 0)} /s`;
}, 250);

// --- take-over: a lesson run that allows it follows the supervisor's own MF-2 session ---
let lastOp = null;
let pendingMark = null;  // the mark sent, cleared from the input when the gateway takes it
const kMarkBytes = 127;
function showTakeover() {
  const sessions = probe.sessions || [];
  const me = sessions.find((s) => s.id === view.session);
  const allowed = view.mode === 'live' && me && me.takeover;
  $('takeover-form').hidden = !allowed;
  if (!allowed) return;
  const sel = $('takeover-from');
  const ids = sessions.filter((s) => s.state === 'active' && s.mode === 'mobilization' && s.id !== view.session);
  const want = ids.map((s) => `${s.id}`).join(',');
  if (sel.dataset.ids === want) return;  // the choice under the pointer stays
  sel.dataset.ids = want;
  const keep = sel.value;
  sel.replaceChildren(...ids.map((s) => {
    const o = document.createElement('option');
    o.value = s.id;
    o.textContent = `session ${s.id} (${s.user})`;
    return o;
  }));
  if (ids.some((s) => `${s.id}` === keep)) sel.value = keep;
  $('takeover-send').disabled = ids.length === 0;
  if (!ids.length) $('takeover-status').textContent = 'open a mobilization at your MF-2 first';
}
$('takeover-form').addEventListener('submit', (e) => {
  e.preventDefault();
  const from = +$('takeover-from').value;
  if (!from) return;
  lastOp = 'takeover';
  send({ op: 'takeover', session: view.session, from });
  $('takeover-status').textContent = 'sending…';
});
$('takeover-back').onclick = () => {
  lastOp = 'takeover';
  send({ op: 'takeover', session: view.session, from: 0 });
  $('takeover-status').textContent = 'sending…';
};

// --- marks ---
$('mark-form').addEventListener('submit', (e) => {
  e.preventDefault();
  const text = $('mark-text').value.trim();
  if (!text || !view.session) {
    $('mark-status').textContent = view.session ? 'type a mark first' : 'watch or replay a session first';
    return;
  }
  const msg = { op: 'mark', session: view.session, text };
  if (view.mode === 'replay') msg.at_s = replayPos;
  // The gateway takes 127 bytes of UTF-8, a replay's "at 123.4 s: " included.
  const prefix = view.mode === 'replay' ? `at ${replayPos.toFixed(1)} s: ` : '';
  const bytes = new TextEncoder().encode(prefix + text).length;
  if (bytes > kMarkBytes) {
    $('mark-status').textContent = `too long: ${bytes} bytes of ${kMarkBytes}${prefix ? ' with the replay time' : ''}; shorten it`;
    return;
  }
  lastOp = 'mark';
  pendingMark = text;
  send(msg);
  $('mark-status').textContent = 'sending…';
});
// The lists are rebuilt as frames come: one handler per table, not per button.
$('sessions').addEventListener('click', (e) => {
  const tr = e.target.closest('button.watch') && e.target.closest('tr');
  if (tr) watch(+tr.dataset.session);
});
$('records').addEventListener('click', (e) => {
  const tr = e.target.closest('button.replay') && e.target.closest('tr');
  if (tr) startReplay(+tr.dataset.session);
});
$('refresh-records').onclick = () => send({ op: 'records' });

// Direct links: ?watch=ID or ?replay=ID.
const params = new URLSearchParams(location.search);
connect();
if (params.get('watch')) watch(+params.get('watch'));
if (params.get('replay')) {
  const id = +params.get('replay');
  const go = () => (ws.readyState === WebSocket.OPEN ? startReplay(id) : setTimeout(go, 100));
  go();
}
