"""The drift programme's orientation figures from visits' attained angles (pure: arrays in, figures out), and
why the simulated warm-up alone gives the orientation nothing to drift."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from station.analysis.iso9283.drift_programme import DRIFT_ANGLE_KEYS, drift_figures
from station.analysis.uncertainty import Budget, angle_drift_uncertainty

#: one-sided tail of each check on drawn data
TAIL = 1e-5


def _visits(rng, c, cmd_abc, drift_abc, scatter_rad, noise_rad, n):
    """Per visit ``{"P1": (stops, times, angles)}``: the tool's angles drift by ``drift_abc[k]`` (rad) from the
    arm's own error, scatter ``scatter_rad`` per angle and read with ``noise_rad``."""
    err = rng.normal(0.0, math.radians(0.05), 3)
    out = []
    for k, d in enumerate(drift_abc):
        ang = cmd_abc + err + d + rng.normal(0.0, 1.0, (n, 3)) * math.hypot(scatter_rad, noise_rad)
        out.append({"P1": (c + 0.01 * rng.standard_normal((n, 3)), 600.0 * k + np.arange(n) * 8.0, ang)})
    return out, err


def test_orientation_drift_is_first_against_last_visit_and_holds_the_drawn_drift_within_u(rng):
    c = np.array([0.0, 1700.0, 1400.0])
    cmd = np.array([math.pi, 0.0, 0.0])  # tool down: a at the +/-180 deg seam
    step = rng.normal(0.0, math.radians(0.01), 3)  # the warm-up's turn of the tool per visit
    drifts = [k * step for k in range(4)]
    scatter, noise, n = math.radians(float(rng.uniform(1e-3, 3e-3))), math.radians(0.005), 8
    budget = Budget(angle_sd_deg=math.degrees(noise), trials=20_000, seed=int(rng.integers(2**31)))
    vs, err = _visits(rng, c, cmd, drifts, scatter, noise, n)
    visits, drift, warnings = drift_figures(vs, {"P1": c}, 0.0, budget, {"P1": cmd})
    assert not warnings
    d = drift["P1"].orientation
    assert set(DRIFT_ANGLE_KEYS) <= set(d)
    z = stats.norm.isf(TAIL / 12)
    for j, ax in enumerate("abc"):
        # |APa(t_n) - APa(t_1)|, APa the mean of the stops' angle less the commanded one (wrapped at the seam)
        dev = [v.angles_deg[:, j] for v in visits]
        ap = [float(np.mean(np.degrees(np.angle(np.exp(1j * (vs[k]["P1"][2][:, j] - cmd[j]))))))
              for k in range(len(vs))]
        assert math.isclose(d[f"dAP{ax}_deg"], abs(ap[-1] - ap[0]), abs_tol=1e-9)
        assert math.isclose(d[f"dRP{ax}_deg"], abs(visits[-1].orientation[f"RP{ax}_deg"]
                                                    - visits[0].orientation[f"RP{ax}_deg"]), abs_tol=1e-12)
        assert math.isclose(visits[0].orientation[f"RP{ax}_deg"], 3.0 * float(np.std(dev[0], ddof=1)),
                            rel_tol=1e-9)
        truth = abs(math.degrees(drifts[-1][j]))
        U = d[f"U_dAP{ax}_deg"]
        print(f"dAP{ax} {d[f'dAP{ax}_deg']:.5f} deg, U {U:.5f}, truth {truth:.5f}")
        # the two means of n stops each: U of the order of 2 sqrt(2) s / sqrt(n), and within it of the truth
        s = math.degrees(math.hypot(scatter, noise))
        assert 0.5 * s * math.sqrt(2.0 / n) < U < 8.0 * s * math.sqrt(2.0 / n)
        assert abs(d[f"dAP{ax}_deg"] - truth) <= z * s * math.sqrt(2.0 / n)
        assert abs(d[f"dAP{ax}_deg"] - truth) <= 2.0 * U  # one figure of six: k = 4
        # the stops' own scatter did not change: dRP's truth is 0, within its U
        assert d[f"dRP{ax}_deg"] <= 2.0 * d[f"U_dRP{ax}_deg"]
    # the frame's rotation is common to the visits: stated, it changes each visit's AP U, never the drift's
    rot = replace(budget, registration_rotation_cov_deg2=((4e-4, 0, 0), (0, 4e-4, 0), (0, 0, 4e-4)),
                  registration_rotation_dof=20.0)
    v2, d2, _ = drift_figures(vs, {"P1": c}, 0.0, rot, {"P1": cmd})
    assert v2[0].orientation["U_APa_deg"] > visits[0].orientation["U_APa_deg"]
    assert {k: d2["P1"].orientation[k] for k in d} == d
    # without angles (a position-only tracker) there is no orientation
    plain = [{p: e[:2] for p, e in v.items()} for v in vs]
    _, dp, _ = drift_figures(plain, {"P1": c}, 0.0, budget, {"P1": cmd})
    assert dp["P1"].orientation is None and "dAPa_deg" not in dp["P1"].to_dict()
    assert drift["P1"].to_dict()["dAPa_deg"] == round(d["dAPa_deg"], 7)


