// The web console in a browser: telehand-server, telehand-client (simulated MF-2),
// telehand-web and a HandState tap run as processes (loopback DDS, a partition of their own,
// stopped by PID); headless Chromium (Debian's) driven by playwright-core opens the page and
// checks that the session appears, the hand's MCP angle follows HandState within 0.5 deg,
// the force plot moves at >= 20 updates/s, a mark typed in the page reaches the record, and
// a replay of the finished session scrubs to a given time and shows that sample's angle, and
// the whole 3D hand there (a non-MCP joint) as the gateway's replayed hand frame has it.
// Screenshots of live and replay go to --artifacts.
//
// node console_test.mjs --build DIR --deploy DIR --artifacts DIR [--chromium PATH]
import { spawn, execFileSync } from 'node:child_process';
import net from 'node:net';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { createRequire } from 'node:module';

const args = Object.fromEntries(process.argv.slice(2).reduce((acc, a, i, all) => {
  if (a.startsWith('--')) acc.push([a.slice(2), all[i + 1]]);
  return acc;
}, []));
const build = path.resolve(args.build);
const deploy = path.resolve(args.deploy);
const artifacts = path.resolve(args.artifacts);
const chromiumPath = args.chromium || '/usr/bin/chromium';
const webDir = path.resolve(args.web || path.join(deploy, '..', 'web'));

if (!fs.existsSync(chromiumPath)) {
  console.log(`SKIP: no Chromium at ${chromiumPath} (deploy/setup.sh installs Debian's chromium)`);
  process.exit(77);  // ctest SKIP_RETURN_CODE
}
const require = createRequire(path.join(webDir, 'package.json'));
const { chromium } = require('playwright-core');

fs.mkdirSync(artifacts, { recursive: true });
const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'telehand-web-test-'));
const partition = `webtest-${process.pid}`;
const dds = ['--dds-config', path.join(deploy, 'cyclonedds/loopback.xml'), '--partition', partition,
             '--insecure'];
const db = path.join(dir, 'records.db');
const children = [];
let failures = 0;
let passes = 0;

function start(name, bin, argv) {
  const out = fs.openSync(path.join(dir, `${name}.log`), 'w');
  const p = spawn(bin, argv, { stdio: ['ignore', out, out] });
  p.logName = name;
  p.exited = new Promise((resolve) => p.on('exit', (code, sig) => resolve(code ?? 128)));
  children.push(p);
  return p;
}
const log = (name) => fs.readFileSync(path.join(dir, `${name}.log`), 'utf8');
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
function check(ok, what, detail = '') {
  if (ok) { passes++; console.log(`ok   ${what} (${new Date().toISOString().slice(11, 23)})`); } else { failures++; console.log(`FAIL ${what} ${detail}`); }
  return ok;
}
async function stopAll() {
  for (const p of children) if (p.exitCode === null && p.signalCode === null) p.kill('SIGTERM');
  await Promise.race([Promise.all(children.map((p) => p.exited)), sleep(15000)]);
  for (const p of children) if (p.exitCode === null && p.signalCode === null) p.kill('SIGKILL');
}
async function waitFor(page, fn, arg, timeout, what) {
  try {
    return await page.waitForFunction(fn, arg, { timeout, polling: 100 });
  } catch (e) {
    const state = await page.evaluate(() => JSON.stringify({ ...window.telehand, sessions: window.telehand.sessions.length }))
      .catch(() => '?');
    throw new Error(`timed out waiting for ${what}; page: ${state.slice(0, 600)}`);
  }
}

// A delay line between a browser and the gateway: each direction `oneWayMs` late.
function delayLine(listenPort, targetPort, oneWayMs) {
  const srv = net.createServer((a) => {
    const b = net.connect(targetPort, '127.0.0.1');
    const pipe = (from, to) => {
      from.on('data', (d) => setTimeout(() => to.writable && to.write(d), oneWayMs));
      from.on('end', () => setTimeout(() => to.end(), oneWayMs));
      from.on('error', () => to.destroy());
    };
    pipe(a, b);
    pipe(b, a);
  });
  srv.listen(listenPort, '127.0.0.1');
  return srv;
}

