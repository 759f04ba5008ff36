// The coordinator's web page: one HTML document with its style and script
// inline, nothing from elsewhere. The script fetches api/status (all
// batches) and api/status?batch=ID (the batch shown in detail) every
// kRefreshMs and draws them with DOM calls only (textContent, never HTML
// from data: error texts come from workers). Fields it does not know are
// shown as they are, so a richer status report shows up without a change
// here. Elements carry data-* attributes naming the status field they show
// (data-batch, data-field, data-task, data-worker), and <body> says how many
// refreshes it drew (data-refreshes) and the report time of the last
// (data-now): the browser test reads them.
#include <sodium.h>

#include <string>

#include "common/error.h"
#include "coordinator/http_status.h"

namespace dofarm::coordinator {

namespace {

constexpr const char* kStyle = R"CSS(
body { font: 14px/1.4 system-ui, sans-serif; margin: 1.2em; color: #222; background: #fafafa; }
h1 { font-size: 1.4em; margin: 0 0 .3em 0; display: inline-block; }
h2 { font-size: 1.15em; margin: 1.2em 0 .4em 0; }
h3 { font-size: 1em; margin: .9em 0 .3em 0; }
#conn { margin-left: 1em; color: #666; }
#conn.bad { color: #b00; font-weight: bold; }
table { border-collapse: collapse; background: #fff; }
th, td { border: 1px solid #ddd; padding: 2px 6px; text-align: left; vertical-align: top; }
th { background: #eee; font-weight: 600; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
tr.sel { outline: 2px solid #36c; }
tbody#batch-rows tr { cursor: pointer; }
.state-running { color: #064; } .state-failed { color: #b00; font-weight: bold; }
.state-cancelled { color: #777; } .state-done { color: #036; }
.bar { position: relative; width: 14em; height: 1em; background: #e4e4e4; }
.bar > div { position: absolute; left: 0; top: 0; height: 100%; }
.bar .rendered { background: #9cd39c; } .bar .packed { background: #3a8f3a; }
#frames { display: flex; flex-wrap: wrap; gap: 2px; max-width: 60em; }
#frames > span { width: 12px; height: 12px; background: #e4e4e4; display: inline-block; }
#frames > span.done { background: #3a8f3a; } #frames > span.part { background: #9cd39c; }
#frames > span.failed { background: #d33; }
code { font-size: 12px; word-break: break-all; }
.muted { color: #777; }
)CSS";

constexpr const char* kScript = R"JS(
'use strict';
const kRefreshMs = 1500;
const params = new URLSearchParams(location.search);
const token = params.get('token');
const headers = token ? { 'Authorization': 'Bearer ' + token } : {};
let selected = params.get('batch');
let refreshes = 0;

function $(id) { return document.getElementById(id); }
// An element with attributes and children (strings become text nodes).
function el(tag, attrs, ...kids) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === 'class') e.className = v; else e.setAttribute(k, v);
  }
  for (const k of kids) e.append(k instanceof Node ? k : String(k));
  return e;
}
function text(v) {
  if (v === null || v === undefined) return '-';
  if (Array.isArray(v)) return v.map(x => typeof x === 'object' ? JSON.stringify(x) : x).join(', ');
  if (typeof v === 'object') return JSON.stringify(v);
  return String(v);
}
// As `dofarm status` prints it.
function eta(s) {
  if (s === null || s === undefined) return '-';
  s = Math.floor(s);
  const two = n => String(n).padStart(2, '0');
  return Math.floor(s / 3600) + ':' + two(Math.floor(s / 60) % 60) + ':' + two(s % 60);
}
function cell(field, value, num) {
  return el('td', { 'data-field': field, class: num ? 'num' : '' }, text(value));
}
async function getJson(url) {
  const r = await fetch(url, { headers, cache: 'no-store' });
  if (!r.ok) throw new Error(r.status + ' ' + (await r.text()).slice(0, 200));
  return r.json();
}
function bar(b) {
  const total = Math.max(1, b.frames_total);
  const d = el('div', { class: 'bar', title: b.frames_rendered + ' rendered, ' + b.frames_packed +
                        ' packed of ' + b.frames_total + ' frames' });
  const r = el('div', { class: 'rendered' }), p = el('div', { class: 'packed' });
  r.style.width = (100 * b.frames_rendered / total) + '%';
  p.style.width = (100 * b.frames_packed / total) + '%';
  d.append(r, p);
  return d;
}

function drawBatches(st) {
  const rows = [];
  for (const b of st.batches) {
    const tr = el('tr', { 'data-batch': b.batch, class: b.batch === selected ? 'sel' : '' },
      cell('batch', b.batch),
      el('td', { 'data-field': 'state', class: 'state-' + b.state }, b.state),
      cell('priority', b.priority, true),
      el('td', {}, bar(b)),
      cell('frames_rendered', b.frames_rendered, true), cell('frames_packed', b.frames_packed, true),
      cell('frames_total', b.frames_total, true),
      cell('tasks_done', b.tasks_done, true), cell('tasks_leased', b.tasks_leased, true),
      cell('tasks_pending', b.tasks_pending, true), cell('tasks_failed', b.tasks_failed, true),
      cell('tasks_total', b.tasks_total, true),
      cell('frames_per_hour', b.frames_per_hour.toFixed(1), true),
      cell('eta_seconds', eta(b.eta_seconds), true),
      cell('spec_path', b.spec_path));
    tr.addEventListener('click', () => {
      selected = b.batch;
      params.set('batch', b.batch);
      history.replaceState(null, '', '?' + params.toString());
      refreshSoon();
    });
    rows.push(tr);
  }
  $('batch-rows').replaceChildren(...rows);
  $('batches-omitted').textContent =
    st.batches_omitted > 0 ? '... and ' + st.batches_omitted + ' older batches not shown' : '';
}

// Per-frame progress from the batch's task list when the report has one;
// otherwise the frame counts alone.
function drawFrames(b) {
  const box = $('frames');
  if (!Array.isArray(b.tasks)) {
    box.replaceChildren();
    $('frames-note').textContent = b.frames_rendered + ' of ' + b.frames_total +
      ' frames rendered, ' + b.frames_packed + ' packed';
    return;
  }
  const frames = new Map();
  for (const t of b.tasks) {
    if (t.kind && t.kind !== 'render_tile') continue;
    const f = frames.get(t.frame) || { tiles: 0, done: 0, failed: 0 };
    f.tiles++;
    if (t.state === 'done') f.done++;
    if (t.state === 'failed') f.failed++;
    frames.set(t.frame, f);
  }
  const cells = [];
  for (const [frame, f] of [...frames].sort((x, y) => x[0] - y[0])) {
    const cls = f.failed ? 'failed' : f.done === f.tiles ? 'done' : f.done ? 'part' : '';
    cells.push(el('span', { class: cls, 'data-frame': frame,
                            title: 'frame ' + frame + ': ' + f.done + '/' + f.tiles + ' tiles done' }));
  }
  box.replaceChildren(...cells);
  $('frames-note').textContent = frames.size + ' frames listed (' + b.frames_rendered + ' of ' +
    b.frames_total + ' rendered, ' + b.frames_packed + ' packed)';
}

// A table of objects, known columns first, then every other scalar field.
function genericRows(items, known, keyAttr, keyField, limit) {
  const cols = [...known];
  for (const it of items.slice(0, limit))
    for (const k of Object.keys(it)) if (!cols.includes(k)) cols.push(k);
  const head = el('tr', {}, ...cols.map(c => el('th', {}, c)));
  const rows = items.slice(0, limit).map(it =>
    el('tr', { [keyAttr]: text(it[keyField]) }, ...cols.map(c => cell(c, it[c], typeof it[c] === 'number'))));
  return [head, ...rows];
}

function drawDetail(b, st) {
  $('detail').hidden = !b;
  if (!b) return;
  $('detail-id').textContent = b.batch + ' (' + b.state + ')';
  $('detail-reason').textContent = b.reason ? 'reason: ' + b.reason : '';
  $('detail-stalled').textContent = b.stalled_seconds !== null && b.stalled_seconds !== undefined
    ? 'stalled: no eligible worker for ' + Math.floor(b.stalled_seconds) + ' s' : '';
  drawFrames(b);
  const failed = b.failed || [];
  // A pack task has no frame or tile: its shard instead.
  const rows = failed.map(f => el('tr', { 'data-task': f.task },
    cell('task', f.task, true), cell('kind', f.kind),
    cell('frame', f.kind === 'pack_shard' ? '-' : f.frame, true),
    cell('rect', f.kind === 'pack_shard' ? 'shard ' + f.shard : f.rect), cell('error', f.error),
    el('td', { 'data-field': 'reproduce' }, el('code', {}, f.reproduce || ''))));
  $('failed-rows').replaceChildren(...rows);
  $('failed-none').textContent = failed.length ? '' : 'no failed tasks';
  $('failed-omitted').textContent = b.failed_omitted > 0 ? '... and ' + b.failed_omitted + ' more' : '';
  $('blocklisted').textContent = (b.blocklisted || []).length
    ? 'blocklisted workers: ' + b.blocklisted.join(', ') +
      (b.blocklisted_omitted > 0 ? ' and ' + b.blocklisted_omitted + ' more' : '') : '';
  const tasks = Array.isArray(b.tasks) ? b.tasks.filter(t => t.state !== 'done') : [];
  $('tasks-section').hidden = !Array.isArray(b.tasks);
  $('tasks').replaceChildren(...genericRows(tasks, ['task', 'state', 'frame'], 'data-task', 'task', 300));
  const events = Array.isArray(b.events) ? b.events.slice(-300).reverse() : [];
  $('events-section').hidden = !Array.isArray(b.events);
  $('events').replaceChildren(...genericRows(events, [], 'data-event', 'time', 300));
}

function drawWorkers(st) {
  const ws = st.workers.map(w => Object.assign({}, w,
    { last_seen: w.last_seen ? (st.now - w.last_seen).toFixed(1) + ' s ago' : '-' }));
  $('workers').replaceChildren(...genericRows(ws, ['worker', 'host', 'live', 'last_seen', 'tasks'],
                                              'data-worker', 'worker', 1000));
  const live = st.workers.filter(w => w.live).length;
  $('workers-live').textContent = live;
  $('workers-omitted').textContent =
    st.workers_omitted > 0 ? '(' + st.workers_omitted + ' more workers not shown)' : '';
}

let timer = null;
function refreshSoon() { clearTimeout(timer); timer = setTimeout(refresh, 0); }

async function refresh() {
  try {
    const st = await getJson('api/status');
    const ids = st.batches.map(b => b.batch);
    let id = ids.includes(selected) ? selected : null;
    if (!id) {
      const running = st.batches.find(b => b.state === 'running');
      id = running ? running.batch : (ids[0] || null);
    }
    let one = null;
    if (id) {
      const detail = await getJson('api/status?batch=' + encodeURIComponent(id));
      one = detail.batches.find(b => b.batch === id) || null;
    }
    selected = id;
    drawBatches(st);
    drawDetail(one, st);
    drawWorkers(st);
    refreshes++;
    document.body.dataset.refreshes = refreshes;
    document.body.dataset.now = st.now;
    $('conn').className = '';
    $('conn').textContent = 'updated ' + new Date(st.now * 1000).toLocaleTimeString() +
      ' (every ' + kRefreshMs / 1000 + ' s)';
  } catch (e) {
    $('conn').className = 'bad';
    $('conn').textContent = 'no answer from the coordinator: ' + e.message;
  }
  clearTimeout(timer);
  timer = setTimeout(refresh, kRefreshMs);
}
refresh();
)JS";

constexpr const char* kBody = R"HTML(
<body data-refreshes="0">
<header><h1>dofarm</h1><span id="conn">connecting...</span></header>
<section>
<h2>Batches</h2>
<table><thead><tr><th>batch</th><th>state</th><th>priority</th><th>frames</th><th>rendered</th><th>packed</th>
<th>of</th><th>tasks done</th><th>running</th><th>pending</th><th>failed</th><th>total</th>
<th>frames/h</th><th>ETA</th><th>spec</th></tr></thead><tbody id="batch-rows"></tbody></table>
<p id="batches-omitted" class="muted"></p>
</section>
<section id="detail" hidden>
<h2>Batch <span id="detail-id"></span></h2>
<p id="detail-reason" class="state-failed"></p><p id="detail-stalled" class="state-failed"></p>
<h3>Frames</h3><div id="frames"></div><p id="frames-note" class="muted"></p>
<h3>Failed tasks</h3>
<table><thead><tr><th>task</th><th>kind</th><th>frame</th><th>tile (x, y, w, h) or shard</th><th>error</th>
<th>reproduce</th></tr></thead><tbody id="failed-rows"></tbody></table>
<p id="failed-none" class="muted"></p><p id="failed-omitted" class="muted"></p>
<p id="blocklisted"></p>
<div id="tasks-section" hidden><h3>Tasks not done</h3><table id="tasks"></table></div>
<div id="events-section" hidden><h3>Events (newest first)</h3><table id="events"></table></div>
</section>
<section>
<h2>Workers: <span id="workers-live">0</span> live <span id="workers-omitted" class="muted"></span></h2>
<table id="workers"></table>
</section>
)HTML";

// 'sha256-BASE64' of a script or style element's text, for the page's
// Content-Security-Policy (CSP Level 2, "hash-source").
std::string csp_hash(const std::string& text) {
  if (sodium_init() < 0) throw RuntimeError("libsodium could not be initialised");
  unsigned char digest[crypto_hash_sha256_BYTES];
  crypto_hash_sha256(digest, reinterpret_cast<const unsigned char*>(text.data()), text.size());
  char b64[sodium_base64_ENCODED_LEN(crypto_hash_sha256_BYTES, sodium_base64_VARIANT_ORIGINAL)];
  sodium_bin2base64(b64, sizeof b64, digest, sizeof digest, sodium_base64_VARIANT_ORIGINAL);
  return "'sha256-" + std::string(b64) + "'";
}

struct Page {
  std::string html, csp;
  Page() {
    html = std::string("<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n") +
           "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n" +
           "<title>dofarm</title>\n<style>" + kStyle + "</style>\n</head>" + kBody + "<script>" +
           kScript + "</script>\n</body></html>\n";
    // Only this page's own script and style run; it talks to its own origin only.
    csp = "default-src 'none'; script-src " + csp_hash(kScript) + "; style-src " +
          csp_hash(kStyle) + "; connect-src 'self'; img-src 'none'; base-uri 'none'; " +
          "form-action 'none'; frame-ancestors 'none'";
  }
};

const Page& page() {
  static const Page p;
  return p;
}

}  // namespace

const std::string& status_page_html() { return page().html; }
const std::string& status_page_csp() { return page().csp; }

}  // namespace dofarm::coordinator
