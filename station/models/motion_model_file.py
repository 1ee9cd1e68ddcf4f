"""Read a motion model file (``station diagnose motion --model-out``), checked by
:func:`station.models.motion_effects.check_motion_model`."""

from __future__ import annotations

import json

from station.errors import ConfigError
from station.models.motion_effects import MotionModel, check_motion_model
from station.readers.once import read_text, shown_name

#: largest motion model file, bytes
MAX_BYTES = 1 << 20


def read_motion_model(path) -> MotionModel:
    where = shown_name(path)
    text = read_text(path, MAX_BYTES, "a motion model file")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{where}: not JSON: {exc}") from None
    return check_motion_model(doc, where)
