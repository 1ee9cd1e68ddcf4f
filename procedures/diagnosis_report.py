"""The HTML report of an arm diagnosis: residual structure before and after each selected step."""

from __future__ import annotations

import numpy as np

from station.analysis.diagnose import ArmDiagnosis
from station.analysis.diagnose.trailer import TrailerDiagnosis
from station.models import kinematics as kin
from station.report import Report, plot_xy

_ARCMIN = np.degrees(1.0) * 60.0


def _joint_error_arcmin(res: ArmDiagnosis, resid: np.ndarray, joint: int) -> np.ndarray:
    """Residual seen as an error of joint ``joint``: its component along that joint's tool-point motion."""
    q = res.variables["q_rad"]
    Jp = kin.param_jacobian(res.state.dh_nominal, q)[:, :, 5 * (joint - 1) + 3] @ res.state.R.T
    n2 = np.maximum(np.sum(Jp ** 2, axis=1), 1e-12)
    return np.sum(resid * Jp, axis=1) / n2 * _ARCMIN


def _variable(res: ArmDiagnosis, effect: str, joint):
    v = res.variables
    if effect == "encoder_eccentricity":
        return np.degrees(v["q_rad"][:, joint - 1]), f"q{joint} [deg]"
    if effect == "backlash":
        return v["last_dir"][:, joint - 1] + np.linspace(-0.15, 0.15, v["q_rad"].shape[0]), \
            f"direction of the last motion of joint {joint} (jittered)"
    if effect == "joint_compliance":
        return v["gravity_torque"][joint], f"gravity torque of joint {joint} [N m]"
    if effect == "thermal_drift" and v["t_s"] is not None:
        return np.asarray(v["t_s"]), "t [s]"
    return np.arange(v["q_rad"].shape[0]), "row"


def build_report(res: ArmDiagnosis, *, title: str, facts: dict | None = None) -> Report:
    doc = res.to_json()
    figs = []
    for k, step in enumerate(res.steps, 1):
        term = step.term
        x, xlabel = _variable(res, term.effect, term.joint)
        if term.joint is not None:
            yb = _joint_error_arcmin(res, step.resid_before, term.joint)
            ya = _joint_error_arcmin(res, step.resid_after, term.joint)
            ylabel = f"residual as joint {term.joint} error [arcmin]"
        else:
            yb = np.linalg.norm(step.resid_before, axis=1)
            ya = np.linalg.norm(step.resid_after, axis=1)
            ylabel = "|residual| [mm]"
        figs.append((f"Step {k}: {term.key}, residuals before (held-out RMS {step.heldout_rms_before:.4f} mm) "
                     f"and after ({step.heldout_rms_after:.4f} mm)",
                     plot_xy([("before", x, yb, "."), ("after", x, ya, ".")], xlabel=xlabel, ylabel=ylabel,
                             title=term.key)))
    rows = _param_rows(doc, _arm_name, 3)
    f = {"held-out RMS, simulation": f"{doc['simulation_heldout_rms']:.4f} mm",
         "held-out RMS, extended model": f"{doc['final_heldout_rms']:.4f} mm ({doc['gain_percent']:.1f} % less)",
         "noise floor": f"{doc['noise_floor']:.4f} mm (from {doc.get('noise_floor_source', '')})",
         "selection": doc.get("selection", ""),
         "poses": f"{doc['n_poses']['train']} training, {doc['n_poses']['heldout']} held-out"}
    f.update(facts or {})
    notes = _notes(doc, _arm_name)
    return Report(title=title, facts=f, rows=rows, figures=figs, notes=notes)


_TRAILER_AXES = {"link_lengths": ("kappa", "curvature [1/m]"), "curvature_gain": ("kappa", "curvature [1/m]"),
                 "hitch_angle_offset": ("t", "t [s]"),
                 "hitch_dynamics": ("kappa_rate", "curvature rate [1/(m s)]")}


def build_trailer_report(res: TrailerDiagnosis, *, title: str, facts: dict | None = None) -> Report:
    """Residuals of the joint angle before and after each step against curvature, its rate or time."""
    doc = res.to_json()
    h = res.heldout
    figs = []
    for name, label in (("kappa", "curvature [1/m]"), ("kappa_rate", "curvature rate [1/(m s)]"), ("t", "t [s]")):
        x = res.variables[name][h]
        figs.append((f"Held-out residuals against {label.split(' [')[0]}: static model and extended model",
                     plot_xy([("static model", x, res.resid_simulation[h], "."),
                              ("extended", x, res.resid_final[h], ".")],
                             xlabel=label, ylabel="psi residual [rad]", title=name)))
    for k, step in enumerate(res.steps, 1):
        var, label = _TRAILER_AXES[step.effect]
        x = res.variables[var][h]
        figs.append((f"Step {k}: {step.effect}, held-out residuals before (RMS {step.heldout_rms_before:.5f} rad) "
                     f"and after ({step.heldout_rms_after:.5f} rad)",
                     plot_xy([("before", x, step.resid_before[h], "."), ("after", x, step.resid_after[h], ".")],
                             xlabel=label, ylabel="psi residual [rad]", title=step.effect)))
    rows = _param_rows(doc, _effect_name, 5)
    f = {"held-out RMS, static model (seed 003 eq. (23))": f"{doc['simulation_heldout_rms']:.5f} rad",
         "held-out RMS, extended model": f"{doc['final_heldout_rms']:.5f} rad ({doc['gain_percent']:.1f} % less)",
         "noise floor": f"{doc['noise_floor']:.5f} rad",
         "samples": f"{doc['n_samples']['train']} training, {doc['n_samples']['heldout']} held-out"}
    f.update(facts or {})
    notes = _notes(doc, _effect_name)
    return Report(title=title, facts=f, rows=rows, figures=figs, notes=notes)


def _arm_name(d: dict) -> str:
    return f"{d['effect']}[{d['joint']}]"


def _effect_name(d: dict) -> str:
    return d["effect"]


def _param_rows(doc: dict, name_of, digits: int) -> list[dict]:
    """One report row per parameter of each selected step, with its 95 % interval."""
    rows = []
    for k, s in enumerate(doc["steps"], 1):
        label = f"{k}. " + (name_of(s) if s.get("joint") else s["effect"])
        for name, val in s["params"].items():
            ci = s["ci"].get(name)
            rows.append({"pose": label, "name": name, "value": val,
                         "unit": "" if ci is None else f"95 % CI [{ci[0]:.{digits}g}, {ci[1]:.{digits}g}]",
                         "limit": None, "passed": None})
    return rows


def _notes(doc: dict, name_of) -> list[str]:
    """Ambiguous pairs and candidates that could not be tested, as report notes."""
    notes = [f"{name_of(s)} and {name_of(a)} explain the same residual ({100 * a['share_of_residual_explained']:.0f} % "
             f"as much alone): the data cannot tell them apart" for s in doc["steps"] for a in s["ambiguous_with"]]
    notes += [f"{name_of(s)} told apart from {name_of(a)}: {a['note']}" for s in doc["steps"]
              for a in s.get("told_apart_from", [])]
    return notes + [f"not testable: {k}: {why}" for k, why in doc["not_testable"].items()]

