"""Benchmark: how far a fake cell's measured ISO 9283 results lie from the noise-free prediction.

Run by hand::

    .venv/bin/python bench/bench_fake_truth.py [--first S] [--cells N] [--cycles C]

For N fake cells (seeds S .. S+N-1, robots as drawn), runs the ISO 9283
procedure on the fake station (emScon tracker and controller fakes on
loopback, 20x real time, C pose cycles, 2 multi-directional cycles) and
compares each pose's measured AP, and the AD of P2-P4, with
:func:`procedures.iso9283_truth.predict_static` from the cell's true error
effects. Prints one line per cell, then the spread of the differences, in mm,
in units of the scatter :func:`~procedures.iso9283_truth.prediction_scatter`
expects (rms length of the attained-position error) and in units of the
run's own registration uncertainty (jackknife, at each pose), and the largest
RP, vAP and PST seen.

These figures back ``app.acceptance.SPEC_SIGMAS``, how many scatters a
fake robot drawn "in spec" or "out of spec" keeps from its limits.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time

import numpy as np

from procedures.iso9283 import plan_from_config
from procedures.iso9283_truth import predict_static, prediction_scatter
from app.acceptance import Station, fake_cell_truth
from station.store import RunStore


def one_cell(seed: int, cycles: int) -> dict:
    with tempfile.TemporaryDirectory() as d:
        st = Station.fake(d, seed=seed, time_scale=20.0)
        plan = plan_from_config(st.config, "r1")
        cell = fake_cell_truth(plan, seed)
        pred = predict_static(plan, cell.effects)
        scatter = prediction_scatter(plan, cell.effects, cell.stop_sigma_rad, cycles=cycles,
                                     tracker_sigma_mm=cell.tracker_sigma_mm, draws=300,
                                     tracker_accuracy=cell.tracker_accuracy)
        run = st.iso9283(cycles=cycles, vap_cycles=2)
        with RunStore(run.store_path) as store:
            reg = next(s.output for s in store.steps(run.run_id) if s.name == "register base frame" and s.status == "done")
        chars = {}
        for c in run.characteristics:
            chars.setdefault(c["name"], {})[c["pose"]] = c["value"]
        return {"seed": seed, "status": run.status, "failures": run.failures, "chars": chars,
                "pred_AP": pred.AP_mm, "pred_AD": pred.AD_mm, "u_reg": reg["uncertainty_at_poses_mm"],
                "rms_AP": scatter.AP_rms_mm, "sd_AD": scatter.AD_sd_mm}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--first", type=int, default=1000)
    ap.add_argument("--cells", type=int, default=30)
    ap.add_argument("--cycles", type=int, default=5)
    args = ap.parse_args(argv)
    d_ap, r_ap, m_ap, d_ad, z_ad = [], [], [], [], []
    worst = {"RP_mm": 0.0, "vAP_mm": 0.0, "PST_s": 0.0}
    t0 = time.perf_counter()
    for seed in range(args.first, args.first + args.cells):
        cell = one_cell(seed, args.cycles)
        ch = cell["chars"]
        for pose, pred in cell["pred_AP"].items():
            diff = ch["AP_mm"][pose] - pred
            d_ap.append(diff)
            r_ap.append(diff / cell["u_reg"][pose])
            m_ap.append(abs(diff) / cell["rms_AP"][pose])
        d_ad.append(ch["AD_mm"]["P2-P4"] - cell["pred_AD"]["P2-P4"])
        z_ad.append(d_ad[-1] / cell["sd_AD"]["P2-P4"])
        for key in worst:
            vals = [v for v in ch.get(key, {}).values() if v is not None]
            worst[key] = max([worst[key], *vals])
        print(json.dumps({"seed": seed, "status": cell["status"],
                          "worst_AP_mm": round(max(ch["AP_mm"].values()), 3),
                          "predicted_worst_AP_mm": round(max(cell["pred_AP"].values()), 3),
                          "failures": cell["failures"]}), flush=True)
    d_ap, r_ap, m_ap, d_ad, z_ad = map(np.asarray, (d_ap, r_ap, m_ap, d_ad, z_ad))
    print(f"{args.cells} cells, {d_ap.size} poses, {time.perf_counter() - t0:.0f} s")
    print(f"AP measured - predicted: mean {d_ap.mean():+.3f} mm, sd {d_ap.std(ddof=1):.3f} mm, "
          f"largest |.| {np.abs(d_ap).max():.3f} mm")
    print(f"  |.| in expected scatters (rms, Monte Carlo): median {np.median(m_ap):.2f}, "
          f"99th percentile {np.percentile(m_ap, 99):.2f}, largest {m_ap.max():.2f}")
    print(f"  in the runs' jackknife registration uncertainties: sd {r_ap.std(ddof=1):.2f}, "
          f"largest |.| {np.abs(r_ap).max():.2f}")
    print(f"AD measured - predicted: mean {d_ad.mean():+.3f} mm, sd {d_ad.std(ddof=1):.3f} mm, "
          f"largest |.| {np.abs(d_ad).max():.3f} mm; in expected sd: mean {z_ad.mean():+.2f}, "
          f"largest |.| {np.abs(z_ad).max():.2f}")
    print("largest " + ", ".join(f"{k} {v:.3f}" for k, v in worst.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
