"""The live state of one session of a run (one process driving it).

The runner hands the session to every step as ``ctx.session``. Each procedure
subclasses :class:`Session` with typed fields for what its steps share (the
plan, the open drivers, intermediate results), so there is no dict of string
keys passed around. A resumed run is a new session: drivers are opened again,
intermediate results are rebuilt from the store.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from procedures.devices import DeviceSet


@dataclass
class Session:
    """What every procedure's session has: its device set and the drivers it opened."""

    devices: DeviceSet
    opened: dict[str, Any] = field(default_factory=dict)

    @property
    def time_scale(self) -> float:
        return self.devices.time_scale

    def device(self, role: str, **options) -> Any:
        """The driver for ``role``, opened once per session (or the injected one)."""
        self.release(role)
        drv, owned = self.devices.open(role, **options)
        if owned:
            self.opened[role] = drv
        return drv

    def release(self, role: str) -> None:
        """Close the driver this session opened for ``role`` (injected drivers are left to their owner)."""
        drv = self.opened.pop(role, None)
        if drv is not None:
            try:
                drv.close()
            except Exception:  # closing is best effort: the link may already be gone
                pass

    def close(self) -> None:
        """Close every driver this session opened."""
        for role in list(self.opened):
            self.release(role)
