"""An arm model with named effects: evaluated at joint angles (predict) and inverted (compensate).

The kinematic table (seed 002 eq. (3), (5)) and the instrument <- base
transform of an arm model file, plus the effects a diagnosis named, each in
the linear form the diagnosis fitted (:mod:`station.analysis.diagnose.terms`):

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
    (a temperature column), or by ``1 + 1.2e-5 dT_max_K (1 - exp(-(t - t0_s) / tau_s))``.

``P = R p(dh', q + dq) + t``: the file's points are in the instrument frame
when it has a ``base``, in the robot's base frame otherwise. Lengths mm,
angles rad inside; the JSON schema is in :mod:`station.models.arm_model_file`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from station.errors import ConfigError, DataError
from station.models import kinematics as kin

__all__ = ["EffectTerm", "ExtendedArm", "terms_from_json", "terms_to_json", "motion_directions"]

STEEL_ALPHA_PER_K = 1.2e-5
_THERMAL_KEYS = ({"alpha_per_K"}, {"dT_max_K"})


@dataclass(frozen=True)
class EffectTerm:
    effect: str
    joint: int | None
    params: dict          # name -> value (file units: rad, rad per N m, rad per kg, 1/K, K)
    extra: dict = field(default_factory=dict)   # tau_s, t0_s, reference_temperature_c


def motion_directions(q_rad: np.ndarray, tol_rad: float = 1e-7) -> np.ndarray:
    """Sign of each joint's last motion (N, 6) when the rows are in motion order (0 before it first moved)."""
    q = np.asarray(q_rad, dtype=float)
    d = np.zeros_like(q)
    cur = np.zeros(q.shape[1])
    for k in range(1, q.shape[0]):
        step = q[k] - q[k - 1]
        cur = np.where(np.abs(step) > tol_rad, np.sign(step), cur)
        d[k] = cur
    return d


def _unit_mass_torques(dh, q_rad, frame_index: int) -> np.ndarray:
    from station.models.robots import GRAVITY_M_S2

    F = kin.frames(dh, q_rad)
    c = F[:, frame_index, :3, 3]
    z = F[:, :6, :3, 2]
    o = F[:, :6, :3, 3]
    tau = GRAVITY_M_S2 * 1e-3 * np.cross(z, c[:, None, :] - o)[:, :, 2]
    tau[:, frame_index:] = 0.0
    return tau


@dataclass
class ExtendedArm:
    """Table, optional base transform, named effects, and the mass model compliance needs."""

    name: str
    dh: np.ndarray
    base_T: np.ndarray | None
    joint_limits_rad: np.ndarray
    terms: list = field(default_factory=list)
    gravity_model: object = None          # RobotSpec or None

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

    def joint_offsets(self, q_rad, *, last_dir=None, load_kg=None) -> np.ndarray:
        """``dq`` (N, 6) of the joint effects at the commanded angles, rad."""
        q = np.asarray(q_rad, dtype=float)
        dq = np.zeros_like(q)
        for term in self.terms:
            if term.joint is None:
                continue
            j = term.joint - 1
            p = term.params
            if term.effect == "encoder_eccentricity":
                dq[:, j] += p[f"s{term.joint}_rad"] * np.sin(q[:, j]) + p[f"c{term.joint}_rad"] * np.cos(q[:, j])
            elif term.effect == "backlash":
                if last_dir is None:
                    raise DataError("the model has backlash: it needs each joint's direction of motion "
                                    "(rows in motion order)")
                dq[:, j] -= p[f"b{term.joint}_rad"] * np.asarray(last_dir, dtype=float)[:, j]
            elif term.effect == "joint_compliance":
                for name, v in p.items():
                    dq[:, j] -= v * self._torque_basis(name, q, load_kg)[:, j]
            else:
                raise ConfigError(f"unknown joint effect {term.effect!r}")
        return dq

    def _torque_basis(self, name: str, q, load_kg) -> np.ndarray:
        if name.endswith("_tcp_rad_per_kg"):
            return _unit_mass_torques(self.dh, q, 7)
        if name.endswith("_elbow_rad_per_kg"):
            return _unit_mass_torques(self.dh, q, 3)
        if name.endswith("_rad_per_Nm"):
            if self.gravity_model is None:
                raise ConfigError(f"{name}: the model names no gravity_model (a library robot's mass model)")
            from station.models.robots import gravity_torques

            g = gravity_torques(self.gravity_model, self.dh, q, payload_kg=0.0)
            if load_kg is not None:
                g = g + np.asarray(load_kg, dtype=float)[:, None] * _unit_mass_torques(self.dh, q, 7)
            return g
        raise ConfigError(f"joint_compliance parameter {name!r}: expected c<j>_rad_per_Nm, k<j>_tcp_rad_per_kg "
                          "or k<j>_elbow_rad_per_kg")

    def length_scale(self, n: int, *, t_s=None, temperature_c=None) -> np.ndarray | None:
        for term in self.terms:
            if term.effect != "thermal_drift":
                continue
            if "alpha_per_K" in term.params:
                if temperature_c is None:
                    raise DataError("the model has thermal drift from a temperature column: give `temperature`")
                dT = np.asarray(temperature_c, float) - term.extra.get("reference_temperature_c", 20.0)
                return term.params["alpha_per_K"] * dT
            if t_s is None:
                raise DataError("the model has a warm-up drift: give `t` (s since the arm started working)")
            t = np.maximum(np.asarray(t_s, float) - term.extra.get("t0_s", 0.0), 0.0)
            return STEEL_ALPHA_PER_K * term.params["dT_max_K"] * -np.expm1(-t / term.extra["tau_s"])
        return None

    def _table(self, n: int, scale) -> np.ndarray:
        if scale is None:
            return self.dh
        dh = np.repeat(self.dh[None], n, axis=0)
        dh[:, :, [0, 2]] *= (1.0 + scale)[:, None, None]
        return dh

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


