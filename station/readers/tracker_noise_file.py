"""The tracker noise file (``station analyze hold --noise-out``; ``station simulate ... --tracker-noise``).

JSON of :meth:`station.models.tracker_noise.TrackerNoise.to_dict` (schema
``station.tracker_noise/1``): ``white_um``, ``wander_um``, ``wander_tau_s``,
``latency_s`` (um per coordinate, s), ``source``; a fit's details under ``fit``.
"""

from __future__ import annotations

import json
from pathlib import Path

from station.errors import ConfigError
from station.models.tracker_noise import TrackerNoise

__all__ = ["read_tracker_noise", "MAX_NOISE_FILE_BYTES"]

#: largest noise file read, bytes (a fit's file is under a kilobyte)
MAX_NOISE_FILE_BYTES = 1 << 16


def read_tracker_noise(path, option: str = "--tracker-noise") -> TrackerNoise:
    """Read a noise file; ConfigError naming ``option``, the file and the key that is wrong."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            raw = fh.read(MAX_NOISE_FILE_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{option} {p}: cannot read ({exc.strerror})") from None
    if len(raw) > MAX_NOISE_FILE_BYTES:
        raise ConfigError(f"{option} {p}: larger than {MAX_NOISE_FILE_BYTES} bytes; a noise file is a few lines")
    try:
        obj = json.loads(raw.decode("utf-8-sig"))
    except UnicodeDecodeError:
        raise ConfigError(f"{option} {p}: not UTF-8 text") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{option} {p}: line {exc.lineno}: not JSON ({exc.msg})") from None
    except (ValueError, RecursionError) as exc:
        raise ConfigError(f"{option} {p}: not JSON ({str(exc)[:80]})") from None
    return TrackerNoise.from_dict(obj, f"{option} {p}")
