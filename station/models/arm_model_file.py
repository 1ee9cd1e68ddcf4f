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
from station.models.arm_ranges import number_in
from station.models.robots import RobotSpec, get_robot

__all__ = ["model_to_json", "model_from_json", "load_arm", "resolve_arm", "ResolvedArm", "ur_deltas",
           "write_ur_calibration", "read_ur_calibration"]

_JOINT_KEYS = ("a_mm", "alpha_deg", "d_mm", "theta_deg", "beta_deg")
_TOOL_KEYS = ("x_mm", "y_mm", "z_mm")
_TOP_KEYS = {"joints", "tool", "base", "joint_limits_deg", "name", "description", "effects", "gravity_model"}
#: angles in a model file beyond this (deg) are not plausible: written in radians, or a typo
_MAX_OFFSET_DEG = 360.0
#: largest model file read, bytes (a model is a few kilobytes; the whole output of `diagnose arm --json`, tens)
MAX_MODEL_BYTES = 4 << 20
#: deepest nesting of a model file (a model nests four levels; the whole output of a command a few more)
MAX_MODEL_DEPTH = 32
#: largest UR calibration file read, bytes (a [mounting] section is a few hundred)
MAX_UR_BYTES = 1 << 20


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


def _matrix(value, rows: int, cols: int | None, where: str, kind: str) -> np.ndarray:
    """A list of ``rows`` lists of ``cols`` numbers (a list of ``rows`` numbers when ``cols`` is None), screened."""
    shape = f"{rows} numbers" if cols is None else f"{rows} lists of {cols} numbers"
    if not isinstance(value, list) or len(value) != rows:
        raise ConfigError(f"{where} must be {shape}")
    if cols is None:
        return np.array([number_in(v, f"{where}[{i}]", kind) for i, v in enumerate(value)])
    out = np.zeros((rows, cols))
    for i, row in enumerate(value):
        if not isinstance(row, list) or len(row) != cols:
            raise ConfigError(f"{where} must be {shape} (row {i} is not)")
        out[i] = [number_in(v, f"{where}[{i}][{j}]", kind) for j, v in enumerate(row)]
    return out


def _text(data: dict, key: str, source: str, most: int) -> None:
    v = data.get(key)
    if v is not None and (not isinstance(v, str) or len(v) > most):
        raise ConfigError(f"{source}: '{key}' must be a text of at most {most} characters, got "
                          f"{type(v).__name__ if not isinstance(v, str) else f'{len(v)} characters'}")
    if isinstance(v, str) and any(ord(c) < 32 and c not in "\t\n" or ord(c) == 127 for c in v):
        raise ConfigError(f"{source}: '{key}' holds a control character")


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
    _text(data, "name", source, 200)
    _text(data, "description", source, 10_000)
    if data.get("gravity_model") is not None and not isinstance(data["gravity_model"], str):
        raise ConfigError(f"{source}: 'gravity_model' must be the name of a library robot")
    dh = np.zeros((7, 5))
    for i, j in enumerate(joints):
        where = f"{source}: joints[{i}]"
        _keys(j, _JOINT_KEYS, where)
        a, al, d, th, be = (_number(j[k], f"{where}.{k}") for k in _JOINT_KEYS)
        for k, v in (("alpha_deg", al), ("theta_deg", th), ("beta_deg", be)):
            if abs(v) > _MAX_OFFSET_DEG:
                raise ConfigError(f"{where}.{k} = {v:g} deg is beyond +-{_MAX_OFFSET_DEG:g} deg")
        for k, v in (("a_mm", a), ("d_mm", d)):
            number_in(v, f"{where}.{k}", "length_mm")
        dh[i] = [a, math.radians(al), d, math.radians(th), math.radians(be)]
    _keys(data.get("tool"), _TOOL_KEYS, f"{source}: tool")
    x, y, z = (number_in(data["tool"][k], f"{source}: tool.{k}", "tool_mm") for k in _TOOL_KEYS)
    dh[6] = [math.hypot(x, y), 0.0, z, math.atan2(y, x) if (x or y) else 0.0, 0.0]
    base = None
    if data.get("base") is not None:
        b = data["base"]
        _keys(b, ("rotation_matrix", "translation_mm"), f"{source}: base")
        R = _matrix(b["rotation_matrix"], 3, 3, f"{source}: base.rotation_matrix", "rotation")
        t = _matrix(b["translation_mm"], 3, None, f"{source}: base.translation_mm", "base_mm")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ConfigError(f"{source}: base.rotation_matrix is not a rotation")
        base = np.eye(4)
        base[:3, :3], base[:3, 3] = R, t
    limits = None
    if data.get("joint_limits_deg") is not None:
        lim = _matrix(data["joint_limits_deg"], 6, 2, f"{source}: joint_limits_deg", "joint_limit_deg")
        if np.any(lim[:, 0] >= lim[:, 1]):
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

    from station.readers.once import STDIN, STDIN_NAME

    p = Path(robot)
    if robot == STDIN or p.suffix.lower() == ".json" or (p.exists() and not p.is_dir()):
        # a file, standard input (``-``) or a pipe, read once
        p = Path(STDIN_NAME) if robot == STDIN else p
        if robot != STDIN and not p.exists():
            raise ConfigError(f"--robot {robot}: no such model file")
        data = _read_json_model(robot, str(p))
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


