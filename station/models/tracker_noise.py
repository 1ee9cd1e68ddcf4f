"""A laser tracker's reading noise, apart from its accuracy: white + slow wander + latency.

A tracker reading a reflector at rest does not scatter by its accuracy (the
maximum permissible error, MPE ``a + b R``): that is a bound on how far a
reading may lie from the truth anywhere in the volume, and within one
measurement session it is mostly a fixed error of the instrument's frame
(scale, offset, angles). From sample to sample a reading scatters far less.
Held-pose records of a Leica tracker ~3.4 m from a UR arm (issue 42) show
about 0.6 um per axis from one sample to the next, and a slow wander of 2-3 um
over a second. The model of one coordinate's reading noise is

    n(t) = w(t) + g(t)                                               (N1)

* ``w``: white, independent per sample, standard deviation ``white_um``;
* ``g``: a first-order Gauss-Markov process (a random walk pulled back to 0),
  stationary standard deviation ``wander_um`` and correlation time
  ``wander_tau_s``: ``cov(g(t), g(t + d)) = wander_um^2 exp(-|d| / tau)``.

Over a lag ``d`` the semivariogram of ``n`` is

    gamma(d) = white_um^2 + wander_um^2 (1 - exp(-d / tau))          (N2)

(for ``d`` > 0), which is what a fit to a held-pose record estimates
(:mod:`station.analysis.iso9283.tracker_noise_fit`). ``latency_s`` is the age
of the position a sample shows relative to its stamp (not measurable from a
hold: a held pose does not move).

The file form (``station analyze hold --noise-out FILE``, read by ``station
simulate ... --tracker-noise FILE`` and ``station analyze iso9283
--tracker-noise FILE`` through :func:`read_tracker_noise`) is the JSON of
:meth:`TrackerNoise.to_dict`, schema ``station.tracker_noise/1``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from station.errors import ConfigError
from station.numeric import finite_number

__all__ = ["TrackerNoise", "read_tracker_noise", "NOISE_SCHEMA", "TRACKER_NOISE_DEFAULTS", "default_tracker_noise",
           "MAX_NOISE_UM", "MAX_TAU_S", "MAX_LATENCY_S", "MAX_NOISE_FILE_BYTES"]

NOISE_SCHEMA = "station.tracker_noise/1"

#: largest white or wander sd accepted, um (a tracker's whole MPE is tens of um)
MAX_NOISE_UM = 1000.0
#: longest wander correlation time accepted, s
MAX_TAU_S = 3600.0
#: largest latency accepted, s
MAX_LATENCY_S = 1.0


@dataclass(frozen=True)
class TrackerNoise:
    """Reading noise of a tracker per coordinate (eq. (N1)): um, s.

    ``wander_tau_s`` may be None only when ``wander_um`` is 0 (no wander).
    ``source`` says where the numbers come from (a data sheet, a fit).
    """

    white_um: float
    wander_um: float = 0.0
    wander_tau_s: float | None = None
    latency_s: float = 0.0
    source: str = ""

    def __post_init__(self) -> None:
        finite_number(self.white_um, "white_um", nonneg=True, hi=MAX_NOISE_UM)
        finite_number(self.wander_um, "wander_um", nonneg=True, hi=MAX_NOISE_UM)
        finite_number(self.latency_s, "latency_s", nonneg=True, hi=MAX_LATENCY_S)
        if self.wander_tau_s is None:
            if self.wander_um > 0:
                raise ConfigError("`wander_tau_s` is needed when `wander_um` > 0 (the wander's correlation time, s)")
        else:
            finite_number(self.wander_tau_s, "wander_tau_s", positive=True, hi=MAX_TAU_S)
        if not isinstance(self.source, str):
            raise ConfigError(f"`source` must be a string, got {type(self.source).__name__}")

    @property
    def total_um(self) -> float:
        """Standard deviation of one reading about the truth (white and wander together), um."""
        return math.hypot(self.white_um, self.wander_um)

    def step_sd_um(self, dt_s: float) -> float:
        """Standard deviation of the difference of two readings ``dt_s`` apart, um (eq. (N2): ``sqrt(2 gamma)``)."""
        return math.sqrt(2.0 * self.semivariogram_um2(dt_s))

    def semivariogram_um2(self, lag_s: float) -> float:
        """Eq. (N2) at a lag > 0, um^2."""
        if self.wander_um == 0 or self.wander_tau_s is None:
            return self.white_um ** 2
        return self.white_um ** 2 + self.wander_um ** 2 * (1.0 - math.exp(-float(lag_s) / self.wander_tau_s))

    def to_dict(self) -> dict:
        return {"schema": NOISE_SCHEMA, "units": {"noise": "um per coordinate (1 sigma)", "time": "s"},
                "white_um": round(float(self.white_um), 6), "wander_um": round(float(self.wander_um), 6),
                "wander_tau_s": None if self.wander_tau_s is None else round(float(self.wander_tau_s), 6),
                "latency_s": round(float(self.latency_s), 6), "source": self.source}

    @classmethod
    def from_dict(cls, d, where: str = "tracker noise") -> "TrackerNoise":
        """Read the JSON form; a ConfigError names ``where`` and the key that is wrong or missing."""
        if not isinstance(d, dict):
            raise ConfigError(f"{where}: must be a JSON object with white_um, wander_um, wander_tau_s, latency_s")
        schema = d.get("schema", NOISE_SCHEMA)
        if schema != NOISE_SCHEMA:
            raise ConfigError(f"{where}: schema must be {NOISE_SCHEMA!r}, got {schema!r}")
        known = {"schema", "units", "white_um", "wander_um", "wander_tau_s", "latency_s", "source", "fit"}
        extra = sorted(set(d) - known)
        if extra:
            raise ConfigError(f"{where}: unknown key {extra[0]!r} (known: {', '.join(sorted(known))})")
        if "white_um" not in d:
            raise ConfigError(f"{where}: white_um is missing (the white noise per coordinate, um)")
        kw = {"white_um": d["white_um"], "wander_um": d.get("wander_um", 0.0), "wander_tau_s": d.get("wander_tau_s"),
              "latency_s": d.get("latency_s", 0.0), "source": d.get("source", "")}
        if kw["latency_s"] is None:  # a hold's fit does not measure it
            kw["latency_s"] = 0.0
        try:
            return cls(**kw)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None


#: reading noise per tracker model. ``leica``: what issue 42's held-pose records of a Leica tracker at ~3.4 m
#: show (0.6 um white sample to sample, a wander of 2-3 um over a second); data sheets do not publish these
#: figures, so this is the one measured default; ``ideal``: no reading noise (the accuracy error alone)
TRACKER_NOISE_DEFAULTS = {
    "leica": TrackerNoise(white_um=0.6, wander_um=2.0, wander_tau_s=1.0, latency_s=0.0,
                          source="Leica tracker at ~3.4 m, held-pose records of issue 42"),
    "ideal": TrackerNoise(white_um=0.0, source="no reading noise"),
}


def default_tracker_noise(name: str = "leica") -> TrackerNoise:
    """The default noise of a tracker model (:data:`TRACKER_NOISE_DEFAULTS`); ConfigError naming the known ones."""
    try:
        return TRACKER_NOISE_DEFAULTS[name]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown tracker noise model {name!r}; known: {', '.join(TRACKER_NOISE_DEFAULTS)}") from None


#: largest noise file read, bytes (a fit's file is under a kilobyte)
MAX_NOISE_FILE_BYTES = 1 << 16


def read_tracker_noise(path, option: str = "--tracker-noise") -> TrackerNoise:
    """Read a noise file (the JSON of :meth:`TrackerNoise.to_dict`, at most :data:`MAX_NOISE_FILE_BYTES`);
    ConfigError naming ``option``, the file and the key that is wrong."""
    from station.readers.text import read_small_text

    p = Path(path)
    text = read_small_text(p, MAX_NOISE_FILE_BYTES, f"{option} {p}", "a noise file is a few lines", ConfigError)
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{option} {p}: line {exc.lineno}: not JSON ({exc.msg})") from None
    except (ValueError, RecursionError) as exc:
        raise ConfigError(f"{option} {p}: not JSON ({str(exc)[:80]})") from None
    return TrackerNoise.from_dict(obj, f"{option} {p}")
