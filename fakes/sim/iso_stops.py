"""Simulated ISO 9283 stops with a known truth, for checking the stated uncertainty.

One simulated test: a robot whose attained positions at a pose scatter as
N(mu, C) (mu - commanded and C drawn at random: the true AP and RP are
known, RP by :func:`station.analysis.uncertainty.population_rp`), a tracker
standing 2-5 m away with a random MPE ``a + b R`` (every coordinate gets
Gaussian noise of sd MPE/2, as :mod:`fakes.sim.tracker`), and a registration
of the tracker to the base frame fitted on 8 fiducials of known base-frame
position measured by the same tracker.  The stops are carried into the base
frame by the fitted registration, as the station does.

With ``reading_noise_um`` the tracker is the one of :mod:`fakes.sim.tracker`
instead: its MPE is a systematic error of the session (an offset of sd
``a / 2`` per coordinate, a scale error and three angles of sd ``b / 2`` ppm
and urad, drawn once), and each reading scatters by the reading noise only
(drawn uniformly from the range, um per coordinate).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.analysis.registration import Registration, fit_rigid
from station.analysis.uncertainty import population_rp

#: commanded pose P1 and the cube corners inset by 100 mm (seed 000 Tables 1-2), base frame, mm
P1_MM = np.array([0.0, 1700.0, 1400.0])
FIDUCIALS_MM = np.array([[x, y, z] for x in (-500.0, 500.0) for y in (1200.0, 2200.0) for z in (900.0, 1900.0)])


@dataclass(frozen=True)
class SimulatedPoseTest:
    measured_mm: np.ndarray  # (n, 3) stops in the base frame (through the fitted registration)
    commanded_mm: np.ndarray  # (3,)
    AP_true_mm: float
    RP_true_mm: float
    mpe_a_um: float
    mpe_b_um_per_m: float
    registration: Registration
    fiducials_mm: np.ndarray
    reading_noise_um: float | None = None  # None: the MPE / 2 is per-reading noise


def _rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def simulate_pose_test(rng: np.random.Generator, n: int, *, sd_range_mm=(0.005, 0.05),
                       ap_range_mm=(0.0, 1.0), mpe_a_um=(5.0, 25.0), mpe_b_um_per_m=(2.0, 10.0),
                       reading_noise_um=None) -> SimulatedPoseTest:
    """One simulated AP/RP test of ``n`` cycles at P1, everything drawn from ``rng`` (``reading_noise_um``:
    a (low, high) range, um: the tracker of the module docstring's last paragraph)."""
    cmd = P1_MM.copy()
    u = rng.standard_normal(3)
    mu = cmd + rng.uniform(*ap_range_mm) * u / np.linalg.norm(u)
    A = _rotation(rng)
    C = A @ np.diag(rng.uniform(*sd_range_mm, size=3) ** 2) @ A.T
    a_um, b_um = rng.uniform(*mpe_a_um), rng.uniform(*mpe_b_um_per_m)
    # the tracker: 2-5 m from the cube centre, looking at it; its frame rotated at random
    d = rng.standard_normal(3)
    d[2] = abs(d[2]) * 0.3
    origin = cmd + rng.uniform(2000.0, 5000.0) * d / np.linalg.norm(d)
    R_tb = _rotation(rng)  # p_tracker = R_tb (p_base - origin)
    noise_um = None if reading_noise_um is None else float(rng.uniform(*reading_noise_um))
    if noise_um is not None:  # the session's error, drawn once
        off = rng.standard_normal(3) * a_um * 1e-3 / 2.0
        scale = float(rng.standard_normal()) * b_um * 1e-6 / 2.0
        w = rng.standard_normal(3) * b_um * 1e-6 / 2.0

    def measure(p_base):
        p_trk = (p_base - origin) @ R_tb.T
        if noise_um is not None:
            return p_trk + scale * p_trk + np.cross(w, p_trk) + off + rng.standard_normal(p_trk.shape) * noise_um * 1e-3
        sd = (a_um + b_um * np.linalg.norm(p_trk, axis=1) / 1000.0) / 1000.0 / 2.0
        return p_trk + rng.standard_normal(p_trk.shape) * sd[:, None]

    reg = fit_rigid(FIDUCIALS_MM, measure(FIDUCIALS_MM))
    x_true = rng.multivariate_normal(mu, C, size=n)
    measured = reg.to_base(measure(x_true))
    ap = float(np.linalg.norm(mu - cmd))
    rp = float(population_rp(np.linalg.eigvalsh(C)))
    return SimulatedPoseTest(measured, cmd, ap, rp, a_um, b_um, reg, FIDUCIALS_MM, noise_um)
