"""How a calibration run's figures are judged by the procedure tests."""

from __future__ import annotations

from collections.abc import Mapping


def assert_calibrated(doc: Mapping, ratio: float) -> None:
    """The held-out poses' mean error after calibration is below ``ratio`` of the error before, or, for an arm
    drawn close to its nominal geometry, below 2.5 times what the model leaves on its own training poses.

    What a kinematic model leaves on its training poses is the floor no kinematic model removes (the arm's
    non-geometric effects and the instrument's noise); on held-out poses it is larger by the held-out factor,
    about sqrt((n + p) / (n - p)), under 2 for these plans. A model that calibrates nothing fails the first
    check: its training error stays its error before.
    """
    train, test = doc["train"], doc["test"]
    assert train["mean_abs_after_mm"] < 0.5 * train["mean_abs_before_mm"], train
    bound = max(ratio * test["mean_abs_before_mm"], 2.5 * train["mean_abs_after_mm"])
    assert test["mean_abs_after_mm"] < bound, (test, train)