def test_orientation_drift_u_covers_drawn_drifts_at_the_stated_rate(rng):
    """Many drawn programmes of 5 stops a visit: each dAPa within U of its drawn truth at least 95 % of the
    time (a drift of a few sd, where |.| does not fold the error)."""
    c = np.array([0.0, 1700.0, 1400.0])
    cmd = np.array([math.pi, 0.0, 0.0])
    K, n = 300, 5
    outside = 0
    for _ in range(K):
        scatter, noise = math.radians(float(rng.uniform(1e-3, 3e-3))), math.radians(0.005)
        step = math.radians(0.02) * rng.choice([-1.0, 1.0], 3)
        vs, _ = _visits(rng, c, cmd, [np.zeros(3), step], scatter, noise, n)
        budget = Budget(angle_sd_deg=math.degrees(noise), trials=2000, seed=int(rng.integers(2**31)))
        _, drift, _ = drift_figures(vs, {"P1": c}, 0.0, budget, {"P1": cmd})
        j = int(rng.integers(3))
        d = drift["P1"].orientation
        outside += abs(d[f"dAP{'abc'[j]}_deg"] - math.degrees(abs(step[j]))) > d[f"U_dAP{'abc'[j]}_deg"]
    print(f"outside U: {outside}/{K}")
    assert outside <= stats.binom.isf(TAIL, K, 0.05)


def test_the_simulated_warm_up_changes_no_orientation(rng):
    """The thermal drift of the simulated arm scales the lengths of its kinematic table (a, d): the rotation
    of each link, and so the tool's orientation, does not depend on them, whatever the temperature rise. A
    drift test of the orientation needs another effect (the procedure test draws one on the wrist)."""
    from station.models import kinematics as kin
    from station.models.effects import EffectContext, EffectSet
    from station.models.robots import get_robot

    robot = get_robot("industrial-3100")
    eff = EffectSet.from_params({"thermal_drift": [float(rng.uniform(3.0, 6.0)), float(rng.uniform(900, 2400))]})
    q = np.asarray(robot.home_q_rad) + rng.normal(0.0, 0.3, (20, 6))
    poses = []
    for t in (0.0, 7200.0):
        ctx = EffectContext(robot=robot, last_dir=np.ones_like(q), warmup_s=np.full(len(q), t))
        poses.append(kin.fk(*eff.apply(robot.dh_nominal, q, ctx)))
    assert np.max(np.abs(poses[1][:, :3, :3] - poses[0][:, :3, :3])) < 1e-12
    assert np.min(np.linalg.norm(poses[1][:, :3, 3] - poses[0][:, :3, 3], axis=1)) > 1e-3  # the positions moved


def _orientation_of(dev_rad, cmd_rad):
    """The orientation figures of one pose's stops (their angles less the commanded ones, (n, 3), rad)."""
    from station.analysis.iso9283.characteristics import OrientationAR

    S, m = dev_rad.std(axis=0, ddof=1), dev_rad.mean(axis=0)
    return OrientationAR(m, 3.0 * S, cmd_rad + m, S, dev_rad.shape[0], np.arange(dev_rad.shape[0]))