def _read_json_model(path, shown: str):
    """The JSON of a model file (a file, ``-``, a pipe), bounded in size and depth; ConfigError naming the file."""
    import re

    from station.readers.once import read_text

    try:
        text = read_text(path, MAX_MODEL_BYTES, "a model file is a few kilobytes")
    except DataError as exc:
        raise ConfigError(str(exc)) from None
    depth = 0
    for m in re.finditer(r'"(?:[^"\\]|\\.)*"|[\[{]|[\]}]', text):  # brackets outside strings
        c = m.group()[0]
        if c in "[{":
            depth += 1
            if depth > MAX_MODEL_DEPTH:
                raise ConfigError(f"{shown}: nested more than {MAX_MODEL_DEPTH} levels deep; a model nests four")
        elif c in "]}":
            depth -= 1
    try:
        # an integer of more than 30 digits is read as a float (then refused as too large), not parsed for minutes
        return json.loads(text, parse_int=lambda d: int(d) if len(d) <= 30 else float(d))
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{shown}: line {exc.lineno}: not a JSON model ({exc.msg})") from None
    except (ValueError, RecursionError) as exc:
        raise ConfigError(f"{shown}: not a JSON model ({str(exc)[:80]})") from None


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
    """The UR nominal ``dh_nominal`` (7, 5) plus the deltas of a ``calibration.conf`` file.

    Each delta is six numbers (not booleans) within what a UR arm's
    calibration holds (:mod:`station.models.arm_ranges`: angles within a
    half turn, lengths within a metre); a refusal names the file, the line and
    the key.
    """
    from station.readers.once import read_text, shown_name
    from station.readers.text import MAX_LINE_CHARS

    p = Path(shown_name(path))
    try:
        text = read_text(path, MAX_UR_BYTES, "a UR calibration file is a few hundred bytes")
    except DataError as exc:
        raise ConfigError(str(exc)) from None
    section, values = None, {}
    for lineno, raw_line in enumerate(text.splitlines(), 1):
        if len(raw_line) > MAX_LINE_CHARS:
            raise ConfigError(f"{p}:{lineno}: longer than {MAX_LINE_CHARS} characters")
        line = raw_line.split("#", 1)[0].strip()
        if not line:
            continue
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1].strip()
            continue
        if section != "mounting" or "=" not in line:
            continue
        key, _, val = (s.strip() for s in line.partition("="))
        if key in _UR_KEYS:
            values[key] = _ur_values(val, f"{p}:{lineno}: {key}", key)
    missing = [k for k in _UR_KEYS if k not in values]
    if missing:
        raise ConfigError(f"{p}: no [mounting] {', '.join(missing)}")
    dh = kin.validate_dh(dh_nominal).copy()
    dh[:6, 3] += values["delta_theta"]
    dh[:6, 0] += values["delta_a"] * 1000.0
    dh[:6, 2] += values["delta_d"] * 1000.0
    dh[:6, 1] += values["delta_alpha"]
    return dh


def _ur_values(text: str, where: str, key: str) -> np.ndarray:
    """Six numbers of one UR delta (``[ v1, ..., v6 ]``), screened; ConfigError naming ``where``."""
    try:
        arr = ast.literal_eval(text)
    except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
        raise ConfigError(f"{where} is not a list of numbers") from None
    if not isinstance(arr, (list, tuple)) or len(arr) != 6:
        raise ConfigError(f"{where} must be six numbers")
    kind = "delta_length_m" if key in ("delta_a", "delta_d") else "delta_angle_rad"
    return np.array([number_in(v, f"{where}[{i}]", kind) for i, v in enumerate(arr)])
