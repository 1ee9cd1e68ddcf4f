"""An arm model with named effects: evaluated at joint angles (predict) and inverted (compensate).

The kinematic table (seed 002 eq. (3), (5)) and the instrument <- base
transform of an arm model file, plus the effects a diagnosis named. The
effects are the objects of :mod:`station.models.effects` (an
:class:`~station.models.effects.EffectSet` built from the file's records,
:func:`effect_set_of`), evaluated to first order as the diagnosis fitted
them (:meth:`EffectSet.joint_offsets`, :meth:`EffectSet.length_scale`):

``encoder_eccentricity`` (joint j)
    ``dq_j = s_j sin q_j + c_j cos q_j``; params ``s{j}_rad``, ``c{j}_rad``.
``backlash`` (joint j)
    ``dq_j = -b_j d_j``, ``d_j`` the sign of joint j's last motion (rows in
    motion order, or given); param ``b{j}_rad``.
``joint_compliance`` (joint j)
    ``dq_j = -sum_k p_k g_k,j(q)`` over the gravity-torque basis named by the
    parameter: ``c{j}_rad_per_Nm`` the robot's mass model (``gravity_model``,
    with the ``load`` column as payload), ``k{j}_tcp_rad_per_kg`` 1 kg at the
    tool point, ``k{j}_elbow_rad_per_kg`` 1 kg at the elbow (frame 3 origin).
``thermal_drift``
    Lengths ``a, d`` scaled by ``1 + alpha_per_K (T - reference_temperature_c)``
    (a temperature column), or by ``1 + alpha dT_max_K (1 - exp(-(t - t0_s) / tau_s))``
    at steel's ``alpha`` (:data:`~station.models.effects.STEEL_ALPHA_PER_K`).

``P = R p(dh', q + dq) + t``: the file's points are in the instrument frame
when it has a ``base``, in the robot's base frame otherwise. Lengths mm,
angles rad inside; the JSON schema is in :mod:`station.models.arm_model_file`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from station.errors import ConfigError, DataError
from station.models import kinematics as kin
from station.models.effects import (
    COMPLIANCE_BASES,
    STEEL_ALPHA_PER_K,
    THERMAL_ALPHA,
    Backlash,
    EffectContext,
    EffectSet,
    EncoderEccentricity,
    JointCompliance,
    ThermalDrift,
    motion_directions,
    scale_lengths,
)

__all__ = ["EffectTerm", "ExtendedArm", "effect_set_of", "terms_from_json", "terms_to_json", "motion_directions"]


@dataclass(frozen=True)
class EffectTerm:
    """One effect record of a model file: effect, joint (None for thermal drift), named parameters."""

    effect: str
    joint: int | None
    params: dict          # name -> value (file units: rad, rad per N m, rad per kg, 1/K, K)
    extra: dict = field(default_factory=dict)   # tau_s, t0_s, reference_temperature_c


def _compliance_basis(terms) -> tuple:
    """The compliance basis the records' parameter names use, in :data:`COMPLIANCE_BASES` order."""
    used = set()
    for t in terms:
        if t.effect == "joint_compliance":
            for name in t.params:
                used.update(b for b, (tmpl, _) in COMPLIANCE_BASES.items() if tmpl.format(j=t.joint) == name)
    return tuple(b for b in COMPLIANCE_BASES if b in used) or ("mass_model",)


