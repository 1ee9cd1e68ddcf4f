"""Screening of arm measurements before a calibration or a diagnosis: enough distinct poses, no gross outlier.

A pure function (arrays in, a DataError out). It does not judge the model,
only what no model can use:

* fewer than :data:`MIN_DISTINCT_POSES` distinct joint poses (identical rows,
  all joints zero): nothing is identifiable, and the solvers spend minutes on
  a singular problem;
* measured points that do not move while the joints do;
* a single gross outlier: the measured points are tied to the nominal model's
  tool points by a rigid fit (the instrument frame, :func:`fit_rigid` of
  :mod:`station.analysis.arm.identification`), refitted without the points far
  from it; a point more than :data:`OUTLIER_MIN_MM` and
  :data:`OUTLIER_FACTOR` times the median distance away is no robot error
  (a real arm's nominal model is off by millimetres) but a wrong reflector,
  a unit or an export error. It is named, never averaged in.

Messages name the file and line when ``source`` and ``lines`` are given, else
the pose (1-based).
"""

from __future__ import annotations

import numpy as np

from station.errors import DataError

#: fewest distinct joint poses a calibration or diagnosis accepts
MIN_DISTINCT_POSES = 10
#: a measured point this far (mm) from the nominal model's, and OUTLIER_FACTOR times the median, is refused
OUTLIER_MIN_MM = 100.0
OUTLIER_FACTOR = 20.0


def _where(k: int, source, lines) -> str:
    if source is not None and lines is not None:
        return f"{source}: line {int(lines[k])}"
    return f"pose {k + 1}"


def screen_arm_poses(dh_nominal, q_rad, xyz_mm, *, source=None, lines=None) -> None:
    """Refuse arm data no calibration can use (see the module); returns None when it passes."""
    from station.analysis.arm.identification import rigid_fit
    from station.models import kinematics as kin

    q = np.asarray(q_rad, dtype=float)
    meas = np.asarray(xyz_mm, dtype=float)
    prefix = f"{source}: " if source is not None else ""
    n = q.shape[0]
    distinct = np.unique(np.round(q, 9), axis=0).shape[0]
    if distinct < n and distinct < MIN_DISTINCT_POSES:  # repeated poses (few poses alone: the methods say so)
        raise DataError(f"{prefix}only {distinct} distinct joint pose(s) among {n} rows; a calibration needs at "
                        f"least {MIN_DISTINCT_POSES} poses spread over the workspace")
    if distinct < MIN_DISTINCT_POSES:
        return
    spread = float(np.ptp(meas, axis=0).max())
    if spread < 1.0:
        raise DataError(f"{prefix}the measured points span {spread:.3g} mm while the joints move: "
                        "is the x,y,z column the tool point?")
    p = kin.tool_position(np.asarray(dh_nominal, dtype=float), q)
    keep = np.ones(n, bool)
    for _ in range(3):  # fit, drop what lies far, refit (a 10 m point pulls a plain fit by 10 m / N)
        T = rigid_fit(p[keep], meas[keep])
        r = np.linalg.norm(meas - (p @ T[:3, :3].T + T[:3, 3]), axis=1)
        med = float(np.median(r))
        new = r <= max(3.0 * med, 1e-9)
        if new.sum() < MIN_DISTINCT_POSES or np.array_equal(new, keep):
            break
        keep = new
    far = np.flatnonzero(r > max(OUTLIER_MIN_MM, OUTLIER_FACTOR * med))
    if far.size:
        k = int(far[np.argmax(r[far])])
        more = f" ({far.size} such points in all)" if far.size > 1 else ""
        raise DataError(f"{_where(k, source, lines)}: the measured point is {r[k]:.6g} mm from where the nominal "
                        f"model puts it, the median point {med:.4g} mm: a gross outlier (wrong reflector, unit, "
                        f"export?){more}; remove or correct it")