#: the screen (:data:`station.models.arm_ranges.LIMITS`) of each effect parameter, by the end of its name
_PARAM_KINDS = (("_rad_per_Nm", "compliance"), ("_rad_per_kg", "compliance"), ("_rad", "joint_offset_rad"),
                ("alpha_per_K", "alpha_per_K"), ("dT_max_K", "dT_max_K"))


def _param_names(effect: str, joint) -> set | None:
    """The parameter names an effect of ``joint`` may have (None: thermal drift, checked on its own)."""
    if effect == "encoder_eccentricity":
        return {f"s{joint}_rad", f"c{joint}_rad"}
    if effect == "backlash":
        return {f"b{joint}_rad"}
    if effect == "joint_compliance":
        return {f"c{joint}_rad_per_Nm", f"k{joint}_tcp_rad_per_kg", f"k{joint}_elbow_rad_per_kg"}
    return None


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
        allowed = _param_names(d["effect"], joint)
        if allowed is not None and not set(params) <= allowed:
            bad = sorted(str(n)[:40] for n in set(params) - allowed)
            raise ConfigError(f"{where}: {d['effect']} of joint {joint} has the param{'s' if len(allowed) > 1 else ''} "
                              f"{', '.join(sorted(allowed))}, not {', '.join(bad)}")
        if allowed is None and not set(params) <= {"alpha_per_K", "dT_max_K"}:
            raise ConfigError(f"{where}: thermal_drift has the params alpha_per_K or dT_max_K")
        values = {}
        for name, v in params.items():
            kind = next(kd for end, kd in _PARAM_KINDS if name.endswith(end))
            values[name] = number_in(v, f"{where}.params.{name}", kind)
        extra = {key_: number_in(d[key_], f"{where}.{key_}", key_) for key_ in _EXTRA if key_ in d}
        if d["effect"] == "thermal_drift" and not ("alpha_per_K" in params or ("dT_max_K" in params
                                                                               and "tau_s" in extra)):
            raise ConfigError(f"{where}: thermal_drift needs params.alpha_per_K, or params.dT_max_K with tau_s")
        if d["effect"] == "encoder_eccentricity" and set(params) != allowed:
            raise ConfigError(f"{where}: encoder_eccentricity of joint {joint} has params s{joint}_rad, c{joint}_rad")
        out.append(EffectTerm(d["effect"], joint if d["effect"] != "thermal_drift" else None, values, extra))
    return out
