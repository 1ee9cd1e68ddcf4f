"""One exception root for the whole station.

Every error the station raises on purpose derives from :class:`StationError`;
where an error resembles a built-in, it also inherits that built-in so callers
that only know the built-in still catch it::

    StationError
    ├── ConfigError(ValueError)        bad configuration, named field
    ├── DataError(ValueError)          bad input data (file, array, stream)
    │   └── InsufficientDataError      too few samples/cycles for a result
    ├── SafetyError(RuntimeError)      refused by the safety gate
    ├── DeviceError(RuntimeError)      a device said no or misbehaved
    │   ├── ProtocolError              malformed frame/reply on the wire
    │   ├── DeviceFault                device reports a fault (e-stop, ...)
    │   └── DeviceNotReady             device not initialised / not ready
    ├── DeviceTimeout(TimeoutError)    a blocking call ran out of time
    └── ConnectionLost(ConnectionError) transport dropped

Third-party errors are translated at the boundary with ``raise X(...) from exc``.
"""

from __future__ import annotations


class StationError(Exception):
    """Root of every error the station raises on purpose."""


class ConfigError(StationError, ValueError):
    """A configuration value is wrong; the message names the field."""


class DataError(StationError, ValueError):
    """Input data (array, file, stream) is malformed; the message says how."""


class InsufficientDataError(DataError):
    """There are too few samples, stops or cycles for the requested result."""


class SafetyError(StationError, RuntimeError):
    """The safety gate refused a target, speed or program."""


class DeviceError(StationError, RuntimeError):
    """A device refused a request or misbehaved."""


class ProtocolError(DeviceError):
    """A frame or reply on the wire is malformed."""


class DeviceFault(DeviceError):
    """The device reports a fault (emergency stop, protective stop, ...)."""


class DeviceNotReady(DeviceError):
    """The device is not initialised or not ready to measure or move."""


class DeviceTimeout(StationError, TimeoutError):
    """A blocking call did not complete within its timeout."""


class ConnectionLost(StationError, ConnectionError):
    """The transport to a device dropped."""


class RunStateError(StationError):
    """A run was asked to do something its state does not allow (see ``station.store.RUN_TRANSITIONS``)."""


class PreflightError(ConfigError):
    """The plan cannot be run by the devices it names; nothing has moved. ``problems`` lists every reason."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = list(problems)
        super().__init__("the run cannot start; nothing moved:\n  - " + "\n  - ".join(self.problems))
