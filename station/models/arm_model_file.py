"""Arm models as files: the station's JSON model and a UR controller's calibration deltas.

JSON model (what ``station calibrate arm --json`` writes under ``model`` and
what ``--robot FILE`` reads, so one calibration is the start of the next)::

    {"joints": [{"a_mm": 0, "alpha_deg": -90, "d_mm": 169.2, "theta_deg": 0, "beta_deg": 0}, ... six],
     "tool": {"x_mm": 0, "y_mm": 0, "z_mm": -88},
     "base": {"rotation_matrix": [[...], [...], [...]], "translation_mm": [x, y, z]},   (optional)
     "joint_limits_deg": [[lo, hi], ... six],                                           (optional)
     "name": "...", "description": "...",                                            (optional)
     "effects": [{"effect": "encoder_eccentricity", "joint": 3,
                  "params": {"s3_rad": 1e-4, "c3_rad": -2e-5}}, ...],                   (optional: extended model)
     "gravity_model": "industrial-3100"}                                               (optional: compliance's mass model)

An extended model (``station diagnose arm --model-out``) adds the named
effects in the form :mod:`station.models.arm_extended` evaluates
(``encoder_eccentricity``: ``s<j>_rad, c<j>_rad``; ``backlash``: ``b<j>_rad``;
``joint_compliance``: ``c<j>_rad_per_Nm`` (the ``gravity_model``'s masses),
``k<j>_tcp_rad_per_kg``, ``k<j>_elbow_rad_per_kg``; ``thermal_drift``:
``alpha_per_K`` with ``reference_temperature_c``, or ``dT_max_K`` with
``tau_s`` and ``t0_s``). ``station predict arm`` and ``station compensate
arm`` read both kinds; so does ``--robot`` (it uses the table).

``theta_deg`` is the offset added to the joint angle (seed 002 Table 2's
``theta_i - 90`` is ``theta_deg = -90``). The tool point is the TCP row of
the model (seed 002 eq. (3) with ``theta, d, a``: ``x = a cos theta``,
``y = a sin theta``, ``z = d``).

UR calibration (the ``[mounting]`` section of a UR controller's
``calibration.conf``): ``delta_theta``, ``delta_a``, ``delta_d``,
``delta_alpha``, six values each, in rad and m, added to the robot's nominal
DH (standard DH, no beta). :func:`ur_deltas` gives them for an identified
model; :func:`read_ur_calibration` turns such a file into a starting model.

Every reader refuses a wrong shape, a missing or unknown key (a unit in the
wrong name, ``a_m``), or a non-finite number, naming the file and the field.
"""

from __future__ import annotations

import ast
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from station.errors import ConfigError, DataError
from station.models import kinematics as kin
from station.models.robots import RobotSpec, get_robot

__all__ = ["model_to_json", "model_from_json", "load_arm", "resolve_arm", "ResolvedArm", "ur_deltas",
           "write_ur_calibration", "read_ur_calibration"]

_JOINT_KEYS = ("a_mm", "alpha_deg", "d_mm", "theta_deg", "beta_deg")
_TOOL_KEYS = ("x_mm", "y_mm", "z_mm")
_TOP_KEYS = {"joints", "tool", "base", "joint_limits_deg", "name", "description", "effects", "gravity_model"}
#: angles in a model file beyond this (deg) are not plausible: written in radians, or a typo
_MAX_OFFSET_DEG = 360.0


def model_to_json(dh, base_T=None, *, name: str | None = None, joint_limits_rad=None) -> dict:
    """The JSON model of ``dh`` (7, 5) (mm, rad) with an optional base transform (4, 4)."""
    dh = kin.validate_dh(dh)
    joints = [{"a_mm": float(r[0]), "alpha_deg": math.degrees(r[1]), "d_mm": float(r[2]),
               "theta_deg": math.degrees(r[3]), "beta_deg": math.degrees(r[4])} for r in dh[:6]]
    a, d, th = dh[6, 0], dh[6, 2], dh[6, 3]
    out = {"joints": joints, "tool": {"x_mm": float(a * math.cos(th)), "y_mm": float(a * math.sin(th)),
                                      "z_mm": float(d)}}
    if base_T is not None:
        B = np.asarray(base_T, dtype=float)
        out["base"] = {"rotation_matrix": B[:3, :3].tolist(), "translation_mm": B[:3, 3].tolist()}
    if joint_limits_rad is not None:
        out["joint_limits_deg"] = np.degrees(np.asarray(joint_limits_rad, dtype=float)).tolist()
    if name:
        out["name"] = name
    return out


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where} must be a finite number, got {value!r}")
    return float(value)


