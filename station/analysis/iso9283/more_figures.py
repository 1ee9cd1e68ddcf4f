"""The station's figures beyond the ISO 9283 pose table, one row each: static compliance (clause 10) and
exchangeability (7.8). A row says the figure's key (its unit in the name), unit, what one value is stated per,
title and formula; the modules that compute the figures and the store's rows take them from here."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Figure:
    """One figure: key (unit in the name), unit, what one value is stated per (``level``), title, formula."""

    key: str
    unit: str
    level: str
    title: str
    formula: str


#: the static compliance, one value per load direction (``+x`` ... ``-z`` of the base frame)
COMPLIANCE = Figure("compliance_mm_per_N", "mm/N", "direction", "static compliance",
                    "ISO 9283 clause 10: slope of the displacement along the load against the load")

#: the exchangeability of robots of one model: one value per pose and the largest (pose ``"all"``)
EXCHANGEABILITY = Figure("exchangeability_mm", "mm", "pose", "exchangeability",
                         "ISO 9283 7.8: largest distance between the barycentres of the robots at a pose")

FIGURES = {f.key: f for f in (COMPLIANCE, EXCHANGEABILITY)}

__all__ = ["Figure", "COMPLIANCE", "EXCHANGEABILITY", "FIGURES"]
