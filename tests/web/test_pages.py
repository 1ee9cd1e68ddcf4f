"""Pages read from the store: the station's runs with verdicts, a robot's history, a run left by a dead process."""

import json
import re
import time

import numpy as np



def _station_state_of(evil: str) -> dict:
    """A station page's state whose every shown string is ``evil``."""
    return {"station": evil, "armed": False, "active": None,
            "devices": [{"name": evil, "kind": evil, "url": evil, "state": evil, "target": evil,
                         "last_fault": {"run_id": evil, "step": evil, "when": evil, "message": evil}}],
            "robots": [{"key": evil, "model": evil, "serial": evil, "overhaul_state": evil}],
            "runs": [{"run_id": evil, "procedure": evil, "serial": evil, "status": evil, "live": True,
                      "verdict": evil}]}

def _stored_run(store, run_id, serial, state, rp_by_pose, limit=0.5, status="done"):
    store.create_run(run_id, "iso9283", model="industrial-3100", serial=serial, overhaul_state=state,
                     config={}, params={})
    store.put_characteristics(run_id, [{"pose": p, "name": "RP_mm", "value": v, "unit": "mm", "limit": limit,
                                        "passed": v <= limit} for p, v in rp_by_pose.items()])
    if status != "running":
        store.set_run_status(run_id, status)


def test_robot_history_shows_the_worst_pose_of_each_finished_run(rng, served, client):
    worst = []
    for k in range(4):
        rp = {f"P{i}": float(rng.uniform(0.01, 0.8)) for i in range(1, 6)}
        _stored_run(served.store, f"run-{k}", "SN-7", "after" if k % 2 else "before", rp)
        worst.append(max(rp.values()))
    _stored_run(served.store, "run-other", "SN-8", "after", {"P1": 9.0})  # another robot: not shown
    _stored_run(served.store, "run-live", "SN-7", "after", {"P1": 7.0}, status="running")  # unfinished: not shown
    status, _, html = client.get("/robots/SN-7")
    assert status == 200 and "RP_mm" in html
    assert html.count("<figure class='history'>") == 1 and html.count("<svg") == 1  # one plot: RP_mm
    rows = re.findall(r"<tr><td>run-\d</td><td>\w+</td><td>([0-9.e-]+)</td><td>[0-9.]*</td>"
                      r"<td class='(pass|fail)'>", html)
    assert np.allclose([float(v) for v, _ in rows], worst, rtol=1e-3)
    assert [c for _, c in rows] == ["pass" if w <= 0.5 else "fail" for w in worst]
    # the station page lists every run with the verdict of its characteristics
    status, _, page = client.get("/")
    for k, w in enumerate(worst):
        verdict = "pass" if w <= 0.5 else "fail"
        assert re.search(rf"run-{k}</a>.*?<td class='{verdict}'>{verdict}</td>", page), (k, w)
    assert "run-other" in page and "9.0" not in page


def test_robot_history_follows_the_path_tests_figures_worst_path_of_each_run(rng, served, client):
    from station.characteristics import history_names

    names = ("AT_mm", "RT_mm", "CR_mm", "CO_mm", "AV_percent", "RV_percent", "FV_percent")
    assert all(n in history_names() for n in names) and "n_cycles" not in history_names()
    worst = []
    for k in range(3):
        store = served.store
        store.create_run(f"path-{k}", "iso9283-path", model="industrial-3100", serial="SN-3", overhaul_state="after",
                         config={}, params={})
        cr = {f"rectangle_blend_{v}": float(rng.uniform(0.1, 3.0)) for v in (10, 50, 100)}
        av = {f"line_{v}": float(rng.uniform(-4.0, 4.0)) for v in (10, 50, 100)}
        store.put_characteristics(f"path-{k}", [
            *({"pose": p, "name": "CR_mm", "value": v, "unit": "mm", "limit": 2.0, "passed": v <= 2.0}
              for p, v in cr.items()),
            *({"pose": p, "name": "AV_percent", "value": v, "unit": "%", "limit": None, "passed": None}
              for p, v in av.items()),
            {"pose": "line_50", "name": "n_cycles", "value": 10.0, "unit": "", "limit": None, "passed": None}])
        store.set_run_status(f"path-{k}", "done")
        worst.append((max(cr.values()), max(av.values(), key=abs)))
    status, _, html = client.get("/robots/SN-3")
    assert status == 200
    assert html.count("<figure class='history'>") == 2  # CR_mm and AV_percent; no plot of the count
    for j, name in enumerate(("CR_mm", "AV_percent")):
        part = html[html.index(f"<h2>{name}</h2>"):]
        rows = re.findall(r"<tr><td>path-\d</td><td>\w+</td><td>([0-9.e-]+)</td>", part)[:3]
        assert np.allclose([float(v) for v in rows], [w[j] for w in worst], rtol=1e-3), name