def _keys(obj, expected, where: str) -> None:
    if not isinstance(obj, dict):
        raise ConfigError(f"{where} must be an object with {', '.join(expected)}")
    unknown = sorted(set(obj) - set(expected))
    missing = [k for k in expected if k not in obj]
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)} (expected {', '.join(expected)}; "
                          f"units are part of the names)")
    if missing:
        raise ConfigError(f"{where}: missing {', '.join(missing)}")


def model_from_json(data: dict, source: str = "model") -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """``(dh (7, 5) mm/rad, base_T (4, 4) or None, joint_limits_rad (6, 2) or None)`` from a JSON model."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a model is a JSON object with 'joints' and 'tool'")
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise ConfigError(f"{source}: unknown key(s) {', '.join(unknown)} (allowed: {', '.join(sorted(_TOP_KEYS))})")
    joints = data.get("joints")
    if not isinstance(joints, list) or len(joints) != 6:
        raise ConfigError(f"{source}: 'joints' must be a list of six objects, got "
                          f"{type(joints).__name__ if not isinstance(joints, list) else f'{len(joints)} entries'}")
    dh = np.zeros((7, 5))
    for i, j in enumerate(joints):
        where = f"{source}: joints[{i}]"
        _keys(j, _JOINT_KEYS, where)
        a, al, d, th, be = (_number(j[k], f"{where}.{k}") for k in _JOINT_KEYS)
        for k, v in (("alpha_deg", al), ("theta_deg", th), ("beta_deg", be)):
            if abs(v) > _MAX_OFFSET_DEG:
                raise ConfigError(f"{where}.{k} = {v:g} deg is beyond +-{_MAX_OFFSET_DEG:g} deg")
        dh[i] = [a, math.radians(al), d, math.radians(th), math.radians(be)]
    _keys(data.get("tool"), _TOOL_KEYS, f"{source}: tool")
    x, y, z = (_number(data["tool"][k], f"{source}: tool.{k}") for k in _TOOL_KEYS)
    dh[6] = [math.hypot(x, y), 0.0, z, math.atan2(y, x) if (x or y) else 0.0, 0.0]
    base = None
    if data.get("base") is not None:
        b = data["base"]
        _keys(b, ("rotation_matrix", "translation_mm"), f"{source}: base")
        R = np.asarray(b["rotation_matrix"], dtype=float)
        t = np.asarray(b["translation_mm"], dtype=float)
        if R.shape != (3, 3) or t.shape != (3,) or not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            raise ConfigError(f"{source}: base needs a finite 3x3 rotation_matrix and 3 translation_mm")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ConfigError(f"{source}: base.rotation_matrix is not a rotation")
        base = np.eye(4)
        base[:3, :3], base[:3, 3] = R, t
    limits = None
    if data.get("joint_limits_deg") is not None:
        lim = np.asarray(data["joint_limits_deg"], dtype=float)
        if lim.shape != (6, 2) or not np.all(np.isfinite(lim)) or np.any(lim[:, 0] >= lim[:, 1]):
            raise ConfigError(f"{source}: joint_limits_deg must be six [low, high] pairs with low < high")
        limits = np.radians(lim)
    return dh, base, limits


@dataclass(frozen=True)
class ResolvedArm:
    """A library robot or a model file, resolved one way.

    ``spec`` is the library :class:`RobotSpec` (mass model, speed limits) or
    None for a model file (unless it names a ``gravity_model``); ``effects``
    the extended model's named effects (empty for a plain model).
    """

    name: str
    dh: np.ndarray
    joint_limits_rad: np.ndarray
    base_T: np.ndarray | None
    spec: RobotSpec | None
    effects: tuple = ()
    source: str = ""

    def extended(self):
        """The :class:`station.models.arm_extended.ExtendedArm` of this model."""
        from station.models.arm_extended import ExtendedArm

        return ExtendedArm(self.name, self.dh, self.base_T, self.joint_limits_rad, list(self.effects), self.spec)


def resolve_arm(robot: str) -> ResolvedArm:
    """The one resolver of ``--robot``/``--model``: a library name (``rb5-850``, ``ur5e``, ...) or a JSON model file.

    A model file is the schema above, or the whole output of ``station
    calibrate arm --json`` / ``station diagnose arm --json`` (its ``model``
    or ``extended_model``); without ``joint_limits_deg`` it gets +-360 deg.
    """
    from station.models.arm_extended import terms_from_json

    from station.readers.once import STDIN, STDIN_NAME, regular_file

    p = Path(robot)
    if robot == STDIN or p.suffix.lower() == ".json" or (p.exists() and not p.is_dir()):
        # a file, standard input (``-``) or a pipe, read once
        p = Path(STDIN_NAME) if robot == STDIN else p
        with regular_file(robot) as (real, _):
            if not Path(real).is_file():
                raise ConfigError(f"--robot {robot}: no such model file")
            try:
                data = json.loads(Path(real).read_text(encoding="utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise ConfigError(f"{p}: not a JSON model ({exc})") from None
        if isinstance(data, dict) and "joints" not in data:
            if isinstance(data.get("extended_model"), dict):
                data = data["extended_model"]  # the whole output of `station diagnose arm --json`
            elif "model" in data:
                data = data["model"]  # the whole output of `station calibrate arm --json`
        dh, base, limits = model_from_json(data, str(p))
        if limits is None:
            limits = np.tile(np.radians([-360.0, 360.0]), (6, 1))
        spec = None
        if data.get("gravity_model") is not None:
            try:
                spec = get_robot(data["gravity_model"])
            except ConfigError as exc:
                raise ConfigError(f"{p}: gravity_model: {exc}") from None
        effects = tuple(terms_from_json(data["effects"], str(p))) if data.get("effects") is not None else ()
        return ResolvedArm(str(data.get("name") or p.stem), dh, limits, base, spec, effects, str(p))
    spec = get_robot(robot)
    return ResolvedArm(spec.name, spec.dh_nominal.copy(), spec.joint_limits_rad.copy(), None, spec, (), robot)


def load_arm(robot: str) -> tuple[str, np.ndarray, np.ndarray, np.ndarray | None]:
    """``(name, dh (7, 5), joint_limits_rad (6, 2), base_T or None)``: :func:`resolve_arm` as a tuple."""
    r = resolve_arm(robot)
    return r.name, r.dh, r.joint_limits_rad, r.base_T


# ---------------------------------------------------------------------- UR calibration deltas
_UR_KEYS = ("delta_theta", "delta_a", "delta_d", "delta_alpha")


def ur_deltas(dh_identified, dh_nominal) -> dict:
    """Per-joint ``delta_theta, delta_a, delta_d, delta_alpha`` (rad, m) of the identified model.

    UR's model is standard DH (no beta): a model whose joints carry a
    non-zero beta cannot be written this way and is refused.
    """
    dh1, dh0 = kin.validate_dh(dh_identified), kin.validate_dh(dh_nominal)
    if np.any(np.abs(dh1[:6, 4]) > 1e-9):
        bad = [f"beta{i + 1}" for i in range(6) if abs(dh1[i, 4]) > 1e-9]
        raise ConfigError(f"UR calibration deltas have no beta; the model has {', '.join(bad)} "
                          f"(identify with beta fixed for a UR export)")
    d = dh1[:6] - dh0[:6]
    return {"delta_theta": d[:, 3].tolist(), "delta_a": (d[:, 0] / 1000.0).tolist(),
            "delta_d": (d[:, 2] / 1000.0).tolist(), "delta_alpha": d[:, 1].tolist()}


def write_ur_calibration(path, deltas: dict) -> None:
    """A ``calibration.conf``-style ``[mounting]`` section with the deltas (status 2: linearised)."""
    lines = ["[mounting]"]
    for k in _UR_KEYS:
        lines.append(f"{k} = [ " + ", ".join(repr(float(v)) for v in deltas[k]) + " ]")
    lines.append("calibration_status = 2")
    from station.readers.out_files import write_output

    write_output(path, "\n".join(lines) + "\n", "--ur-deltas")


def read_ur_calibration(path, dh_nominal) -> np.ndarray:
    """The UR nominal ``dh_nominal`` (7, 5) plus the deltas of a ``calibration.conf`` file."""
    from station.readers.once import STDIN, STDIN_NAME, regular_file

    p = Path(STDIN_NAME if str(path) == STDIN else path)
    try:
        with regular_file(path) as (real, _):  # a file, ``-`` or a pipe, read once
            text = Path(real).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read the UR calibration ({exc})") from None
    except DataError as exc:
        raise ConfigError(str(exc)) from None
    section, values = None, {}
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1].strip()
            continue
        if section != "mounting" or "=" not in line:
            continue
        key, _, val = (s.strip() for s in line.partition("="))
        if key in _UR_KEYS:
            try:
                arr = ast.literal_eval(val)
            except (ValueError, SyntaxError):
                raise ConfigError(f"{p}:{lineno}: {key} is not a list of numbers") from None
            arr = np.asarray(arr, dtype=float) if isinstance(arr, (list, tuple)) else np.zeros(0)
            if arr.shape != (6,) or not np.all(np.isfinite(arr)):
                raise ConfigError(f"{p}:{lineno}: {key} must be six finite numbers")
            values[key] = arr
    missing = [k for k in _UR_KEYS if k not in values]
    if missing:
        raise ConfigError(f"{p}: no [mounting] {', '.join(missing)}")
    dh = kin.validate_dh(dh_nominal).copy()
    dh[:6, 3] += values["delta_theta"]
    dh[:6, 0] += values["delta_a"] * 1000.0
    dh[:6, 2] += values["delta_d"] * 1000.0
    dh[:6, 1] += values["delta_alpha"]
    return dh
