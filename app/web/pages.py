"""The HTML of the pages and their small script (no build step, no external files).

Pages are rendered on the server with the current snapshot, so they are
useful without the script; the script then follows the run's event stream
and redraws the parts that change. Every action is a form POST carrying the
CSRF token.
"""

from __future__ import annotations

import json
import time
from html import escape

_STYLE = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:#222;max-width:1100px}
h1{font-size:1.4em}h2{font-size:1.15em;margin-top:1.4em}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left}
th{background:#f3f3f3}.pass,.done{color:#176b2c;font-weight:600}.fail,.failed{color:#b00020;font-weight:600}
.aborted,.interrupted{color:#a15c00;font-weight:600}.running{color:#0b57d0;font-weight:600}
.pending{color:#888}tr.current{background:#eef4ff}
.banner{position:sticky;top:0;z-index:5;font-size:2em;font-weight:700;padding:.3em .6em;margin:0 0 .5em;border-radius:6px}
.banner ul{font-size:.45em;font-weight:400;margin:.2em 0 0 1em}
.v-PASS{background:#cdeccd;color:#0b5d1e}.v-FAIL{background:#f7c9d0;color:#8a0016}
.v-NOT{background:#ffe8a8;color:#6b4e00}.v-ABORTED{background:#ddd;color:#333}
#prompt{border:3px solid #0b57d0;padding:1em;margin:1em 0;font-size:1.2em;background:#f5f9ff}
#prompt button{font-size:1.1em;padding:.4em 1.4em;margin-right:1em}
.bar{height:14px;background:#eee;width:100%;max-width:600px}.bar div{height:100%;background:#0b57d0}
.error{color:#b00020;white-space:pre-wrap}pre{background:#f7f7f7;padding:.5em}
form.inline{display:inline}button{cursor:pointer}
"""


def _page(title: str, body: str, csrf: str) -> str:
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{escape(title)}</title>"
            f"<meta name='csrf-token' content='{escape(csrf)}'><style>{_STYLE}</style></head>"
            f"<body>{body}</body></html>")


def _form(action: str, label: str, csrf: str, fields: dict | None = None, name: str = "") -> str:
    hidden = "".join(f"<input type='hidden' name='{escape(k)}' value='{escape(str(v))}'>"
                     for k, v in {"csrf": csrf, **(fields or {})}.items())
    return (f"<form class='inline' method='post' action='{escape(action)}'>{hidden}"
            f"<button type='submit' name='{escape(name)}' id='btn-{escape(label.lower())}'>{escape(label)}</button>"
            "</form>")


def station_page(state: dict, csrf: str, procedures: list[str]) -> str:
    """Devices, robots, runs with verdicts, and the form that starts a run."""
    armed = state["armed"]
    rows_dev = "".join(f"<tr><td>{escape(d['name'])}</td><td>{escape(d.get('kind', ''))}</td>"
                       f"<td>{escape(d['url'])}</td><td>{escape(d['state'])}</td>"
                       f"<td class='target'>{escape(d.get('target', ''))}</td></tr>" for d in state["devices"])
    rows_rob = "".join(f"<tr><td>{escape(r['key'])}</td><td>{escape(str(r['model']))}</td>"
                       f"<td><a href='/robots/{escape(str(r['serial']))}'>{escape(str(r['serial']))}</a></td>"
                       f"<td>{escape(str(r['overhaul_state']))}</td></tr>" for r in state["robots"])
    robot_opts = "".join(f"<option>{escape(r['key'])}</option>" for r in state["robots"])
    proc_opts = "".join(f"<option>{escape(p)}</option>" for p in procedures)
    mode = ("<p class='fail'>ARMED: runs use the configured devices; real hardware moves after you confirm "
            "on the run page.</p>" if armed else
            "<p>Dry runs: every run uses the procedure's fake cell (simulated devices on loopback).</p>")
    if state["active"]:
        start = (f"<p>Run <a href='/runs/{escape(state['active'])}'>{escape(state['active'])}</a> is going; "
                 "one run at a time.</p>")
    else:
        seed = "" if armed else "<label> seed <input name='seed' value='0' size='6'></label>"
        start = (f"<form method='post' action='/runs'><input type='hidden' name='csrf' value='{escape(csrf)}'>"
                 f"<label>procedure <select name='procedure'>{proc_opts}</select></label> "
                 f"<label>robot <select name='robot'>{robot_opts}</select></label> {seed} "
                 "<button type='submit' id='btn-start'>Start run</button></form>")
    body = (f"<h1>Station {escape(state['station'])}</h1>{mode}<h2>Start a run</h2>{start}"
            f"<h2>Devices</h2><table><tr><th>device</th><th>kind</th><th>URL</th><th>state</th><th>moving to</th></tr>{rows_dev}</table>"
            f"<h2>Robots</h2><table><tr><th>key</th><th>model</th><th>serial (history)</th><th>overhaul</th></tr>"
            f"{rows_rob}</table><h2>Runs</h2><div id='runs'>{runs_table(state['runs'])}</div>"
            f"<script>{_STATION_JS}</script>")
    return _page(f"station {state['station']}", body, csrf)


def runs_table(runs: list[dict]) -> str:
    rows = "".join(
        f"<tr><td><a href='/runs/{escape(r['run_id'])}'>{escape(r['run_id'])}</a></td><td>{escape(r['procedure'])}</td>"
        f"<td>{escape(str(r['serial']))}</td><td class='{escape(r['status'])}'>{escape(r['status'])}"
        f"{' (live)' if r['live'] else ''}</td><td class='{escape(str(r['verdict']))}'>{escape(r['verdict'] or '')}</td></tr>"
        for r in runs)
    return (f"<table><tr><th>run</th><th>procedure</th><th>serial</th><th>status</th><th>verdict</th></tr>{rows}</table>"
            if runs else "<p>No runs in the store yet.</p>")


def run_page(state: dict, csrf: str) -> str:
    """The run: its steps, the current one, the prompt, controls, results; redrawn from the event stream."""
    rid = escape(state["run_id"])
    body = (f"<div id='banner' class='banner' hidden></div><p><a href='/'>&larr; station</a></p><h1>Run {rid}</h1>"
            f"<p id='summary'></p><div class='bar'><div id='bar' style='width:0%'></div></div>"
            "<div id='prompt' hidden></div><p id='controls'></p><p id='error' class='error'></p>"
            "<h2 id='instrument-title'>Instrument</h2><div id='tracker'></div>"
            "<h2>Results</h2><div id='results'></div><h2>Steps</h2><div id='steps'></div><pre id='output' hidden></pre>"
            f"<script id='state' type='application/json'>{_json_for_script(state)}</script>"
            f"<script>{_RUN_JS}</script>")
    return _page(f"run {state['run_id']}", body, csrf)


def robot_page(serial: str, names: list[str], history: dict[str, list[dict]], csrf: str,
               overhauls: list[dict] | None = None) -> str:
    """One robot's characteristics across its finished runs: a plot against the date per characteristic
    (matplotlib, :func:`station.report.plot_history`) and its table."""
    parts = [f"<p><a href='/'>&larr; station</a></p><h1>Robot {escape(serial)}</h1>"]
    if not any(history.values()):
        parts.append("<p>No finished runs with results for this robot yet.</p>")
    events = [(o["at"], f"overhaul: {o['what']}") for o in overhauls or []]
    parts.append(_overhauls(serial, overhauls or [], csrf))
    for name in names:
        rows = history.get(name) or []
        if not rows:
            continue
        parts.append(f"<h2>{escape(name)}</h2>{_history(name, rows, events)}")
    return _page(f"robot {serial}", "".join(parts), csrf)


def _overhauls(serial: str, overhauls: list[dict], csrf: str) -> str:
    """The robot's recorded overhauls and the form that records one (date, what was done, work ticket)."""
    rows = "".join(f"<tr><td>{time.strftime('%Y-%m-%d %H:%M', time.localtime(o['at']))}</td>"
                   f"<td>{escape(str(o['what']))}</td><td>{escape(str(o.get('ticket') or ''))}</td>"
                   f"<td>{escape(str(o.get('station') or ''))}</td></tr>" for o in overhauls)
    table = (f"<table id='overhauls'><tr><th>date</th><th>what was done</th><th>ticket</th><th>station</th></tr>"
             f"{rows}</table>" if overhauls else "<p id='overhauls'>No overhaul recorded.</p>")
    form = (f"<form method='post' action='/robots/{escape(serial)}/overhauls'>"
            f"<input type='hidden' name='csrf' value='{escape(csrf)}'>"
            "<label>date <input name='date' type='date' required></label> "
            "<label>what was done <input name='what' size='40' required></label> "
            "<label>ticket <input name='ticket' size='12'></label> "
            "<button type='submit' id='btn-overhaul'>Record overhaul</button></form>")
    return f"<h2>Overhauls</h2>{table}{form}"


def worst_per_run(rows: list[dict]) -> list[dict]:
    """Per finished run (in time order): the value of largest magnitude over its poses (sign kept, as limits
    bound ``|value|``), its limit, and whether any pose failed."""
    runs: dict[str, dict] = {}
    for r in rows:
        if r["value"] is None:
            continue
        cur = runs.setdefault(r["run_id"], {"run_id": r["run_id"], "created_at": r["created_at"], "value": r["value"],
                                            "limit": r["limit"], "state": r["overhaul_state"], "failed": False})
        if abs(r["value"]) > abs(cur["value"]):
            cur["value"] = r["value"]
        if r["limit"] is not None and (cur["limit"] is None or r["limit"] > cur["limit"]):
            cur["limit"] = r["limit"]
        cur["failed"] = cur["failed"] or r.get("passed") is False
    return list(runs.values())


def _history(name: str, rows: list[dict], events) -> str:
    from station.report import plot_history

    runs = worst_per_run(rows)
    if not runs:
        return "<p>no values</p>"
    svg = plot_history([r["created_at"] for r in runs], [r["value"] for r in runs], [r["limit"] for r in runs],
                       [r["failed"] for r in runs], ylabel=name, title=f"{name}: worst pose of each run", events=events)
    lines = []
    for r in runs:
        limit = "" if r["limit"] is None else f"{r['limit']:.4g}"
        verdict = "fail" if r["failed"] else "pass"
        when = time.strftime("%Y-%m-%d %H:%M", time.gmtime(r["created_at"]))
        lines.append(f"<tr><td>{escape(r['run_id'])}</td><td>{escape(str(r['state']))}</td><td>{r['value']:.4g}</td>"
                     f"<td>{limit}</td><td class='{verdict}'>{verdict}</td><td>{when}</td></tr>")
    return (f"<figure class='history'>{svg}</figure><table><tr><th>run</th><th>overhaul</th>"
            f"<th>worst over poses</th><th>limit</th><th>verdict</th><th>date (UTC)</th></tr>{''.join(lines)}</table>")


def message_page(title: str, message: str, csrf: str = "") -> str:
    return _page(title, f"<p><a href='/'>&larr; station</a></p><h1>{escape(title)}</h1>"
                        f"<p class='error'>{escape(message)}</p>", csrf)


def _json_for_script(state: dict) -> str:
    return json.dumps(state, default=float).replace("</", "<\\/")


_STATION_JS = r"""
(function(){
  const es = new EventSource('/events');
  es.addEventListener('runs', ev => { document.getElementById('runs').innerHTML = ev.data; });
})();
"""

_RUN_JS = r"""
(function(){
  const csrf = document.querySelector("meta[name=csrf-token]").content;
  const esc = s => String(s ?? '').replace(/[&<>"']/g, c => ({'&':'&amp;','<':'&lt;','>':'&gt;','"':'&quot;',"'":'&#39;'}[c]));
  const fmt = s => { if (s == null) return '?'; s = Math.max(0, Math.round(s));
    return Math.floor(s/60) + ':' + String(s%60).padStart(2,'0'); };
  const form = (action, label, fields) => {
    let h = `<form class="inline" method="post" action="${action}"><input type="hidden" name="csrf" value="${esc(csrf)}">`;
    for (const [k, v] of Object.entries(fields || {})) h += `<input type="hidden" name="${k}" value="${esc(v)}">`;
    return h + `<button type="submit" id="btn-${label.toLowerCase()}">${esc(label)}</button></form> `;
  };
  function draw(st) {
    const base = '/runs/' + encodeURIComponent(st.run_id);
    const cur = st.current ? `step ${st.current.idx + 1}/${st.n_steps}: <b id="current">${esc(st.current.name)}</b>`
      + (st.detail ? ` <span id="detail">${esc(st.detail)}</span>` : '') : '';
    const paused = st.paused ? ' <b class="aborted" id="paused">PAUSED</b>' : '';
    const verdict = st.verdict ? ` verdict <b id="verdict" class="${esc(st.verdict)}">${esc(st.verdict)}</b>`
      + ((st.reasons || []).length ? ` <span id="reasons">(${esc(st.reasons.join('; '))})</span>` : '') : '';
    document.getElementById('summary').innerHTML =
      `${esc(st.procedure || '')} ${esc(st.model || '')} ${esc(st.serial || '')} &mdash; ` +
      `<span id="status" class="${esc(st.status)}">${esc(st.status)}</span>${paused} ${cur}` +
      ` &mdash; ${st.n_done}/${st.n_steps} steps, elapsed ${fmt(st.elapsed_s)}` +
      (st.status === 'running' ? `, remaining ~${fmt(st.remaining_s)}` : '') + verdict;
    document.getElementById('bar').style.width = (st.n_steps ? 100 * st.n_done / st.n_steps : 0) + '%';
    // the prompt and the controls are redrawn only when they change: a button under the operator's
    // finger is never replaced by the next state event (a press held across one would be lost)
    const p = document.getElementById('prompt');
    const pid = st.prompt ? String(st.prompt.id) : '';
    if (p.dataset.promptId !== pid) {
      p.dataset.promptId = pid;
      if (st.prompt) {
        p.hidden = false;
        p.innerHTML = `<p id="prompt-text">${esc(st.prompt.message)}</p>` +
          form(base + '/answer', 'Yes', {prompt_id: st.prompt.id, answer: 'yes'}) +
          form(base + '/answer', 'No', {prompt_id: st.prompt.id, answer: 'no'});
      } else { p.hidden = true; p.innerHTML = ''; }
    }
    let c = '';
    if (st.live) {
      c += st.paused ? form(base + '/continue', 'Continue') : form(base + '/pause', 'Pause');
      c += form(base + '/abort', 'Abort');
    } else if (st.status === 'failed' || st.status === 'aborted') {
      c += form(base + '/resume', 'Resume');
    }
    if (st.report) c += `<a id="report" href="${base}/report">HTML report</a>`;
    const ctl = document.getElementById('controls');
    if (ctl.dataset.html !== c) { ctl.dataset.html = c; ctl.innerHTML = c; }
    const resumable = !st.live && (st.status === 'failed' || st.status === 'aborted');
    document.getElementById('error').textContent = (st.error || '') +
      (resumable ? (st.error ? ' ' : '') + 'Press Resume to go on from the last finished step.' : '');
    // the verdict, once the run has one, in a banner at the top of the page
    const banner = document.getElementById('banner');
    const word = st.verdict ? String(st.verdict).toUpperCase() : (resumable ? 'ABORTED' : '');
    if (word && st.status !== 'running') {
      banner.hidden = false;
      banner.className = 'banner v-' + word.split(' ')[0];
      banner.innerHTML = `<span id="banner-verdict">${esc(word)}</span>` +
        ((st.reasons || []).length ? `<ul id="banner-reasons">${st.reasons.map(x => `<li>${esc(x)}</li>`).join('')}</ul>` : '');
    } else { banner.hidden = true; }
    const out = document.getElementById('output');
    // the console's hint to resume from the command line is the Resume button here
    const text = (st.output || '').split('\n').filter(l => !l.startsWith('resume with: station run')).join('\n');
    out.hidden = !text.trim(); out.textContent = text;
    let r = '';
    if (st.results.length) {
      r = '<table id="results-table"><tr><th>pose</th><th>characteristic</th><th>value</th><th>unit</th><th>limit</th><th>verdict</th></tr>';
      for (const x of st.results) {
        const v = x.passed == null ? '' : (x.passed ? 'pass' : 'fail');
        r += `<tr><td>${esc(x.pose)}</td><td>${esc(x.name)}</td><td>${x.value == null ? '' : Number(x.value).toPrecision(4)}</td>` +
             `<td>${esc(x.unit)}</td><td>${x.limit == null ? '' : esc(x.limit)}</td><td class="${v}">${v}</td></tr>`;
      }
      r += '</table>';
    } else r = '<p>none yet</p>';
    document.getElementById('results').innerHTML = r;
    let s = '<table id="steps-table"><tr><th>#</th><th>step</th><th>state</th><th>attempts</th><th>time</th><th>message</th></tr>';
    for (const x of st.steps) {
      const cls = (st.current && st.current.idx === x.idx) ? ' class="current"' : '';
      s += `<tr${cls} data-state="${esc(x.state)}"><td>${x.idx + 1}</td><td>${esc(x.name)}</td><td class="${esc(x.state)}">${esc(x.state)}</td>` +
           `<td>${x.attempts || ''}</td><td>${x.duration_s == null ? '' : x.duration_s.toFixed(1) + ' s'}</td><td>${esc(x.message || '')}</td></tr>`;
    }
    document.getElementById('steps').innerHTML = s + '</table>';
    if (st.instrument) drawInstrument(st.instrument); else drawTracker(st.tracker);
    document.body.dataset.status = st.status;
  }
  function chart(id, xs, ys, label, color) {
    const w = 520, h = 120, l = 50, b = 18;
    if (!ys || !ys.length) return '';
    const x0 = Math.min(...xs), x1 = Math.max(0, ...xs), top = Math.max(...ys) * 1.1 || 1;
    const px = x => l + (w - l - 8) * (x - x0) / ((x1 - x0) || 1), py = y => h - b - (h - b - 6) * y / top;
    const pts = xs.map((x, i) => px(x).toFixed(1) + ',' + py(ys[i]).toFixed(1)).join(' ');
    return `<svg id="${id}" width="${w}" height="${h}" role="img"><text x="2" y="12" font-size="11">${top.toPrecision(3)}</text>` +
      `<text x="2" y="${h - b}" font-size="11">0</text><text x="${l}" y="${h - 2}" font-size="11">${x0.toFixed(1)} s</text>` +
      `<text x="${w - 40}" y="${h - 2}" font-size="11">now</text><text x="${l + 6}" y="12" font-size="11">${esc(label)}</text>` +
      `<line x1="${l}" x2="${w - 8}" y1="${h - b}" y2="${h - b}" stroke="#888"/><line x1="${l}" x2="${l}" y1="4" y2="${h - b}" stroke="#888"/>` +
      `<polyline fill="none" stroke="${color}" stroke-width="1.5" points="${pts}"/></svg>`;
  }
  function drawInstrument(ins) {
    document.getElementById('instrument-title').textContent = ins.title;
    const el = document.getElementById('tracker');
    if (ins.kind === 'odometry') {
      el.innerHTML = `<p id="instrument-counters">received <b id="received">${ins.received}</b> samples</p>` +
        (ins.t.length ? chart('plot-psi', ins.t, ins.psi_deg.map(Math.abs), '|joint angle|, deg', '#0b57d0') +
          chart('plot-v', ins.t, ins.v_m_s.map(Math.abs), '|speed|, m/s', '#176b2c') : '<p>not streaming yet</p>');
      return;
    }
    const last = ins.last ? ` &mdash; last: pose ${ins.last.pose}` + (ins.last.x == null ? ' (nothing found)' :
      ` at (${[ins.last.x, ins.last.y, ins.last.z].map(v => v.toFixed(3)).join(', ')}) mm`) : '';
    const missed = (ins.not_found || []).length ? `; no corner found at pose(s) ${ins.not_found.join(', ')}` : '';
    el.innerHTML = `<p id="instrument-counters">measured <b id="measured">${ins.measured}</b> of ` +
      `<b id="planned">${ins.planned}</b> poses${last}${esc(missed)}</p>`;
  }
  function drawTracker(tr) {
    document.getElementById('instrument-title').textContent = 'Tracker, last seconds';
    const el = document.getElementById('tracker');
    if (!tr) { el.innerHTML = '<p>not streaming</p>'; return; }
    const rate = tr.rate_hz == null ? '?' : tr.rate_hz.toFixed(0);
    el.innerHTML = `<p id="tracker-counters">${esc(tr.step)}: received <b id="received">${tr.received}</b> in the run, ` +
      `${tr.n} in this step at ${rate} Hz; flagged ${tr.flagged}; gaps <b id="gaps">${tr.gaps}</b></p>` +
      chart('plot-speed', tr.t, tr.speed_mm_s, 'speed, mm/s', '#0b57d0') +
      (tr.dist_mm ? chart('plot-dist', tr.t, tr.dist_mm, 'distance to the nearest commanded pose, mm', '#b00020') : '');
  }
  const st0 = JSON.parse(document.getElementById('state').textContent);
  draw(st0);
  const es = new EventSource('/runs/' + encodeURIComponent(st0.run_id) + '/events');
  es.addEventListener('state', ev => draw(JSON.parse(ev.data)));
})();
"""
