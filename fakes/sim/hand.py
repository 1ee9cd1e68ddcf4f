"""The simulated operator's hand of a static compliance test: it pulls on the tool when asked.

The station asks its operator for each load with a prompt of
:func:`station.analysis.iso9283.compliance.load_prompt`. :class:`SimulatedHand`
wraps the operator of a dry run on the fakes: when the wrapped operator says
yes to such a prompt, the hand applies the load to the simulated arm's TCP
(:meth:`fakes.sim.arm.SimArm.apply_tcp_force`) as a person would: along the
asked direction, with a magnitude off the asked one by a few percent (the
force gauge in the load path reads what was really applied). Any other
prompt passes through untouched.
"""

from __future__ import annotations

import numpy as np

from station.analysis.iso9283.compliance import DIRECTIONS, parse_load_prompt


class SimulatedHand:
    """An operator (``confirm(message) -> bool``) that also applies the loads it is asked for.

    Parameters
    ----------
    operator : object with ``confirm``
        Who answers the prompts (a scripted operator on the fakes).
    arm : SimArm
    rng : numpy.random.Generator
    spread : float
        Relative standard deviation of the applied load about the asked one.
    """

    def __init__(self, operator, arm, rng: np.random.Generator, *, spread: float = 0.02) -> None:
        self.operator = operator
        self.arm = arm
        self.rng = rng
        self.spread = float(spread)
        #: (direction, asked N, applied force vector N) of every load applied
        self.applied: list[tuple[str, float, np.ndarray]] = []

    def confirm(self, message: str) -> bool:
        answer = self.operator.confirm(message)
        asked = parse_load_prompt(message) if answer else None
        if asked is not None:
            direction, load = asked
            magnitude = max(0.0, load * (1.0 + self.spread * float(self.rng.normal())))
            force = magnitude * np.asarray(DIRECTIONS[direction])
            self.arm.apply_tcp_force(force)
            self.applied.append((direction, load, force))
        return answer

    def __getattr__(self, name):  # the wrapped operator's other attributes (what it was asked, ...)
        return getattr(self.operator, name)


__all__ = ["SimulatedHand"]
