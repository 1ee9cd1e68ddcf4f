(function(){
  const csrf = document.querySelector("meta[name=csrf-token]").content;
  // control characters and bidi overrides written visibly, as the server does (station/shown.py); tab and newline stay
  const vis = s => String(s ?? '').replace(/[\x00-\x08\x0b-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069\u2028\u2029]/g,
    c => { const n = c.charCodeAt(0); return n < 0x100 ? '\\x' + n.toString(16).padStart(2, '0') : '\\u' + n.toString(16).padStart(4, '0'); });
  const esc = s => vis(s).replace(/[&<>"']/g, c => ({'&':'&amp;','<':'&lt;','>':'&gt;','"':'&quot;',"'":'&#39;'}[c]));
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
    // paused: asked to; held: the procedure waits at a checkpoint and the station sends nothing new
    const paused = !st.paused ? '' : st.held ? ' <b class="aborted" id="paused">PAUSED</b>'
      : ' <b class="aborted" id="paused">PAUSING (until the next checkpoint)</b>';
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
    document.getElementById('error').textContent = vis(st.error || '') +
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
    out.hidden = !text.trim(); out.textContent = vis(text);
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
    // the axis takes every value (signed ones too) and zero; the zero line is drawn where it falls
    const w = 520, h = 120, l = 50, b = 18, t = 6;
    if (!ys || !ys.length) return '';
    const x0 = Math.min(...xs), x1 = Math.max(0, ...xs);
    let lo = Math.min(0, ...ys), hi = Math.max(0, ...ys);
    const pad = 0.1 * ((hi - lo) || 1); hi += hi > 0 ? pad : 0; lo -= lo < 0 ? pad : 0;
    if (hi === lo) hi = lo + 1;
    const px = x => l + (w - l - 8) * (x - x0) / ((x1 - x0) || 1), py = y => t + (h - b - t) * (hi - y) / (hi - lo);
    const pts = xs.map((x, i) => px(x).toFixed(1) + ',' + py(ys[i]).toFixed(1)).join(' ');
    const y0 = py(0).toFixed(1);
    return `<svg id="${id}" width="${w}" height="${h}" role="img" data-lo="${lo}" data-hi="${hi}">` +
      `<text x="2" y="12" font-size="11">${hi.toPrecision(3)}</text><text x="2" y="${h - b}" font-size="11">${lo.toPrecision(3)}</text>` +
      `<text x="${l}" y="${h - 2}" font-size="11">${x0.toFixed(1)} s</text>` +
      `<text x="${w - 40}" y="${h - 2}" font-size="11">now</text><text x="${l + 6}" y="12" font-size="11">${esc(label)}</text>` +
      `<line x1="${l}" x2="${w - 8}" y1="${y0}" y2="${y0}" stroke="#888"/><line x1="${l}" x2="${l}" y1="${t}" y2="${h - b}" stroke="#888"/>` +
      `<polyline fill="none" stroke="${color}" stroke-width="1.5" points="${pts}"/></svg>`;
  }
  function drawInstrument(ins) {
    document.getElementById('instrument-title').textContent = vis(ins.title);
    const el = document.getElementById('tracker');
    if (ins.kind === 'odometry') {
      el.innerHTML = `<p id="instrument-counters">received <b id="received">${ins.received}</b> samples</p>` +
        (ins.t.length ? chart('plot-psi', ins.t, ins.psi_deg, 'joint angle, deg', '#0b57d0') +
          chart('plot-v', ins.t, ins.v_m_s, 'speed, m/s', '#176b2c') : '<p>not streaming yet</p>');
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