def test_stops_that_agree_better_than_the_instrument_reads_do_not_state_the_mean_better_than_it(rng):
    """Five stops whose angles happen to agree within a fraction of the T-Mac's stated angle noise: the
    population sd behind them cannot be below that noise (each stop carries it), so AP's U and dAP's U are at
    least k times the noise's sd of a mean (of one visit, of the difference of two). A plain t with 4 dof on the
    small scatter would state them several times smaller."""
    from station.analysis.iso9283.uncertainty import orientation_uncertainty

    n, noise_deg = 5, 0.01
    M = 20_000
    budget = Budget(angle_sd_deg=noise_deg, trials=M, seed=int(rng.integers(2**31)))
    cmd = np.array([math.pi, 0.0, 0.0])
    frac = float(rng.uniform(0.2, 0.4))  # the stops' scatter, of the stated noise
    dev = [np.radians(noise_deg * frac * rng.standard_normal((n, 3))) for _ in range(2)]
    # the rms of M draws of sigma z with sigma >= the noise: within a few sd of the mean of z^2 (sd sqrt(2 / M))
    low = 1.0 - stats.norm.isf(TAIL) * math.sqrt(2.0 / M)
    fu = orientation_uncertainty(_orientation_of(dev[0], cmd), budget, "P1")
    for ax in "abc":
        assert fu[f"AP{ax}_deg"].U >= low * budget.k * noise_deg / math.sqrt(n), (ax, fu[f"AP{ax}_deg"])
        assert fu[f"AP{ax}_deg"].components["sampling"] == pytest.approx(noise_deg / math.sqrt(n))
    fd = angle_drift_uncertainty(np.degrees(dev[0]), np.degrees(dev[1]), budget, "P1")
    for ax in "abc":  # the two visits' means: the noise's sd of their difference (|.| folds the draws)
        assert fd[f"dAP{ax}_deg"].components["sampling"] == pytest.approx(noise_deg * math.sqrt(2.0 / n))
    # stops that scatter well above the noise: their own scatter, by the t (the floor does not enter)
    wide = np.radians(noise_deg * 3.0 * rng.standard_normal((n, 3)))
    fw = orientation_uncertainty(_orientation_of(wide, cmd), budget, "P1")
    for j, ax in enumerate("abc"):
        s = math.degrees(float(wide[:, j].std(ddof=1)))
        if s > noise_deg:
            assert fw[f"AP{ax}_deg"].components["sampling"] == pytest.approx(s / math.sqrt(n))


def test_orientation_ap_u_of_five_stops_read_with_the_instruments_noise_has_no_t_tail(rng):
    """Many poses of 5 stops whose scatter is the instrument's angle noise (a still arm, as on the fake cell):
    AP within U at least 95 % of the time, and beyond 2 U (k = 4) as rarely as a normal's 4 sd. The plain t
    with 4 dof of the stops' own scatter puts about 0.5 % of the figures beyond 2 U (a few stops that agree by
    chance); the instrument's stated noise as the floor of the population sd leaves it at the normal's rate."""
    from station.analysis.iso9283.uncertainty import orientation_uncertainty

    K, n, noise_deg = 1000, 5, 0.01
    budget = Budget(angle_sd_deg=noise_deg, trials=2000, seed=int(rng.integers(2**31)))
    cmd = np.array([math.pi, 0.0, 0.0])
    outside = beyond = 0
    for i in range(K):
        dev = np.radians(noise_deg * rng.standard_normal((n, 3)))
        fu = orientation_uncertainty(_orientation_of(dev, cmd), replace(budget, seed=budget.seed + i), "P1")
        for ax in "abc":  # the truth: 0 (the arm stands still at the commanded angles)
            e, U = abs(fu[f"AP{ax}_deg"].value), fu[f"AP{ax}_deg"].U
            outside += e > U
            beyond += e > 2.0 * U
    print(f"outside U {outside}/{3 * K}, beyond 2 U {beyond}/{3 * K}")
    assert outside <= stats.binom.isf(TAIL, 3 * K, 0.05)
    assert beyond <= stats.binom.isf(TAIL, 3 * K, 2.0 * stats.norm.sf(4.0))
