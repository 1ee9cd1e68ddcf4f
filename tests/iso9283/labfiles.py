"""Writers of the files a lab has, for the tests: SpatialAnalyzer exports, point lists, stop lists,
registration files; and the independent reference formulas the tests check the station against."""

from __future__ import annotations

import json
from datetime import datetime, timedelta

import numpy as np

MM_PER = {"mm": 1.0, "m": 1000.0, "in": 25.4}
T0 = datetime(2024, 3, 5, 10, 15, 0)


def write_sa(path, xyz_mm, *, t_s=None, stamps=None, unit="mm", group="Stream", stray=None, frame="A::World"):
    """A SpatialAnalyzer point export of one stream group (+ a trailing stray group ``stray`` (k, 3))."""
    s = MM_PER[unit]
    lines = ["// SpatialAnalyzer Point Export", f"// Points Relative to Coordinate Frame '{frame}'",
             f"// AXES = CARTESIAN: X, Y, Z ({unit})", "// Group, Point, Index, X, Y, Z, Date Time"]
    if stamps is None and t_s is not None:
        stamps = [(T0 + timedelta(seconds=float(t))).strftime("%Y-%m-%d %H:%M:%S.%f") for t in t_s]
    for k, p in enumerate(xyz_mm):
        row = f"{group}, {group}_{k}, {k + 1}, {p[0] / s:.10f}, {p[1] / s:.10f}, {p[2] / s:.10f}"
        lines.append(row + (f", {stamps[k]}" if stamps is not None else ""))
    for k, p in enumerate([] if stray is None else stray):
        lines.append(f"Scratch, nest{k}, {k + 1}, {p[0] / s:.10f}, {p[1] / s:.10f}, {p[2] / s:.10f}"
                     + (f", {stamps[-1]}" if stamps is not None else ""))
    path.write_text("\n".join(lines) + "\n")
    return path


def write_points(path, xyz_mm, sep=" ", header=False):
    """A plain point list ``id x y z``."""
    head = (sep.join(["id", "x", "y", "z"]) + "\n") if header else ""
    path.write_text(head + "".join(sep.join([str(k + 1)] + [f"{v:.6f}" for v in p]) + "\n"
                                   for k, p in enumerate(xyz_mm)))
    return path


def write_stream_csv(path, t, xyz, status=None):
    with open(path, "w") as f:
        f.write("t,x,y,z" + (",status" if status is not None else "") + "\n")
        for i in range(t.size):  # test data writer
            f.write(f"{t[i]:.6f},{xyz[i, 0]:.6f},{xyz[i, 1]:.6f},{xyz[i, 2]:.6f}"
                    + (f",{status[i]}" if status is not None else "") + "\n")
    return path


def write_poses(path, names, poses):
    path.write_text("name,x,y,z\n" + "".join(f"{n},{float(p[0])!r},{float(p[1])!r},{float(p[2])!r}\n"
                                           for n, p in zip(names, poses)))
    return path


def write_stops(path, pose, cycle, points, reflectors=None, approach=None):
    """A stop list; ``points`` (K, R, 3)."""
    cols = ["pose", "cycle"] + (["reflector"] if reflectors else []) + (["approach"] if approach else []) + \
        ["x", "y", "z"]
    lines = [",".join(cols)]
    for k in range(len(pose)):
        for r in range(points.shape[1]):
            c = [pose[k], str(int(cycle[k]))]
            if reflectors:
                c.append(reflectors[r])
            if approach:
                c.append(approach[k])
            c += [f"{v:.9f}" for v in points[k, r]]
            lines.append(",".join(c))
    path.write_text("\n".join(lines) + "\n")
    return path


def write_registration(path, names, base, tracker):
    path.write_text("name,base_x,base_y,base_z,tracker_x,tracker_y,tracker_z\n" + "".join(
        f"{n},{b[0]:.6f},{b[1]:.6f},{b[2]:.6f},{t[0]:.6f},{t[1]:.6f},{t[2]:.6f}\n"
        for n, b, t in zip(names, base, tracker)))
    return path


def write_frame(path, R, t_mm, **extra):
    path.write_text(json.dumps({"R": np.asarray(R).tolist(), "t_mm": np.asarray(t_mm).tolist(), **extra}))
    return path


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


# --- reference formulas, written out here rather than taken from the station

def ap_ref(att, cmd):
    """Eq. (1)."""
    return float(np.sqrt(np.sum((np.mean(att, axis=0) - cmd) ** 2)))


def rp_ref(att):
    """Eq. (2): l_bar + 3 S_l."""
    c = np.mean(att, axis=0)
    l = np.sqrt(np.sum((att - c) ** 2, axis=1))
    return float(l.mean() + 3.0 * np.sqrt(np.sum((l - l.mean()) ** 2) / (len(l) - 1)))
