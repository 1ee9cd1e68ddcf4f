"""The uncertainty of every figure of an ISO 9283 result, and the verdicts under a decision rule.

:func:`figure_uncertainties` walks a result of the stream analysis
(:class:`~station.analysis.iso9283.Iso9283Result`) or of the stop-list
analysis (:class:`~station.analysis.stop_list.StopListResult`) and gives each
figure it can its :class:`~station.analysis.uncertainty.FigureUncertainty`;
:func:`apply_rule` puts them on the verdicts and decides each one by the rule
(:mod:`station.analysis.decision`).  Under ``simple`` every outcome is what
it was; under ``guarded`` a figure in its guard band is NOT DECIDED (the
note says why).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from station.analysis.decision import check_rule, decide
from station.characteristics import unit_of
from station.analysis.uncertainty import (
    Budget,
    FigureUncertainty,
    drift_uncertainty,
    mean_uncertainty,
    mean_uncertainty_stats,
    overshoot_uncertainty,
    path_uncertainty,
    pose_uncertainty,
    spread_uncertainty,
    three_s_uncertainty,
    three_s_uncertainty_stats,
    vap_uncertainty,
)
from station.verdict import Outcome

Key = tuple[str, str]


def figure_uncertainties(res, budget: Budget, points_by_row=None) -> dict[Key, FigureUncertainty]:
    """``{(characteristic, subject): FigureUncertainty}`` for every figure of ``res`` that has one.

    ``points_by_row`` (N, 3): the measured positions indexed by the rows the result names (stream data
    rows; for a stop list, ``res.stop_position_mm``, taken by default).  Without it vAP and POS have none.
    """
    if points_by_row is None:
        points_by_row = getattr(res, "stop_position_mm", None)
    xyz = None if points_by_row is None else np.asarray(points_by_row, dtype=float)
    out: dict[Key, FigureUncertainty] = {}

    def put(fu):
        if fu is not None:
            out[(fu.characteristic, fu.subject)] = fu

    for name, pr in res.poses.items():  # loop over poses
        acc, rep = pr.accuracy, pr.repeatability
        cmd = pr.commanded_mm if acc is not None else None
        pu = pose_uncertainty(pr.attained_mm, cmd, budget, name, AP_mm=acc.AP_mm if acc else None,
                              RP_mm=rep.RP_mm if rep else None) if pr.n_cycles else {}
        for fu in pu.values():
            put(fu)
        md = pr.multidirectional
        if xyz is not None and md.vAP_mm is not None:
            groups = [xyz[np.asarray(g.rows, dtype=np.int64)] for g in md.groups]
            put(vap_uncertainty(groups, md.vAP_mm, budget, name))
        if md.vAP_rad is not None:
            for j, ax in enumerate("abc"):
                put(spread_uncertainty(f"vAP{ax}_deg", name, [np.degrees(g.angles_rad[:, j]) for g in md.groups],
                                       math.degrees(float(md.vAP_rad[j])), budget))
        ovs = pr.overshoot
        if ovs is not None and ovs.POS_mm is not None:
            good = ~np.asarray(ovs.incomplete, dtype=bool)
            over = good & (np.asarray(ovs.POS_j_mm) > 0) & (np.asarray(ovs.row_max) >= 0)
            if xyz is not None and over.any():
                put(overshoot_uncertainty(xyz[ovs.rows[over]], xyz[ovs.row_max[over]], ovs.POS_mm, budget, name))
            if ovs.PST_s is not None:
                put(mean_uncertainty("PST_s", name, ovs.PST_j_s[good], ovs.PST_s, budget,
                                     resolution=0.0 if budget.rate_hz is None else 1.0 / budget.rate_hz))
        dr = pr.drift
        if dr is not None and dr.n_per_block.size >= 2:
            b = int(dr.n_per_block[0])
            blocks = pr.attained_mm[: dr.n_per_block.size * b].reshape(-1, b, 3)
            for fu in drift_uncertainty([blocks[0], blocks[-1]], pr.commanded_mm, dr.dAP_mm, dr.dRP_mm, budget,
                                        name).values():
                put(fu)
        if pr.orientation is not None:
            for fu in orientation_uncertainty(pr.orientation, budget, name).values():
                put(fu)
    for d in res.distances:
        subj = f"{d.pose_a}-{d.pose_b}"
        pa, pb = res.poses[d.pose_a], res.poses[d.pose_b]
        ma = pa.attained_mm.mean(axis=0) if pa.n_cycles else None
        mb = pb.attained_mm.mean(axis=0) if pb.n_cycles else None
        sys_sd = math.hypot(budget.scale_sd(), budget.systematic_scale_sd()) * float(np.mean(d.D_mm))
        put(mean_uncertainty("AD_mm", subj, d.D_mm, d.AD_mm, budget, reference=d.Dc_mm, systematic_sd=sys_sd))
        if d.RD_mm is not None and ma is not None and mb is not None:
            nv = float(budget.instrument_sd_mm(ma)) ** 2 + float(budget.instrument_sd_mm(mb)) ** 2
            put(three_s_uncertainty("RD_mm", subj, d.D_mm, d.RD_mm, budget, noise_var=nv))
    res_q = 0.0 if budget.rate_hz is None else 1.0 / budget.rate_hz
    for m in getattr(res, "posing_times", ()):
        if m.MPT_s is None:
            continue
        t = np.asarray(m.times_s, dtype=float)
        # eq. (10) averages the first n; the scatter of every posing time of the move gives its sd
        if t.size >= 4:
            put(mean_uncertainty_stats("MPT_s", f"{m.from_pose}->{m.to_pose}", float(np.mean(t[: m.n])),
                                       float(np.std(t, ddof=1)), m.n, m.MPT_s, budget, dof=t.size - 1,
                                       resolution=res_q))
    for pa in getattr(res, "paths", ()):
        if pa.crossings_mm is None:
            continue
        p0 = res.poses[pa.from_pose].commanded_mm
        p1 = res.poses[pa.to_pose].commanded_mm
        u = (p1 - p0) / max(float(np.linalg.norm(p1 - p0)), 1e-12)
        planes = p0[None, :] + pa.plane_s_mm[:, None] * u[None, :]
        for fu in path_uncertainty(pa.crossings_mm, planes, pa.AT_mm, pa.RT_mm, budget,
                                   f"{pa.from_pose}->{pa.to_pose}").values():
            put(fu)
    return out


def orientation_uncertainty(o, budget: Budget, subject: str) -> dict[str, FigureUncertainty]:
    """``{"APa_deg": ..., "RPa_deg": ..., ...}``: the uncertainties of one pose's orientation figures
    (:class:`~station.analysis.iso9283.characteristics.OrientationAR`), the keys that could be computed.

    AP per angle (the mean of the n stops' angle less the commanded one): the stops' scatter (its population
    sd no lower than the instrument's angle noise ``budget.angle_sd_deg``, which every stop carries), and the
    registered frame's rotation (:meth:`Budget.registration_angle_sd_deg` at the pose's mean orientation, with
    the degrees of freedom of its estimate), a systematic error common to the stops. RP per angle (3 S): the scatter's posterior less the instrument's
    angle noise (``budget.angle_sd_deg``); a fixed frame rotation does not change it."""
    out: dict[str, FigureUncertainty] = {}
    sd = math.radians(budget.angle_sd_deg)
    frame = budget.registration_angle_sd_deg(o.mean_rad)
    for j, ax in enumerate("abc"):
        s = float(o.S_rad[j])
        figs = []
        if o.AP_rad is not None:
            v = math.degrees(float(o.AP_rad[j]))
            figs.append(mean_uncertainty_stats(f"AP{ax}_deg", subject, v, math.degrees(s), o.n, v, budget,
                                               systematic_sd=float(frame[j]), systematic_name="registration",
                                               systematic_dof=budget.registration_rotation_dof,
                                               noise_sd=budget.angle_sd_deg))
        figs.append(three_s_uncertainty_stats(f"RP{ax}_deg", subject, math.degrees(s), o.n,
                                              math.degrees(float(o.RP_rad[j])), budget,
                                              noise_var=math.degrees(sd) ** 2))
        out.update({fu.characteristic: fu for fu in figs if fu is not None})
    return out


def apply_rule(res, uncertainties: dict[Key, FigureUncertainty], rule: str):
    """``res`` with every verdict carrying its uncertainty and decided by ``rule`` (a new result object)."""
    check_rule(rule)
    new = []
    for v in res.verdicts:
        fu = uncertainties.get((v.characteristic, v.subject))
        if v.value is None:
            new.append(replace(v, uncertainty=fu, rule=rule))
            continue
        d = decide(v.value, v.limit, None if fu is None else fu.U, rule)
        note = v.note
        if rule == "guarded":
            if fu is None:
                note = "no uncertainty for this figure: not decided under the guarded rule"
            elif d.outcome is Outcome.NOT_DECIDED:
                note = d.explain()
        new.append(replace(v, outcome=d.outcome, note=note, uncertainty=fu, rule=rule, guard_band=d.guard_band))
    extra = {"uncertainties": dict(uncertainties)} if hasattr(res, "uncertainties") else {}
    return replace(res, verdicts=tuple(new), **extra)


def verdict_uncertainty_dict(v) -> dict:
    """The keys a verdict's JSON gains under a rule: ``u_mm``, ``U_mm``, ``k``, ``rule``, ``outcome``, ..."""
    unit = unit_of(v.characteristic)
    fu = v.uncertainty
    r = _r
    d = {"rule": v.rule, "outcome": None if v.value is None else v.outcome.word,
         f"u_{unit}": None if fu is None else r(fu.u), f"U_{unit}": None if fu is None else r(fu.U),
         "k": None if fu is None else fu.k,
         "guard_band": None if v.guard_band is None else [r(v.guard_band[0]), r(v.guard_band[1])]}
    if fu is not None:
        d[f"u_gum_{unit}"] = r(fu.u_gum)
        d[f"interval_{unit}"] = [r(fu.interval[0]), r(fu.interval[1])]
        d["budget"] = {c: r(x) for c, x in fu.components.items()}
    return d


def _r(x, nd=7):
    if x is None:
        return None
    x = float(x)
    return round(x, nd) if math.isfinite(x) else None


def uncertainty_to_dict(uncertainties: dict[Key, FigureUncertainty], budget: Budget, rule: str) -> dict:
    """The JSON block ``uncertainty``: the rule, the budget and every figure's uncertainty."""
    return {"decision_rule": rule, "budget": budget.to_dict(),
            "figures": [fu.to_dict() for fu in uncertainties.values()]}


def format_uncertainty_lines(uncertainties: dict[Key, FigureUncertainty], budget: Budget, rule: str) -> list[str]:
    """Console lines: the rule, the budget, and each figure's u, U, interval (and the first-order u)."""
    b = budget
    inst = (f"{b.instrument_a_um:g} um + {b.instrument_b_um_per_m:g} um/m "
            + ("MPE (k = 2)" if b.instrument_kind == "mpe" else "sd"))
    if b.instrument_noise_um is not None:
        inst += f" systematic, reading noise {b.instrument_noise_um:g} um"
    reg = ("none" if b.registration_rms_mm is None
           else f"fit rms {b.registration_rms_mm:.4f} mm over {b.registration_n} pairs")
    if b.registration_rotation_cov_deg2 is not None:
        reg += ", rotation sd " + "/".join(f"{math.sqrt(max(b.registration_rotation_cov_deg2[i][i], 0.0)):.2g}"
                                           for i in range(3)) + " deg about x/y/z"
    lines = [f"decision rule: {rule}; uncertainty budget: instrument {inst}; registration {reg}; "
             f"temperature u {b.temperature_u_K:g} K; GUM S1 Monte Carlo, {b.trials} trials, seed {b.seed}, "
             f"k = {b.k:g}"]
    for (ch, subj), fu in uncertainties.items():
        unit = unit_of(ch)
        gum = "-" if fu.u_gum is None else f"{fu.u_gum:.4g} U {fu.U_gum:.4g}"
        flag = "" if fu.agree in (None, True) else "  (MC and first-order law differ: both shown)"
        lines.append(f"u {ch:<8} {subj:<8} {fu.value:>9.4f} u {fu.u:.4g} U {fu.U:.4g} {unit} "
                     f"[95 %: {fu.interval[0]:.4g} .. {fu.interval[1]:.4g}] first-order u {gum}{flag}")
    return lines


def with_uncertainty(res, budget: Budget, rule: str, points_by_row=None):
    """``(result decided by rule, its uncertainties, the JSON block, the console lines)``."""
    unc = figure_uncertainties(res, budget, points_by_row)
    return (apply_rule(res, unc, rule), unc, uncertainty_to_dict(unc, budget, rule),
            format_uncertainty_lines(unc, budget, rule))
