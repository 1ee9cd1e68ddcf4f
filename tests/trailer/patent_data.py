"""The seed's sampling grids and ideal data (shared by the trailer tests)."""

from __future__ import annotations

import numpy as np

from station.models.trailer import command_curvature, steady_state_psi

#: the seed's simulations: 63 s sampled at 10 Hz (631 samples); see test_patent_figures
N_SAMPLES = 631


def patent_time(kind: str) -> np.ndarray:
    """Sample times that reproduce the seed's figures.

    H and C: ``t = 0, 0.1, ..., 63`` s. L: 631 samples over ``[0, 20 pi]`` s
    (one period of ``0.1 t``, so ``kappa`` runs from ``-M`` to ``+M``
    exactly) — the only grid that reproduces the L rows of Figs. 8, 10, 11.
    """
    if kind == "L":
        return np.linspace(0.0, 20.0 * np.pi, N_SAMPLES)
    return np.arange(N_SAMPLES) * 0.1


def patent_data(kind: str, M: float, L1: float = 1.25, L2: float = 2.48):
    """Noise-free ``(kappa, psi)`` of the seed: the steady state of eq. (23)."""
    kappa = command_curvature(kind, M, patent_time(kind))
    return kappa, steady_state_psi(kappa, L1, L2)
