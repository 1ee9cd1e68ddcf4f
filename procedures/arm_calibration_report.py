"""The HTML report of an arm calibration: seed 002's figures and the parameter changes."""

from __future__ import annotations

import math

import numpy as np

from station.analysis.arm.calibration import ArmCalibration
from station.models import kinematics as kin
from station.report import Report, plot_errors_before_after, plot_xy


def build_report(cal: ArmCalibration, *, title: str, facts: dict | None = None) -> Report:
    res = cal.identification
    what = "distance error" if cal.method == "distance" else "position error"
    figs = [(f"Fig. 15 (a): {what} of the training poses before and after calibration",
             plot_errors_before_after(cal.train.before_mm, cal.train.after_mm, ylabel=f"|{what}| [mm]",
                                      title="training"))]
    if cal.test is not None:
        figs.append((f"Fig. 15 (b): {what} of the test poses (not used by the fit) before and after",
                     plot_errors_before_after(cal.test.before_mm, cal.test.after_mm, ylabel=f"|{what}| [mm]",
                                              title="test")))
    it = np.arange(len(res.rmse_per_iteration))
    series = [("training residuals", it, np.asarray(res.rmse_per_iteration), "-")]
    if cal.test is not None and cal.test.rmse_per_iteration:
        series.append(("test", it, np.asarray(cal.test.rmse_per_iteration), "-"))
    figs.append(("Fig. 16: RMSE per iteration", plot_xy(series, xlabel="iteration", ylabel="RMSE [mm]",
                                                        title="convergence")))
    rows = []
    d0, d1 = kin.dh_to_degrees(cal.dh_nominal), kin.dh_to_degrees(res.dh)
    for k, name in enumerate(kin.PARAM_NAMES):
        i, j = divmod(k, 5)
        change = float(d1[i, j] - d0[i, j])
        sd = res.sigma.get(name)
        unit = "deg" if j in (1, 3, 4) else "mm"
        rows.append({"pose": name, "name": "identified" if sd is not None else "fixed",
                     "value": float(d1[i, j]), "unit": f"{unit} (change {change:+.4g}"
                     + (f" +- {sd:.2g})" if sd is not None else ")"), "limit": None, "passed": None})
    t = cal.train.to_json()
    f = {"method": cal.method, "training poses": str(cal.split.train.size), "test poses": str(cal.split.test.size),
         "condition number": f"{res.identifiability.condition_number:.1f}",
         "training mean |error|": f"{t['mean_abs_before_mm']:.4f} -> {t['mean_abs_after_mm']:.4f} mm "
                                  f"({100 * cal.train.mean_reduction:.1f} % less)"}
    if cal.test is not None:
        v = cal.test.to_json()
        f["test mean |error|"] = (f"{v['mean_abs_before_mm']:.4f} -> {v['mean_abs_after_mm']:.4f} mm "
                                  f"({100 * cal.test.mean_reduction:.1f} % less)")
    f.update(facts or {})
    notes = [f"fixed {name}: {why}" for name, why in res.identifiability.fixed.items()]
    if not res.converged:
        notes.insert(0, f"identification did not converge: {res.message}")
    if any(not math.isfinite(x) for x in res.rmse_per_iteration):
        notes.insert(0, "non-finite residuals during the iteration")
    return Report(title=title, facts=f, rows=rows, figures=figs, notes=notes)