let browser;
let delay;
try {
  const server = start('server', path.join(build, 'server/telehand-server'), ['--db', db, '--seconds', '150', ...dds]);
  const web = start('web', path.join(build, 'server/telehand-web'),
    ['--db', db, '--bind', '127.0.0.1:0', '--seconds', '150', ...dds]);
  const tap = start('tap', path.join(build, 'tests/telehand-test-handtap'), ['--seconds', '150', ...dds]);
  let port = 0;  // the system chose it; the gateway says which
  for (let i = 0; i < 100 && !port; ++i) {
    await sleep(100);
    if (web.exitCode !== null) throw new Error(`telehand-web exited: ${log('web')}`);
    port = +(log('web').match(/serving http:\/\/127\.0\.0\.1:(\d+)\//)?.[1] ?? 0);
  }
  if (!port) throw new Error(`telehand-web did not say where it serves: ${log('web')}`);
  browser = await chromium.launch({
    executablePath: chromiumPath,
    args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
  });
  const page = await browser.newPage({ viewport: { width: 1400, height: 900 } });
  page.on('console', (m) => { if (m.type() === 'error') console.log(`page: ${m.text()}`); });
  page.on('pageerror', (e) => console.log(`page error: ${e.message}`));
  await page.goto(`http://127.0.0.1:${port}/`);
  await waitFor(page, () => window.telehand.connected, null, 10000, 'the page connected');
  // A second supervisor 1 s of round trip away from the gateway.
  delay = delayLine(0, port, 500);
  await new Promise((r) => delay.on('listening', r));
  const farPort = delay.address().port;
  const far = await browser.newPage({ viewport: { width: 1400, height: 900 } });
  await far.goto(`http://127.0.0.1:${farPort}/`);
  await waitFor(far, () => window.telehand.connected, null, 15000, 'the far page connected');
  // --no-fault-stop: on a busy machine the simulated loop can overrun into a rendering fault
  // that would end the session early; this test is about the console, not the loop.
  // Long enough for every live check however slowly a busy machine renders the pages (a fixed
  // 30 s once ran out before the far page was measured); ended with Ctrl-C once they are done.
  const client = start('client', path.join(build, 'client/telehand-client'), ['--seconds', '120', '-q', '--no-fault-stop', ...dds]);

  // The session appears, active.
  const handle = await waitFor(page, () => (window.telehand.sessions || []).find((s) => s.state === 'active')?.id,
    null, 20000, 'an active session in the list');
  const session = await handle.jsonValue();
  check(session > 0, `session ${session} appears in the list`);
  console.log(`clicking watch at ${new Date().toISOString().slice(11, 23)}`);
  await page.click(`#sessions tr[data-session="${session}"] button.watch`);
  console.log(`clicked at ${new Date().toISOString().slice(11, 23)}`);
  await waitFor(page, () => window.telehand.handFrames > 10, null, 10000, 'hand frames');
  await far.click(`#sessions tr[data-session="${session}"] button.watch`);

  // A mark typed in the page.
  const markText = `web mark ${process.pid}`;
  await page.fill('#mark-text', markText);
  await page.press('#mark-text', 'Enter');
  await waitFor(page, (t) => window.telehand.acks.some((a) => a.text === t), markText, 10000, 'the mark acknowledged');
  const seen = await page.waitForFunction((t) => window.telehand.events.some((e) => e.kind === 'mark' && e.text.startsWith(t)),
    markText, { timeout: 10000 }).then(() => true, () => false);
  check(seen, 'the mark comes back as a session event');
  const toStudent = await (async () => {
    for (let i = 0; i < 50; ++i) {
      if (log('client').includes(`server: mark: ${markText}`)) return true;
      await sleep(100);
    }
    return false;
  })();
  check(toStudent, "the student's client shows the mark");

  // The MCP angle, sampled while it moves, and the plot's update rate.
  const samples = [];
  const u0 = await page.evaluate(() => [window.telehand.plotUpdates, performance.now(), window.telehand.plotSamples]);
  for (let i = 0; i < 25; ++i) {
    samples.push(await page.evaluate(() => ({
      seq: window.telehand.lastHand.seq, shown: window.telehand.shownMcpDeg,
      model3d: window.telehand.handMcpDeg, age: window.telehand.ageMs })));
    await sleep(80);
  }
  const u1 = await page.evaluate(() => [window.telehand.plotUpdates, performance.now(), window.telehand.plotSamples]);
  const span = (u1[1] - u0[1]) / 1000;
  const plotRate = (u1[2] - u0[2]) / span;
  const redrawRate = (u1[0] - u0[0]) / span;
  check(plotRate >= 20, `force plot receives ${plotRate.toFixed(1)} updates/s (>= 20; redrawn ${redrawRate.toFixed(1)}/s)`);
  await page.screenshot({ path: path.join(artifacts, 'console-live.png') });

  // The far page, over the 1 s delay line: it follows, and says how old its view is.
  await waitFor(far, () => window.telehand.handFrames > 10 && window.telehand.ageMs > 0, null, 15000, 'far hand frames');
  const f0 = await far.evaluate(() => [window.telehand.handFrames, performance.now()]);
  await sleep(2000);
  const f1 = await far.evaluate(() => [window.telehand.handFrames, performance.now(), window.telehand.ageMs,
    document.getElementById('age').textContent, document.getElementById('rtt').textContent]);
  const farRate = (f1[0] - f0[0]) / ((f1[1] - f0[1]) / 1000);
  // It keeps following (the rate itself belongs to the benchmark: two pages share a busy CPU).
  check(farRate >= 5, `over a 1 s round trip the page keeps following: ${farRate.toFixed(1)} hand frames/s`);
  check(f1[2] >= 500 && f1[2] < 3000, `and shows its view's age: "${f1[3]}" (${f1[4]})`);
  await far.screenshot({ path: path.join(artifacts, 'console-live-1s-rtt.png') });
  await far.close();

  // The student ends the session (Ctrl-C); the page says so.
  client.kill('SIGINT');
  const crc = await Promise.race([client.exited, sleep(40000).then(() => null)]);
  check(crc === 0, `client ended by Ctrl-C (exit ${crc})`);
  await waitFor(page, (id) => window.telehand.sessions.find((s) => s.id === id)?.state === 'closed',
    session, 15000, 'the session closed in the list');
  tap.kill('SIGTERM');
  await tap.exited;

  // The angle against HandState, sample by sample (same seq).
  const truth = new Map();
  for (const line of log('tap').split('\n')) {
    const f = line.split(' ');
    if (f[0] === 'hand' && +f[1] === session) truth.set(+f[2], [+f[3], +f[4]]);
  }
  let compared = 0;
  let worst = 0;
  let worst3d = 0;
  for (const s of samples) {
    const t = truth.get(s.seq);
    if (!t) continue;
    ++compared;
    worst = Math.max(worst, Math.abs(s.shown - (t[0] * 180) / Math.PI));
    worst3d = Math.max(worst3d, Math.abs(s.model3d - (t[1] * 180) / Math.PI));
  }
  const moved = Math.max(...samples.map((s) => s.shown)) - Math.min(...samples.map((s) => s.shown));
  check(compared >= 10, `${compared} page samples matched to HandState by seq`);
  check(worst <= 0.5, `shown MCP angle within ${worst.toFixed(4)} deg of HandState (<= 0.5; it moved ${moved.toFixed(1)} deg)`);
  check(worst3d <= 0.5, `3D hand's MCP flexion joint within ${worst3d.toFixed(4)} deg of HandState's joint`);
  console.log(`view age while live: ${samples.map((s) => s.age?.toFixed(0)).join(' ')} ms`);

  // The mark is in the record.
  const records = path.join(build, 'server/telehand-records');
  const shown = execFileSync(records, ['--db', db, 'show', String(session)], { encoding: 'utf8' });
  check(shown.includes(markText), 'telehand-records show lists the mark', shown);

  // A massage: the page shows the web, each pad's depth and the web's force on it and the
  // surface, and judges the force against the massage's 10 ± 2 N.
  const massage = start('massage', path.join(build, 'client/telehand-client'),
    ['--technique', 'massage', '--seconds', '8', '-q', '--no-fault-stop', ...dds]);
  const mHandle = await waitFor(page, (prev) => (window.telehand.sessions || [])
    .find((s) => s.state === 'active' && s.id > prev)?.id, session, 20000, 'the massage in the list');
  const mSession = await mHandle.jsonValue();
  await page.click(`#sessions tr[data-session="${mSession}"] button.watch`);
  await waitFor(page, () => window.telehand.web && window.telehand.web.depth.every((d) => d > 0.001),
    null, 15000, 'both pads in the web');
  await sleep(1000);  // the press settles (the clinician ramps up over 0.5 s)
  const w = await page.evaluate(() => ({ web: window.telehand.web, hidden: document.getElementById('web').hidden,
    label: document.getElementById('force-label').textContent, force: document.getElementById('force').textContent,
    cls: document.getElementById('force').className, thumb: document.getElementById('web-thumb').textContent }));
  check(!w.hidden && w.label.startsWith('web force'), `the web panel shows for a massage (${w.label}: ${w.force}, thumb ${w.thumb})`);
  check(w.web.depth.every((d) => d > 0.001 && d < 0.02) && w.web.force.every((f) => f > 5 && f < 15)
    && w.web.deepest > 0.001,
    `both pads pressed in: ${w.web.depth.map((d) => (d * 1000).toFixed(1)).join(' and ')} mm, `
    + `${w.web.force.map((f) => f.toFixed(1)).join(' and ')} N, the surface ${(w.web.deepest * 1000).toFixed(1)} mm deep`);
  await page.screenshot({ path: path.join(artifacts, 'console-massage.png') });
  const mrc = await Promise.race([massage.exited, sleep(30000).then(() => null)]);
  check(mrc !== null, `massage client finished (exit ${mrc})`);

  // Replay: scrub to a time, the angle shown is that sample's.
  await page.click('#refresh-records');
  await page.waitForSelector(`#records tr[data-session="${session}"] button.replay`, { timeout: 10000 });
  await page.click(`#records tr[data-session="${session}"] button.replay`);
  await waitFor(page, (id) => window.telehand.replay?.session === id, session, 20000, 'the replay');
  const duration = await page.evaluate(() => window.telehand.replay.duration);
  // The time the timeline holds: a range input snaps its value to its step (1 ms), so the
  // scrub is to the snapped time (to 0.6 of a 7.941 s record the slider goes to 4.765 s).
  const target = await page.evaluate((t) => {
    const tl = document.getElementById('timeline');
    tl.value = t;
    tl.dispatchEvent(new Event('input'));
    return +tl.value;
  }, Math.min(5.0, duration * 0.6));
  const r = await page.evaluate(() => ({ t: window.telehand.replayT, seq: window.telehand.replaySeq,
    mcp: window.telehand.replayMcpDeg, shown: document.getElementById('alpha').textContent }));
  const csvPath = path.join(dir, 'session.csv');
  execFileSync(records, ['--db', db, 'export', String(session), '-o', csvPath], { stdio: 'ignore' });
  const rows = fs.readFileSync(csvPath, 'utf8').trim().split('\n');
  const head = rows[0].split(',');
  const iSeq = head.indexOf('seq');
  const iT = head.indexOf('t_ns');
  const iA = head.indexOf('alpha_rad');
  const t0 = +rows[1].split(',')[iT];
  const row = rows.slice(1).map((l) => l.split(',')).find((f) => +f[iSeq] === r.seq);
  check(!!row, `replay sample seq ${r.seq} is in the record`);
  if (row) {
    const tRec = (+row[iT] - t0) / 1e9;
    const aRec = (+row[iA] * 180) / Math.PI;
    check(Math.abs(tRec - target) <= 0.05 && r.t <= target + 1e-9,
      `scrubbed to ${target.toFixed(3)} s: sample at ${tRec.toFixed(3)} s`);
    check(Math.abs(r.mcp - aRec) <= 0.5 && Math.abs(parseFloat(r.shown) - aRec) <= 0.01,
      `replay shows ${r.shown} for the record's ${aRec.toFixed(3)} deg`);
  }

  // The replay's whole hand: the gateway runs the record through the server's hand code. A
  // separate WebSocket (not the page's code) takes the frames the gateway sends; the page,
  // scrubbed to the target, poses every joint from the frame nearest it.
  await waitFor(page, () => window.telehand.replayHand?.done, null, 90000, "the replay's hand");
  const rh = await page.evaluate(() => window.telehand.replayHand);
  check(rh.ok && rh.frames >= 20 * Math.floor(duration), `the replay's hand: ${rh.frames} frames at ${rh.hz}/s`
    + ` over ${rh.simulated_s?.toFixed(1)} s, computed in ${rh.compute_s?.toFixed(2)} s (${rh.message})`, JSON.stringify(rh));
  const gw = await page.evaluate((id) => new Promise((resolve, reject) => {
    const ws = new WebSocket(`ws://${location.host}/ws`);
    const got = { dofs: null, frames: [], t0: null, end: null };
    ws.onopen = () => ws.send(JSON.stringify({ op: 'replay', session: id }));
    ws.onmessage = (e) => {
      const m = JSON.parse(e.data);
      if (m.type === 'hello') got.dofs = m.dofs;
      if (m.type === 'replay') got.t0 = m.t0_ms;
      if (m.type === 'replay_hand') got.frames.push(...m.frames.map((f) => ({ seq: f.dev_seq, t: (f.dev_t_ms - got.t0) / 1000, joints: f.joints })));
      if (m.type === 'replay_hand_end') { got.end = m; ws.close(); resolve(got); }
    };
    ws.onerror = () => reject(new Error('websocket error'));
  }), session);
  check(gw.frames.length === rh.frames, `a second connection gets the same ${gw.frames.length} hand frames`);
  // The joint that moves most apart from the index MCP's three.
  let jBest = -1;
  let jRange = 0;
  gw.dofs.forEach((name, j) => {
    if (name.startsWith('index_mcp')) return;
    const a = gw.frames.map((f) => f.joints[j]);
    const range = Math.max(...a) - Math.min(...a);
    if (range > jRange) { jRange = range; jBest = j; }
  });
  if (jBest < 0) jBest = gw.dofs.findIndex((name) => !name.startsWith('index_mcp'));
  await page.evaluate((t) => window.telehandSeek(t), target);
  const posed = await page.evaluate((name) => ({ frame: window.telehand.replayHandFrame, deg: window.telehand.jointDeg(name),
    mcpDeg: window.telehand.jointDeg('index_mcp_flexion') }), gw.dofs[jBest]);
  const nearest = gw.frames.reduce((b, f) => (Math.abs(f.t - target) < Math.abs(b.t - target) ? f : b));
  check(posed.frame && posed.frame.dev_seq === nearest.seq,
    `scrubbed to ${target.toFixed(3)} s: the page poses the hand frame of sample ${posed.frame?.dev_seq} (nearest: ${nearest.seq} at ${nearest.t.toFixed(3)} s)`);
  const jGw = (nearest.joints[jBest] * 180) / Math.PI;
  const jMcp = (nearest.joints[gw.dofs.indexOf('index_mcp_flexion')] * 180) / Math.PI;
  check(Math.abs(posed.deg - jGw) <= 0.01 && Math.abs(posed.mcpDeg - jMcp) <= 0.01,
    `3D ${gw.dofs[jBest]} ${posed.deg.toFixed(4)} deg, the gateway's frame ${jGw.toFixed(4)} deg (it moves over `
    + `${((jRange * 180) / Math.PI).toFixed(1)} deg in the replay); MCP flexion ${posed.mcpDeg.toFixed(3)} vs ${jMcp.toFixed(3)} deg`);
  await sleep(300);
  await page.screenshot({ path: path.join(artifacts, 'console-replay.png') });
  void server;
} catch (e) {
  failures++;
  console.log(`FAIL ${e.message}`);
  for (const n of ['server', 'web', 'client']) {
    try { console.log(`--- ${n}.log (tail)\n${log(n).split('\n').slice(-15).join('\n')}`); } catch { /* none */ }
  }
} finally {
  if (browser) await browser.close();
  if (delay) delay.close();
  await stopAll();
}
console.log(`${passes} passed, ${failures} failed`);
if (failures === 0) fs.rmSync(dir, { recursive: true, force: true });
else console.log(`logs kept in ${dir}`);
process.exit(failures === 0 ? 0 : 1);