def effect_set_of(terms) -> EffectSet:
    """The :class:`EffectSet` of a model file's effect records: each record's parameters at their place in its
    effect's vector (zero elsewhere), the named effects switched on; a thermal drift from a temperature column
    carries its fitted ``alpha_per_K`` as the effect's coefficient (its parameters then unused)."""
    ecc, back, comp = EncoderEccentricity(), Backlash(), JointCompliance(basis=_compliance_basis(terms))
    vecs = {e.name: np.zeros(len(e.param_names)) for e in (ecc, back, comp)}
    index = {e.name: {n: i for i, n in enumerate(e.param_names)} for e in (ecc, back, comp)}
    options = {"joint_compliance": {"basis": comp.basis}}
    on = set()
    for t in terms:
        on.add(t.effect)
        if t.effect == "thermal_drift":
            if "alpha_per_K" in t.params:
                options["thermal_drift"] = {"alpha_per_K": float(t.params["alpha_per_K"])}
                vecs["thermal_drift"] = np.array([0.0, 3600.0])
            else:
                options["thermal_drift"] = {"alpha_per_K": STEEL_ALPHA_PER_K}
                vecs["thermal_drift"] = np.array([float(t.params["dT_max_K"]), float(t.extra["tau_s"])])
            continue
        try:
            idx = index[t.effect]
        except KeyError:
            raise ConfigError(f"unknown joint effect {t.effect!r}") from None
        for name, v in t.params.items():
            if name not in idx:
                raise ConfigError(f"{t.effect} of joint {t.joint}: unknown parameter {name!r}")
            vecs[t.effect][idx[name]] = float(v)
    return EffectSet.from_params(vecs, enabled=on, options=options)


