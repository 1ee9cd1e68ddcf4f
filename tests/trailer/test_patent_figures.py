"""Reproduce the numbers of seed 003 (Figs. 8-13) with L1 = 1.25 m, L2 = 2.48 m.

How the seed generated its data (worked out from its own numbers):

* **Sampling**: 63 s at 10 Hz, ``t = 0, 0.1, ..., 63`` (631 samples) for H
  and C — the singular values mu_1 of Fig. 11 are ``||kappa||``: 3.54 for H,
  M=0.2 needs ``sum(kappa^2) = 12.5 = 631 * 0.02``, and the PM2 intercept of
  H, M=0.2 comes out as the printed -2.02e-8 only on this grid. L covers one
  period of ``0.1 t``: 631 samples over ``[0, 20 pi]`` s, so that ``kappa``
  runs from -M to +M exactly (its PM2 intercepts are ~1e-12 in Fig. 10, and
  only this grid gives the L condition numbers of Figs. 8 and 10).
* **Ideal data**: the steady state of eq. (23) (Fig. 8: every EMLS recovers
  L1, L2 exactly), not the joint-angle dynamics.
* **Noise** (Figs. 12-13): "Gaussian noise of amplitude 0.03" on both
  kappa and psi. The OLS1 slopes fix its variance through the attenuation
  ``a * var(kappa) / (var(kappa) + s^2)``: s = 0.017 in every row, i.e. a
  variance of 0.03^2/3 — that of a uniform noise of amplitude 0.03 — while a
  Gaussian of sigma 0.03 would give 3.16 instead of the printed 3.53 (H,
  M=0.1). The noisy singular values of Fig. 13 agree (3.57 = sqrt(3.545^2 +
  631 s^2)). We draw Gaussian noise of sigma 0.03/sqrt(3); the least-squares
  statistics depend on its first two moments only.
* **Combined methods** (Figs. 10-11, last column): the predicted data of step
  S140 are the model values of eq. (5) of the prediction fit; the exact
  model is fitted to them.

Small mismatches and their cause are stated next to each check.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from station.analysis.trailer.least_squares import (
    METHODS, combined_fit, exact_condition_numbers, fit_exact_model, fit_prediction_model,
)
from station.models.trailer import PATENT_NOISE_SIGMA
from tests.trailer.patent_data import patent_data

L_TRUE = np.array([1.25, 2.48])
CASES = [(k, M) for k in "HCL" for M in (0.2, 0.1)]


def _close(ours: float, printed: float, decimals: int, rel: float = 0.0) -> bool:
    return abs(ours - printed) <= 0.5 * 10.0 ** (-decimals) + rel * abs(printed) + 1e-12


# ----------------------------------------------------------------------------- Fig. 8
FIG8_OLS1 = {  # (EM1, EM2, EM3) condition numbers, eq. (17)
    ("H", 0.2): (24.91, 159.3, 78.07), ("H", 0.1): (110.8, 673.7, 337.3),
    ("C", 0.2): (41.03, 266.3, 129.6), ("C", 0.1): (188.2, 1150, 574.5),
    ("L", 0.2): (24.5, 154.6, 76.2), ("L", 0.1): (106.4, 644.4, 323.0),
}
FIG8_TLS = {  # eq. (20)
    ("H", 0.2): (16.2, 29.3, 7.35), ("H", 0.1): (134.0, 236.4, 59.86),
    ("C", 0.2): (21.0, 38.4, 9.58), ("C", 0.1): (176.3, 311.7, 78.9),
    ("L", 0.2): (19.1, 34.3, 8.62), ("L", 0.1): (156.2, 275.0, 69.7),
}


def _decimals(x: float) -> int:
    s = repr(x)
    return len(s.split(".")[1]) if "." in s else 0


@pytest.mark.parametrize("kind,M", CASES)
def test_fig8_noise_free_emls_is_exact_with_the_printed_condition_numbers(kind, M):
    """OLS1 condition numbers to the printed digits (+0.05 %); TLS ones within
    0.25 %: ours are ~0.1 % lower throughout, as if the seed's ideal joint
    angles were solved less exactly (its PM2 intercepts, e.g. 5.13e-8 for H,
    M=0.1 where the exact steady state gives 3e-10, say the same) — the TLS
    number depends on the tiny smallest singular value of [A Y]."""
    kappa, psi = patent_data(kind, M)
    for method in ("OLS1", "TLS"):
        for model in ("EM1", "EM2", "EM3"):
            fit = fit_exact_model(kappa, psi, model, method)
            np.testing.assert_allclose([fit.L1_m, fit.L2_m], L_TRUE, atol=1e-9)
    for method, table, rel in (("OLS1", FIG8_OLS1, 5e-4), ("TLS", FIG8_TLS, 2.5e-3)):
        conds = exact_condition_numbers(kappa, psi, method)
        for model, printed in zip(("EM1", "EM2", "EM3"), table[kind, M]):
            ours = float(conds[model])
            assert _close(ours, printed, _decimals(printed), rel), (method, model, ours, printed)


# ----------------------------------------------------------------------------- Figs. 10-11
FIG10_SLOPE = {("H", 0.2): 3.733, ("H", 0.1): 3.730, ("C", 0.2): 3.737, ("C", 0.1): 3.730,
               ("L", 0.2): 3.732, ("L", 0.1): 3.730}
FIG11_SLOPE = {**FIG10_SLOPE, ("C", 0.2): 3.734}
FIG10_COND = {  # OLS1(PM2), OLS2(PM2), TLS(PM2)
    ("H", 0.2): (7.09, 1.90, 1.09), ("H", 0.1): (14.2, 3.80, 2.18),
    ("C", 0.2): (23.1, 8.69, 3.51), ("C", 0.1): (45.2, 13.4, 6.92),
    ("L", 0.2): (8.65, 2.32, 1.33), ("L", 0.1): (17.3, 4.64, 2.66),
}
FIG11_MU1 = {  # OLS1(PM1) mu_1 = ||kappa||, OLS2(PM1) mu_1 = ||psi||, TLS(PM1) condition number
    ("H", 0.2): (3.54, 13.22, 1.09), ("H", 0.1): (1.77, 6.61, 2.18),
    ("C", 0.2): (4.60, 17.19, 0.84), ("C", 0.1): (2.30, 8.58, 1.68),
    ("L", 0.2): (2.90, 10.83, 1.33), ("L", 0.1): (1.45, 5.41, 2.66),
}
FIG10_CLS = {  # estimation error %, [dL1, dL2], for PM2 (Fig. 10) and PM1 (Fig. 11)
    ("PM2", "H", 0.2): (1.9, -0.8), ("PM2", "H", 0.1): (0.04, -0.02),
    ("PM2", "C", 0.2): (1.2, -0.5), ("PM2", "C", 0.1): (0.09, -0.04),
    ("PM2", "L", 0.2): (1.6, -0.7), ("PM2", "L", 0.1): (-0.02, 0.01),
    ("PM1", "H", 0.2): (1.9, -0.8), ("PM1", "H", 0.1): (0.04, -0.02),
    ("PM1", "C", 0.2): (2.3, -0.9), ("PM1", "C", 0.1): (0.11, -0.05),
    ("PM1", "L", 0.2): (1.6, -0.7), ("PM1", "L", 0.1): (-0.02, 0.01),
}


@pytest.mark.parametrize("kind,M", CASES)
def test_figs10_11_noise_free_pmls_slopes_and_condition_numbers(kind, M):
    """Slopes 3.73 to the printed three decimals for all six PMLS; PM2
    condition numbers (eq. (17), (20)) to the printed digits; the mu_1 of
    Fig. 11 within 0.3 % (the seed's noise-free column is 0.1-0.4 % below
    ``||kappa||`` and ``||psi||`` on its own grid, whereas its noisy Fig. 13
    column equals ours plus the noise power, e.g. 4.62 = sqrt(4.607^2 + 0.19))."""
    kappa, psi = patent_data(kind, M)
    for model, slopes in (("PM2", FIG10_SLOPE), ("PM1", FIG11_SLOPE)):
        for method in ("OLS1", "OLS2", "TLS"):
            fit = fit_prediction_model(kappa, psi, model, method)
            assert _close(float(fit.a), slopes[kind, M], 3), (model, method, float(fit.a))
    for method, printed in zip(("OLS1", "OLS2", "TLS"), FIG10_COND[kind, M]):
        cond = float(fit_prediction_model(kappa, psi, "PM2", method).condition_number)
        assert _close(cond, printed, _decimals(printed), 2e-3), (method, cond, printed)
    mu_k = float(fit_prediction_model(kappa, psi, "PM1", "OLS1").singular_values[0])
    mu_p = float(fit_prediction_model(kappa, psi, "PM1", "OLS2").singular_values[0])
    cond_tls = float(fit_prediction_model(kappa, psi, "PM1", "TLS").condition_number)
    printed = FIG11_MU1[kind, M]
    assert mu_k == pytest.approx(printed[0], rel=3e-3)
    assert mu_p == pytest.approx(printed[1], rel=3e-3)
    assert _close(cond_tls, printed[2], 2, 2e-3)


def test_fig10_intercepts():
    """PM2 intercepts: H, M=0.2 -2.02e-8 and C, M=0.2 -5.35e-4 as printed;
    the others are below 1e-5 here as there (their exact tiny values, e.g.
    5.13e-8 or 1.38e-12, follow the seed's equation solver, not the model)."""
    kappa, psi = patent_data("H", 0.2)
    b = float(fit_prediction_model(kappa, psi, "PM2", "OLS1").b)
    assert b == pytest.approx(-2.02e-8, abs=0.006e-8)
    kappa, psi = patent_data("C", 0.2)
    for method, printed in (("OLS1", -5.35e-4), ("OLS2", -5.36e-4), ("TLS", -5.36e-4)):
        assert float(fit_prediction_model(kappa, psi, "PM2", method).b) == pytest.approx(printed, abs=0.006e-4)
    for kind, M in (("H", 0.1), ("C", 0.1), ("L", 0.2), ("L", 0.1)):
        kappa, psi = patent_data(kind, M)
        assert abs(float(fit_prediction_model(kappa, psi, "PM2", "TLS").b)) < 1e-5


@pytest.mark.parametrize("kind,M", CASES)
def test_figs10_11_combined_estimation_errors(kind, M):
    """All 24 combined methods of Table 3 on ideal data: the percentage errors
    of Figs. 10-11 to the printed digits. (Noise-free, the three prediction
    least squares agree, so the seed prints one value per row.)"""
    kappa, psi = patent_data(kind, M)
    decimals = 1 if M == 0.2 else 2
    for name, spec in METHODS.items():
        fit = combined_fit(kappa, psi, name)
        err = 100.0 * (np.array([float(fit.L1_m), float(fit.L2_m)]) - L_TRUE) / L_TRUE
        printed = FIG10_CLS[spec.pm_model, kind, M]
        for e, p in zip(err, printed):
            assert abs(e - p) <= 0.6 * 10.0 ** (-decimals), (name, kind, M, err, printed)


# ----------------------------------------------------------------------------- Figs. 12-13
#: (model, method) -> {(kind, M): (mean, sd)} of the slope a, 10 noisy repetitions
FIG12_13_SLOPE = {
    ("PM2", "OLS1"): {("H", 0.2): (3.68, 0.01), ("H", 0.1): (3.53, 0.04), ("C", 0.2): (3.24, 0.06),
                      ("C", 0.1): (2.33, 0.03), ("L", 0.2): (3.64, 0.01)},
    ("PM2", "OLS2"): {("H", 0.2): (3.74, 0.02), ("H", 0.1): (3.76, 0.05), ("C", 0.2): (3.76, 0.06),
                      ("C", 0.1): (3.86, 0.12), ("L", 0.2): (3.73, 0.01), ("L", 0.1): (3.76, 0.04)},
    ("PM2", "TLS"): {("H", 0.2): (3.74, 0.02), ("H", 0.1): (3.75, 0.05), ("C", 0.2): (3.72, 0.06),
                     ("C", 0.1): (3.70, 0.11), ("L", 0.2): (3.72, 0.01), ("L", 0.1): (3.73, 0.04)},
    ("PM1", "OLS1"): {("H", 0.2): (3.68, 0.01), ("H", 0.1): (3.52, 0.04), ("C", 0.2): (3.71, 0.02),
                      ("C", 0.1): (3.59, 0.03), ("L", 0.2): (3.64, 0.01), ("L", 0.1): (3.42, 0.03)},
    ("PM1", "OLS2"): {("H", 0.2): (3.74, 0.02), ("H", 0.1): (3.75, 0.04), ("C", 0.2): (3.74, 0.02),
                      ("C", 0.1): (3.73, 0.03), ("L", 0.2): (3.73, 0.01), ("L", 0.1): (3.76, 0.04)},
    ("PM1", "TLS"): {("H", 0.2): (3.74, 0.02), ("H", 0.1): (3.73, 0.04), ("C", 0.2): (3.74, 0.02),
                     ("C", 0.1): (3.72, 0.03), ("L", 0.2): (3.72, 0.01), ("L", 0.1): (3.73, 0.04)},
}
#: Fig. 13: mu_1 of OLS1(PM1), OLS2(PM1) and the TLS(PM1) condition number, (mean, sd)
FIG13_OTHER = {
    ("H", 0.2): ((3.57, 0.01), (13.24, 0.01), (1.09, 0.01)),
    ("H", 0.1): ((1.82, 0.02), (6.62, 0.01), (2.19, 0.05)),
    ("C", 0.2): ((4.62, 0.02), (17.20, 0.01), (0.84, 0.01)),
    ("C", 0.1): ((2.35, 0.02), (8.59, 0.02), (1.67, 0.03)),
    ("L", 0.2): ((2.94, 0.01), (10.84, 0.01), (1.33, 0.01)),
    ("L", 0.1): ((1.52, 0.02), (5.43, 0.01), (2.68, 0.06)),
}
N_PATENT = 10  # the seed's repetitions (para. [0131])
R_OURS = 400   # our repetitions, to know the distribution of a 10-repetition mean
UNIT = 0.01    # the printed resolution


def _noisy(kind, M, sigma, rng, reps):
    kappa, psi = patent_data(kind, M)
    return (kappa + rng.normal(0.0, sigma, (reps, kappa.size)),
            psi + rng.normal(0.0, sigma, (reps, psi.size)))


def _consistent(printed_mean, printed_sd, values) -> tuple[bool, str]:
    """Is the seed's 10-repetition (mean, sd) a plausible draw from ``values``?

    Mean: within 4 sigma/sqrt(10) (+ half the print unit + our Monte-Carlo
    error). Sd: inside the 99.9 % band of a 9-degree-of-freedom sample sd,
    widened by half the print unit.
    """
    mu, sd = float(np.mean(values)), float(np.std(values, ddof=1))
    mean_ok = abs(printed_mean - mu) <= 4 * sd / math.sqrt(N_PATENT) + UNIT / 2 + 4 * sd / math.sqrt(values.size)
    lo = sd * math.sqrt(chi2.ppf(0.0005, N_PATENT - 1) / (N_PATENT - 1)) - UNIT / 2
    hi = sd * math.sqrt(chi2.ppf(0.9995, N_PATENT - 1) / (N_PATENT - 1)) + UNIT / 2
    return mean_ok and lo <= printed_sd <= hi, f"ours {mu:.4f} +- {sd:.4f}, printed {printed_mean} +- {printed_sd}"


@pytest.mark.parametrize("kind,M", CASES)
def test_figs12_13_noisy_slopes_means_and_spreads(kind, M):
    """Every slope mean and spread of Figs. 12-13 is a plausible 10-repetition
    draw under our noise convention (sigma = 0.03/sqrt(3)); so are Fig. 13's
    noisy mu_1 and TLS condition numbers, and Fig. 12's intercepts of
    OLS1(PM2) for the C command. Left out: Fig. 12, L, M=0.1, OLS1(PM2)
    prints 2.42 +- 0.03 where its PM1 twin prints 3.42 +- 0.03 — with a
    symmetric L command PM2 and PM1 coincide (b ~ 0), so 2.42 is a typo of
    3.42 (we get 3.42 for both). Fig. 12's condition numbers are not
    checked: several contradict the seed's own noise-free Fig. 10 (OLS2(PM2),
    H, M=0.1: 14.74 +- 3.87 against 3.80)."""
    rng = np.random.default_rng([ord(kind), int(M * 10)])
    kappa, psi = _noisy(kind, M, PATENT_NOISE_SIGMA, rng, R_OURS)
    for (model, method), table in FIG12_13_SLOPE.items():
        if (kind, M) not in table:
            continue
        fit = fit_prediction_model(kappa, psi, model, method)
        ok, msg = _consistent(*table[kind, M], fit.a)
        assert ok, (model, method, kind, M, msg)
        if (model, method) == ("PM2", "OLS1") and kind == "C":
            printed_b = {0.2: (8.93e-2, 1.00e-2), 0.1: (1.24e-1, 2.51e-3)}[M]
            b = fit.b
            assert abs(printed_b[0] - b.mean()) <= 4 * b.std() / math.sqrt(N_PATENT) + 5e-4
    if (kind, M) == ("L", 0.1):
        fit = fit_prediction_model(kappa, psi, "PM2", "OLS1")
        assert _consistent(3.42, 0.03, fit.a)[0]
    mu_k = np.linalg.norm(kappa, axis=-1)
    mu_p = np.linalg.norm(psi, axis=-1)
    cond = fit_prediction_model(kappa, psi, "PM1", "TLS").condition_number
    for values, printed in zip((mu_k, mu_p, cond), FIG13_OTHER[kind, M]):
        ok, msg = _consistent(*printed, values)
        assert ok, (kind, M, msg)


def test_figs12_13_exclude_a_gaussian_of_sigma_003():
    """The other reading of "Gaussian noise of amplitude 0.03" is refuted by
    the seed's own OLS1 slopes: with sigma = 0.03 none of the eleven OLS1
    entries is a plausible draw (attenuation ~3x too strong)."""
    rng = np.random.default_rng(7)
    refuted = 0
    for (model, method), table in FIG12_13_SLOPE.items():
        if method != "OLS1":
            continue
        for (kind, M), printed in table.items():
            kappa, psi = _noisy(kind, M, 0.03, rng, 200)
            refuted += not _consistent(*printed, fit_prediction_model(kappa, psi, model, method).a)[0]
    assert refuted == 11


FIG9 = {  # Norm(mean dL1, mean dL2), m: OLS1(EM1), OLS1(EM2), OLS1(EM3), TLS(EM1, 2, 3)
    ("H", 0.2): (1.25, 202.78, 127.17, 36.74), ("H", 0.1): (18.18, 257.39, 229.24, 244.89),
    ("C", 0.2): (1.16, 126.47, 77.86, 67.56), ("C", 0.1): (16.37, 424.86, 371.56, 366.21),
    ("L", 0.2): (1.59, 926.29, 595.57, 42.73), ("L", 0.1): (21.72, 278.88, 253.69, 251.44),
}


@pytest.mark.parametrize("kind,M", CASES)
def test_fig9_noisy_emls_errors(kind, M):
    """EMLS on noisy data (errors in metres): the seed's norm of the
    10-repetition mean error lies inside the central 98 % of ours for
    OLS1(EM1), OLS1(EM2) and TLS(EM1, 2, 3). OLS1(EM3) is not checked: the
    seed's EM3 values are a fixed fraction of its EM2 values in every row
    (0.63 at M=0.2: 127/203, 78/126, 596/926; 0.89 at M=0.1), as if derived
    from them, while EM3 fitted here gives 15-21 m at M=0.2 and 200-330 m at
    M=0.1 (the seed's 372 and 254 m for C and L fall outside that)."""
    rng = np.random.default_rng([9, ord(kind), int(M * 10)])
    groups = 100
    kappa, psi = _noisy(kind, M, PATENT_NOISE_SIGMA, rng, groups * N_PATENT)
    for j, (model, method) in enumerate((("EM1", "OLS1"), ("EM2", "OLS1"), ("EM3", "OLS1"), ("EM1", "TLS"))):
        if model == "EM3":
            continue
        fit = fit_exact_model(kappa, psi, model, method)
        dL = np.stack([fit.L1_m - 1.25, fit.L2_m - 2.48], -1).reshape(groups, N_PATENT, 2).mean(axis=1)
        norms = np.hypot(dL[:, 0], dL[:, 1])
        lo, hi = np.percentile(norms, [1, 99])
        assert lo <= FIG9[kind, M][j] <= hi, (model, method, kind, M, lo, hi, FIG9[kind, M][j])
