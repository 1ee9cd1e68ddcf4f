import re

import numpy as np

from station.report import (Report, plot_approach, plot_bars, plot_clusters, plot_errors_before_after,
                            plot_velocity_windows, render_html, write_report)


def test_report_is_self_contained_and_shows_verdicts(rng, tmp_path):
    t = np.linspace(0, 10, 2001)
    speed = np.abs(np.sin(t)) * 500
    rows = [
        {"pose": "P1", "name": "RP_mm", "value": 0.2, "unit": "mm", "limit": 0.5, "passed": True},
        {"pose": "P2", "name": "RP_mm", "value": 0.7, "unit": "mm", "limit": 0.5, "passed": False},
        {"pose": "P3", "name": "vAP_mm", "value": float("nan"), "unit": "mm", "limit": None, "passed": None},
        {"pose": "<script>", "name": "AP_mm", "value": 1.0, "unit": "mm", "limit": None, "passed": None},
    ]
    figs = [
        ("velocity", plot_velocity_windows(t, speed, [(3.1, 3.3), (6.2, 6.4)])),
        ("approach", plot_approach(t[:50], np.linspace(2, 0.01, 50), 0.5, t_enter_s=0.1, t_settle_s=0.15)),
        ("clusters", plot_clusters({"x": rng.normal(size=(10, 3)), "y": rng.normal(size=(10, 3)) + 1}, np.zeros(3))),
        ("bars", plot_bars(["P1", "P2"], [0.2, 0.7], limit=0.5, ylabel="RP [mm]", title="RP")),
        ("cal", plot_errors_before_after(rng.normal(size=20), rng.normal(size=20) * 0.1)),
    ]
    rep = Report("ISO 9283 run r1", facts={"robot": "SN-1"}, rows=rows, figures=figs)
    assert rep.verdict == "FAIL"
    text = render_html(rep)
    assert text.count("<svg") == 5
    assert "<script>" not in text and "&lt;script&gt;" in text  # escaped
    assert re.search(r"class='fail'>FAIL", text) and "n/a" in text
    assert not re.search(r"(src|href)=['\"]https?://", text)  # nothing fetched from outside
    p = write_report(rep, tmp_path / "r" / "report.html")
    assert p.stat().st_size > 10_000
    rows[1]["passed"] = True
    assert Report("x", rows=rows).verdict == "PASS"
    assert Report("x").verdict == "NO LIMITS"


def test_a_long_trace_is_drawn_thinned_with_every_extreme(rng):
    from station.report import decimate_trace

    n = int(rng.integers(20_000, 60_000))
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n))
    y = np.abs(rng.normal(0.0, 50.0, n))
    gap = slice(int(rng.integers(0, n - 500)), None)
    y[gap.start:gap.start + 400] = np.nan  # a beam break
    spikes = rng.choice(n, 5, replace=False)
    y[spikes] = 1e3 * rng.uniform(1.0, 2.0, 5)
    td, yd = decimate_trace(t, y, 2000)
    assert td.size <= 2000 and np.all(np.diff(td) > 0) and set(td) <= set(t)
    assert set(t[spikes][np.isfinite(y[spikes])]) <= set(td)  # every spike is drawn
    assert np.nanmin(yd) == np.nanmin(y) and np.nanmax(yd) == np.nanmax(y)
    assert np.any(np.isnan(yd))  # the break stays a gap
    # the trace is cut into 1,000 runs of equal length: each keeps its own extremes
    k = -(-n // 1000)
    for a in range(0, n, k):
        run = y[a:a + k]
        if np.any(np.isfinite(run)):
            kept = yd[(td >= t[a]) & (td <= t[min(a + k, n) - 1])]
            assert np.nanmax(kept) == np.nanmax(run) and np.nanmin(kept) == np.nanmin(run)
    assert decimate_trace(t[:4000], y[:4000])[1].size == 4000  # what the figure can show stays whole
    # the figure of the long trace holds the thinned points, not all of them
    svg = plot_velocity_windows(t, y, [(t[100], t[200])])
    assert svg.count("\nL ") < 2 * 2000 + 500  # two lines (speed, moving average); 2 n without thinning