def test_a_run_left_running_by_a_dead_process_is_not_resumed_from_the_page(served, client):
    _stored_run(served.store, "orphan", "SN-9", "after", {"P1": 0.1}, status="running")
    st = client.state("orphan")
    assert st["status"] == "running" and not st["live"] and st["prompt"] is None
    status, _, text = client.post("/runs/orphan/resume")
    assert status == 409 and "station run --resume" in text
    assert served.hub.active() is None


def test_a_history_plot_is_against_the_date_takes_every_value_and_marks_failures(rng):
    """A negative AD below the band stays on the chart (the hand-drawn chart lost it under its axis); the limit is
    a band; failed runs are drawn apart from passed ones; the x axis is a date axis."""
    import matplotlib.dates as mdates

    from app.web.pages import worst_per_run
    from station.report import history_figure

    n = int(rng.integers(5, 12))
    t0 = 1.70e9 + float(rng.uniform(0, 3e7))
    t = t0 + np.cumsum(rng.uniform(5, 40, n)) * 86400.0
    limit = float(rng.uniform(0.3, 0.6))
    rows = []
    for k in range(n):
        for p in ("P1", "P2", "P3"):
            v = float(rng.uniform(-0.8 * limit, 0.8 * limit))
            rows.append({"run_id": f"r{k}", "created_at": t[k], "overhaul_state": "after", "pose": p, "value": v,
                         "limit": limit, "passed": abs(v) <= limit})
    low = int(rng.integers(n))  # one run with a pose far below the band
    rows[3 * low]["value"], rows[3 * low]["passed"] = -float(rng.uniform(1.2, 2.0)) * limit, False
    runs = worst_per_run(rows)
    assert [r["run_id"] for r in runs] == [f"r{k}" for k in range(n)]
    assert runs[low]["value"] == rows[3 * low]["value"] and runs[low]["failed"]
    assert sum(r["failed"] for r in runs) == 1
    fig = history_figure([r["created_at"] for r in runs], [r["value"] for r in runs], [r["limit"] for r in runs],
                         [r["failed"] for r in runs], ylabel="AD_mm", title="AD", events=[(t[n // 2] - 3600, "o")])
    ax = fig.axes[0]
    y0, y1 = ax.get_ylim()
    assert y0 < min(r["value"] for r in runs) and y1 > limit and y0 < -limit  # every value and the whole band
    assert isinstance(ax.xaxis.get_major_formatter(), mdates.ConciseDateFormatter)
    x0, x1 = ax.get_xlim()
    assert x0 <= mdates.date2num(np.datetime64(int(t[0]), "s")) and x1 >= mdates.date2num(np.datetime64(int(t[-1]), "s"))
    marks = {ln.get_label(): ln for ln in ax.get_lines()}
    assert len(marks["failed"].get_xdata()) == 1 and len(marks["passed"].get_xdata()) == n - 1
    assert marks["failed"].get_ydata()[0] == runs[low]["value"]
    band = [p for p in ax.patches if p.get_label().startswith("within the limit")]
    assert len(band) == 1
    import matplotlib.pyplot as plt
    plt.close(fig)


def test_an_overhaul_recorded_on_the_robot_page_is_an_event_the_fleet_counts_from(rng, served, client):
    from station.fleet.questions import since_overhaul

    days = sorted(rng.choice(np.arange(10, 300), size=3, replace=False).tolist())
    t0 = 1.70e9
    for k, d in enumerate(days):  # three runs; the overhaul falls between the first and the second
        _stored_run(served.store, f"oh-{k}", "SN-5", "after", {"P1": float(rng.uniform(0.05, 0.2))})
        served.store.backend.execute("UPDATE runs SET created_at=? WHERE run_id=?", (t0 + d * 86400.0, f"oh-{k}"))
    at = time.strftime("%Y-%m-%d", time.localtime(t0 + (days[0] + days[1]) / 2 * 86400.0))
    status, _, html = client.get("/robots/SN-5")
    assert status == 200 and "No overhaul recorded." in html and "id='btn-overhaul'" in html
    # refused, each with the reason and nothing recorded: a date that is none, nothing said of what was done
    for fields, why in (({"date": "yesterday", "what": "J2 gearbox"}, "is not YYYY-MM-DD"),
                        ({"date": at, "what": "  "}, "needs a description")):
        status, _, text = client.post("/robots/SN-5/overhauls", fields)
        assert status == 400 and why in text
    status, _, text = client.post("/robots/SN-5/overhauls", {"date": at, "what": "J2 gearbox <replaced>"},
                                  csrf=False)
    assert status == 403  # no CSRF token: refused like every action
    assert served.store.overhauls(serial="SN-5") == []
    status, headers, text = client.post("/robots/SN-5/overhauls",
                                        {"date": at, "what": "J2 gearbox <replaced>", "ticket": "WO-77"})
    assert status == 303 and headers["location"] == "/robots/SN-5", text
    (o,) = served.store.overhauls(serial="SN-5")
    assert o["what"] == "J2 gearbox <replaced>" and o["ticket"] == "WO-77"
    assert time.strftime("%Y-%m-%d", time.localtime(o["at"])) == at
    status, _, html = client.get("/robots/SN-5")
    assert "J2 gearbox &lt;replaced&gt;" in html and "<replaced>" not in html  # listed, escaped
    (row,) = [r for r in since_overhaul(served.store, "RP_mm") if r["serial"] == "SN-5"]
    assert row["baseline_run"] == "oh-1" and row["runs_since"] == 2


def test_every_page_escapes_what_it_shows():
    """The templates escape everything (autoescape): a hostile name anywhere comes out as text."""
    from app.web import pages

    evil = "<script>alert(1)</script>'\""
    state = _station_state_of(evil)
    run = {"run_id": evil, "steps": [], "note": "</script><script>alert(2)</script>"}
    rows = [{"run_id": evil, "created_at": 1.7e9, "overhaul_state": evil, "pose": "P1", "value": 0.1, "limit": 0.5,
             "passed": True}]
    html = [pages.station_page(state, evil, [evil]), pages.run_page(run, evil),
            pages.robot_page(evil, ["RP_mm"], {"RP_mm": rows}, evil,
                             [{"at": 1.7e9, "what": evil, "ticket": evil, "station": evil}]),
            pages.message_page(evil, evil, evil)]
    # the run's state goes to its script as JSON, inside which "</" is broken up: it cannot close the element
    head, rest = html[1].split("<script id='state' type='application/json'>", 1)
    data, tail = rest.split("</script>", 1)
    assert "</" not in data and json.loads(data)["note"] == run["note"]
    html[1] = head + tail
    for h in html:
        assert "<script>alert" not in h
    for h in (html[0], html[2], html[3]):
        assert "&lt;script&gt;alert(1)" in h


#: what no page may carry raw: C0 controls but tab, newline and carriage return, DEL, C1, bidi overrides
_RAW_CONTROL = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069\u2028\u2029]")


def _hostile_name(rng) -> str:
    """A name with drawn control characters between letters: ANSI colour, BEL, NUL, C1, a bidi override."""
    bad = ["\x1b[31m", "\x07", "\x00", "\x9b", "\u202e", "\u2066", "\x7f", "\u2028"]
    picks = rng.choice(len(bad), size=4, replace=False)
    return "J2" + "".join(bad[i] + "x" for i in picks)


def test_the_station_and_robot_pages_show_control_characters_visibly(rng):
    """Issue 47: a name from a config, a store or a form (robot serial and model, device, run, overhaul text)
    reaches the station and robot pages with its control characters written visibly (station.shown), not raw:
    no ANSI escape, BEL, NUL or bidi override that reorders the line is left in the HTML."""
    from app.web import pages
    from station.shown import shown

    evil = _hostile_name(rng)
    state = _station_state_of(evil)
    rows = [{"run_id": evil, "created_at": 1.7e9, "overhaul_state": evil, "pose": "P1", "value": 0.1, "limit": 0.5,
             "passed": True}]
    html = {"station": pages.station_page(state, "t", [evil]),
            "robot": pages.robot_page(evil, [evil], {evil: rows}, "t",
                                      [{"at": 1.7e9, "what": evil, "ticket": evil, "station": evil}]),
            "runs": pages.runs_table(state["runs"]), "message": pages.message_page(evil, evil),
            "run": pages.run_page({"run_id": evil, "steps": [], "note": evil}, "t")}
    visible = shown(evil, lines=True)
    assert _RAW_CONTROL.search(evil) and not _RAW_CONTROL.search(visible)
    for name, h in html.items():
        assert not _RAW_CONTROL.search(h), (name, _RAW_CONTROL.search(h))
        assert visible in h or name == "run", name  # the run page draws its names from its state, in its script
    assert html["robot"].count(visible) >= 4  # serial, the overhaul's what, ticket and station, the run id


def test_the_run_pages_script_screens_as_the_server_does(rng):
    """The run page draws from its state in the browser: its ``vis`` writes the same characters visibly as
    station.shown(lines=True) does (run under node, the browsers' JavaScript engine, where it is installed)."""
    import json
    import shutil
    import subprocess
    from pathlib import Path

    import pytest

    from station.shown import shown

    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed")
    src = (Path(__file__).resolve().parents[2] / "app/web/templates/run.js").read_text()
    m = re.search(r"^  const vis = .*?;\n(?=  const esc)", src, re.S | re.M)
    assert m, "run.js defines vis"
    texts = [_hostile_name(rng) + "\tline\nnext" for _ in range(5)] + ["".join(map(chr, range(0, 0x250)))]
    out = subprocess.run([node, "-e", m.group(0) + "process.stdout.write(JSON.stringify(JSON.parse("
                          "require('fs').readFileSync(0, 'utf8')).map(vis)));"],
                         input=json.dumps(texts), capture_output=True, text=True, timeout=60, check=True)
    assert json.loads(out.stdout) == [shown(t, lines=True) for t in texts]