@dataclass
class ExtendedArm:
    """Table, optional base transform, named effects, and the mass model compliance needs.

    ``terms`` are the file's effect records; :attr:`effects` the
    :class:`EffectSet` of :mod:`station.models.effects` they make, which is
    what is evaluated.
    """

    name: str
    dh: np.ndarray
    base_T: np.ndarray | None
    joint_limits_rad: np.ndarray
    terms: list = field(default_factory=list)
    gravity_model: object = None          # RobotSpec or None
    effects: EffectSet = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.effects = effect_set_of(self.terms)

    @property
    def needs(self) -> set:
        """Columns the effects need: ``direction`` (backlash), ``t`` or ``temperature``, ``load``."""
        out = set()
        for t in self.terms:
            if t.effect == "backlash":
                out.add("direction")
            if t.effect == "thermal_drift":
                out.add("temperature" if "alpha_per_K" in t.params else "t")
        return out

    def _thermal(self):
        return next((t for t in self.terms if t.effect == "thermal_drift"), None)

    def _joint_context(self, last_dir, load_kg) -> EffectContext:
        """The joint effects' context: the directions (backlash), the mass model and the load (compliance)."""
        if last_dir is None and "direction" in self.needs:
            raise DataError("the model has backlash: it needs each joint's direction of motion "
                            "(rows in motion order)")
        if self.gravity_model is None:
            for t in self.terms:
                for name in t.params:
                    if t.effect == "joint_compliance" and name.endswith("_rad_per_Nm"):
                        raise ConfigError(f"{name}: the model names no gravity_model (a library robot's mass model)")
        return EffectContext(robot=self.gravity_model, last_dir=last_dir,
                             payload_kg=0.0 if load_kg is None else np.asarray(load_kg, dtype=float))

    def _thermal_context(self, t_s, temperature_c) -> EffectContext:
        """The thermal drift's context: the rise from the reference temperature, or the time since ``t0_s``."""
        th = self._thermal()
        if th is None:
            return EffectContext()
        if "alpha_per_K" in th.params:
            if temperature_c is None:
                raise DataError("the model has thermal drift from a temperature column: give `temperature`")
            dT = np.asarray(temperature_c, float) - th.extra.get("reference_temperature_c", 20.0)
            return EffectContext(temperature_rise_K=dT)
        if t_s is None:
            raise DataError("the model has a warm-up drift: give `t` (s since the arm started working)")
        return EffectContext(warmup_s=np.asarray(t_s, float) - th.extra.get("t0_s", 0.0))

    def joint_offsets(self, q_rad, *, last_dir=None, load_kg=None) -> np.ndarray:
        """``dq`` (N, 6) of the joint effects at the commanded angles, rad."""
        q = np.asarray(q_rad, dtype=float)
        return self.effects.joint_offsets(self.dh, q, self._joint_context(last_dir, load_kg))

    def length_scale(self, n: int, *, t_s=None, temperature_c=None) -> np.ndarray | None:
        """Relative growth of the lengths (N,) of the thermal drift, None without one."""
        return self.effects.length_scale(n, self._thermal_context(t_s, temperature_c))

    def _table(self, n: int, scale) -> np.ndarray:
        if scale is None:
            return self.dh
        return scale_lengths(np.broadcast_to(self.dh, (n, 7, 5)), scale)

    def predict(self, q_rad, *, last_dir=None, t_s=None, temperature_c=None, load_kg=None) -> np.ndarray:
        """Tool points (N, 3), mm: instrument frame with a base transform, the robot's base frame without."""
        q = np.asarray(q_rad, dtype=float)
        dq = self.joint_offsets(q, last_dir=last_dir, load_kg=load_kg)
        dh = self._table(q.shape[0], self.length_scale(q.shape[0], t_s=t_s, temperature_c=temperature_c))
        p = kin.tool_position(dh, q + dq)
        if self.base_T is None:
            return p
        return p @ self.base_T[:3, :3].T + self.base_T[:3, 3]

    def compensate(self, targets_mm, q_start_rad, *, last_dir=None, t_s=None, temperature_c=None, load_kg=None,
                   tol_mm: float = 1e-4, max_iter: int = 30) -> tuple[np.ndarray, np.ndarray]:
        """Commanded joint angles (N, 6) that put the modelled tool point on ``targets_mm``, and the residual (N,) mm.

        Gauss-Newton on the joint angles from ``q_start_rad`` with the table's
        joint Jacobian (the effects' own slope in q is a small fraction of
        one and only slows the convergence), damped by halving a step that
        does not lower the error.
        """
        tgt = np.asarray(targets_mm, dtype=float)
        q = np.array(q_start_rad, dtype=float)
        n = q.shape[0]
        lim = self.joint_limits_rad
        dh = self._table(n, self.length_scale(n, t_s=t_s, temperature_c=temperature_c))
        R = np.eye(3) if self.base_T is None else self.base_T[:3, :3]

        def err(qq):
            return tgt - self.predict(qq, last_dir=last_dir, t_s=t_s, temperature_c=temperature_c, load_kg=load_kg)

        e = err(q)
        for _ in range(max_iter):
            norm = np.linalg.norm(e, axis=1)
            if np.all(norm < tol_mm):
                break
            dq_eff = self.joint_offsets(q, last_dir=last_dir, load_kg=load_kg)
            Jq = kin.joint_jacobian(dh, q + dq_eff)[:, :3, :]
            Jw = np.einsum("ij,njk->nik", R, Jq)
            JtJ = np.einsum("nki,nkj->nij", Jw, Jw) + 1e-9 * np.eye(6)
            g = np.einsum("nki,nk->ni", Jw, e)
            dq = np.linalg.solve(JtJ, g[..., None])[..., 0]
            for _half in range(8):
                q_new = np.clip(q + dq, lim[:, 0], lim[:, 1])
                e_new = err(q_new)
                better = np.linalg.norm(e_new, axis=1) <= norm
                if better.all():
                    break
                dq = np.where(better[:, None], dq, 0.5 * dq)
            q, e = q_new, e_new
        return q, np.linalg.norm(e, axis=1)


def terms_to_json(terms) -> list:
    out = []
    for t in terms:
        d = {"effect": t.effect, "params": {k: float(v) for k, v in t.params.items()}}
        if t.joint is not None:
            d["joint"] = int(t.joint)
        d.update({k: float(v) for k, v in t.extra.items()})
        out.append(d)
    return out


_EFFECTS = ("encoder_eccentricity", "backlash", "joint_compliance", "thermal_drift")
_EXTRA = ("tau_s", "t0_s", "reference_temperature_c")


