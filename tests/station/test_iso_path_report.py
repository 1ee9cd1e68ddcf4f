"""The path run's report: per path its plots (path, deviation along it, speed along it) and every stored figure's
value with its U, written at the run's end and linked as the run's report; the profiles it plots against
drawn truth."""

from __future__ import annotations

import html
import re

import numpy as np

from app.assemble import RunRequest, run_procedure
from app.web.state import report_path, run_state
from fakes.station import FakeStation
from station.analysis.path.commanded import Line, PathSpec
from station.analysis.path.profiles import cycle_profiles
from station.analysis.path.velocity import SPEED_WINDOW_S
from station.config import config_from_dict
from station.store import RunStore
from tests.pace import LOCKSTEP
from tests.person import person_typing_yes
from tests.station.test_iso_path_procedure import OVERRIDES


def test_cycle_profiles_give_the_drawn_deviation_and_speed(rng):
    start, d = rng.uniform(-500, 500, 3), rng.normal(size=3)
    d /= np.linalg.norm(d)
    spec = PathSpec("l", Line(start, start + rng.uniform(200, 400) * d), velocity_mm_s=float(rng.uniform(50, 500)))
    n_perp = np.cross(d, rng.normal(size=3))
    n_perp /= np.linalg.norm(n_perp)
    dt = 1.0 / float(rng.choice([250.0, 500.0, 1000.0]))
    t = np.arange(0.0, spec.geometry.length_mm / spec.velocity_mm_s, dt)
    s_true = spec.velocity_mm_s * t
    off_true = rng.uniform(0.1, 2.0) * np.sin(2 * np.pi * s_true / spec.geometry.length_mm) ** 2
    xyz = start + s_true[:, None] * d + off_true[:, None] * n_perp
    half = t.size // 2
    (a, b) = cycle_profiles(spec, t, xyz, [(0, half - 1), (half, t.size - 1)])
    assert (a.cycle, b.cycle) == (1, 2)
    np.testing.assert_allclose(np.concatenate([a.s_mm, b.s_mm]), s_true, atol=1e-9)
    np.testing.assert_allclose(np.concatenate([a.deviation_mm, b.deviation_mm]), off_true, atol=1e-9)
    # the offset's own motion adds at most its slope's share to the speed
    slope = np.max(np.abs(np.diff(off_true))) / (spec.velocity_mm_s * dt)
    margin = int(SPEED_WINDOW_S / dt) + 1  # the filter's half window meets the cycle's ends there
    inner = slice(margin, -margin)
    for p in (a, b):
        assert np.all(np.abs(p.speed_mm_s[inner] / spec.velocity_mm_s - 1.0) <= slope ** 2 + 1e-6)
    # a cycle whose clock stalls has no speed
    t2 = t.copy()
    t2[half + 5:] += 10 * dt
    assert cycle_profiles(spec, t2, xyz, [(half, t.size - 1)])[0].speed_mm_s is None


def test_a_path_run_writes_a_report_with_each_paths_plots_and_every_stored_figure(test_seed, tmp_path):
    with FakeStation.start(seed=test_seed, time_scale=LOCKSTEP, robot="industrial-3100") as station:
        d = station.config_dict(store_path=str(tmp_path / "s.sqlite"), report_dir=str(tmp_path / "reports"),
                                iso9283={"cycles": 3, "vap_cycles": 2, "tracker_rate_hz": 500.0})
        d["iso9283_path"] = {k: list(v) if isinstance(v, tuple) else v for k, v in OVERRIDES.items()}
        code = run_procedure(RunRequest(config_from_dict(d), "iso9283-path", arm=True, operator=person_typing_yes(),
                                        quiet=True, run_id="p1", config_dir=tmp_path))
    store = RunStore(tmp_path / "s.sqlite")
    assert code.status == "done", code.error
    path = report_path(store.steps("p1"))
    assert path is not None and path == (tmp_path / "reports" / "p1.html").resolve()
    assert run_state(store, "p1", None)["report"] is True  # the run page links it
    text = html.unescape(path.read_text())
    rows = [r for r in store.characteristics("p1") if r["name"] != "n_cycles"]
    paths = sorted({r["pose"] for r in rows})
    assert paths == ["line_50", "rectangle_blend_50"]
    for name in paths:
        assert f"{name}: measured cycles against the commanded path" in text
        assert f"{name}: distance of the measured path from the commanded one along it, per cycle" in text
    # the line is timed against its commanded speed; the rectangle's corners have no commanded speed figure
    assert "line_50: speed of the tool point along the path, per cycle against the commanded speed" in text
    assert text.count("<svg") >= 2 * len(paths) + 1
    table = text[text.index("<h2>Results</h2>"):text.index("</table>", text.index("<h2>Results</h2>"))]
    cells = re.findall(r"<tr><td class='l'>([^<]*)</td><td class='l'>([^<]*)</td><td>([^<]*)</td><td>([^<]*)</td>",
                       table)
    shown = {(p, f): (v, u) for p, f, v, u in cells}
    assert len(rows) == 7 and len(shown) == len(rows)  # line: AT RT AV RV FV; rectangle: CR CO
    for r in rows:
        value, U = shown[(r["pose"], r["name"])]
        assert value == f"{r['value']:.4g}", r
        assert U and float(U) > 0, r  # every figure with its U
    assert "PASS" in text or "FAIL" in text or "NOT DECIDED" in text
    assert store.steps("p1")[-1].output["verdict"] == str(code.verdict)
