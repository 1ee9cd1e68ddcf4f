"""The part of a diagnosis's JSON that the arm and the trailer share (issue keys: steps, rms, gain, noise floor)."""

from __future__ import annotations


def core_json(diag, key_of) -> dict:
    """``steps``, the held-out rms before and after, the gain, the noise floor, what remains and what is
    not testable; ``key_of(candidate)`` names a candidate in ``not_testable``."""
    last = diag.rounds[-1] if diag.rounds else []
    untestable = dict(diag.not_testable)
    for ct in last:
        if not ct.testable:
            untestable.setdefault(key_of(ct), ct.reason)
    return {
        "steps": [s.to_json() for s in diag.steps],
        "simulation_heldout_rms": diag.simulation_heldout_rms,
        "final_heldout_rms": diag.final_heldout_rms,
        "gain": diag.gain,
        "gain_percent": 100.0 * diag.gain,
        "noise_floor": diag.noise_floor,
        "remaining_structure": [ct.to_json() for ct in last],
        "not_testable": untestable,
    }