def _param_specs(effect: str, joint) -> dict:
    """``{name: ParamSpec}`` an effect record of ``joint`` may have, from the effects' own vocabulary."""
    if effect == "thermal_drift":
        return {THERMAL_ALPHA.name: THERMAL_ALPHA, **{p.name: p for p in ThermalDrift().param_specs[:1]}}
    eff = {"encoder_eccentricity": EncoderEccentricity(), "backlash": Backlash(),
           "joint_compliance": JointCompliance(basis=tuple(COMPLIANCE_BASES))}[effect]
    m = len(eff.per_joint)
    return {p.name: p for p in eff.param_specs[(joint - 1) * m: joint * m]}


def terms_from_json(data, source: str) -> list:
    """The ``effects`` list of an extended model file, checked (file and field named on error).

    Each effect at most once (per joint), each parameter a number within what
    an arm has (:mod:`station.models.arm_ranges`).
    """
    from station.models.arm_ranges import MAX_EFFECTS, number_in

    if not isinstance(data, list):
        raise ConfigError(f"{source}: 'effects' must be a list of objects")
    if len(data) > MAX_EFFECTS:
        raise ConfigError(f"{source}: 'effects' lists {len(data)} effects; at most {MAX_EFFECTS} (each joint effect "
                          "once per joint, one thermal drift)")
    out, seen = [], {}
    for k, d in enumerate(data):
        where = f"{source}: effects[{k}]"
        if not isinstance(d, dict) or not isinstance(d.get("effect"), str) or d["effect"] not in _EFFECTS:
            raise ConfigError(f"{where}: 'effect' must be one of {', '.join(_EFFECTS)}")
        unknown = sorted(str(u)[:40] for u in set(d) - {"effect", "joint", "params", *_EXTRA})
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}")
        joint = d.get("joint")
        if d["effect"] != "thermal_drift" and (isinstance(joint, bool) or not isinstance(joint, int)
                                               or joint not in range(1, 7)):
            raise ConfigError(f"{where}: 'joint' must be 1..6, got {str(joint)[:40]}")
        key = (d["effect"], joint if d["effect"] != "thermal_drift" else None)
        if key in seen:
            raise ConfigError(f"{where}: {d['effect']}" + (f" of joint {joint}" if key[1] else "")
                              + f" is listed twice (also effects[{seen[key]}])")
        seen[key] = k
        params = d.get("params")
        if not isinstance(params, dict) or not params:
            raise ConfigError(f"{where}: 'params' must be an object of named numbers")
        specs = _param_specs(d["effect"], joint)
        allowed = set(specs)
        if d["effect"] != "thermal_drift" and not set(params) <= allowed:
            bad = sorted(str(n)[:40] for n in set(params) - allowed)
            raise ConfigError(f"{where}: {d['effect']} of joint {joint} has the param{'s' if len(allowed) > 1 else ''} "
                              f"{', '.join(sorted(allowed))}, not {', '.join(bad)}")
        if d["effect"] == "thermal_drift" and not set(params) <= allowed:
            raise ConfigError(f"{where}: thermal_drift has the params alpha_per_K or dT_max_K")
        values = {name: specs[name].check(v, f"{where}.params.{name}") for name, v in params.items()}
        extra = {key_: number_in(d[key_], f"{where}.{key_}", key_) for key_ in _EXTRA if key_ in d}
        if d["effect"] == "thermal_drift" and not ("alpha_per_K" in params or ("dT_max_K" in params
                                                                               and "tau_s" in extra)):
            raise ConfigError(f"{where}: thermal_drift needs params.alpha_per_K, or params.dT_max_K with tau_s")
        if d["effect"] == "encoder_eccentricity" and set(params) != allowed:
            raise ConfigError(f"{where}: encoder_eccentricity of joint {joint} has params s{joint}_rad, c{joint}_rad")
        out.append(EffectTerm(d["effect"], joint if d["effect"] != "thermal_drift" else None, values, extra))
    return out
