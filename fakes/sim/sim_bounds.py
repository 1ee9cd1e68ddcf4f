"""What ``station simulate`` accepts: the ranges a plant would ask for, each refusal naming the option.

A simulated file is bounded like a measured one: at most :data:`MAX_SAMPLES`
tracker samples in one stream, run lengths a test cell records, seeds of 32
bits. A value beyond is refused before anything is simulated or written
(:class:`~station.errors.ConfigError`, exit code 2), so no option can make the
command run for minutes, ask for gigabytes or end in a traceback.
"""

from __future__ import annotations

import math
from numbers import Integral, Real

from station.errors import ConfigError
from station.numeric import short_repr as shown

__all__ = ["MAX_SAMPLES", "SEED_MAX", "check_int", "check_real", "check_seed", "check_samples"]

#: most samples of one simulated stream: some 40-70 MB of CSV, written in about 10-25 s (a 30-cycle ISO 9283
#: run at 1000 Hz with 2 s dwells has half a million; at 3000 Hz it needs dwells under 0.3 s)
MAX_SAMPLES = 1_000_000
#: largest seed: 32 bits, as every seed the station prints
SEED_MAX = 2**32 - 1


def check_int(value, option: str, lo: int, hi: int, unit: str = "") -> int:
    """``value`` if it is an integer within ``lo``..``hi``; ConfigError naming ``option`` and the range."""
    if isinstance(value, bool) or not isinstance(value, Integral) or not lo <= value <= hi:
        raise ConfigError(f"{option} must be an integer within {lo}-{hi}{unit}, got {shown(value)}")
    return int(value)


def check_real(value, option: str, lo: float, hi: float, unit: str = "") -> float:
    """``value`` as a float if it is finite and within ``lo``..``hi``; ConfigError naming ``option`` and the range."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ConfigError(f"{option} must be a number within {lo:g}-{hi:g}{unit}, got {shown(value)}")
    v = float(value) if abs(value) < 1e300 else math.inf
    if not (math.isfinite(v) and lo <= v <= hi):
        raise ConfigError(f"{option} must be within {lo:g}-{hi:g}{unit}, got {shown(value)}")
    return v


def check_seed(value, option: str = "--seed") -> int:
    return check_int(value, option, 0, SEED_MAX)


def check_samples(n: float, what: str) -> None:
    """Refuse a stream of more than :data:`MAX_SAMPLES` samples; ``what`` says which options make ``n``."""
    if n > MAX_SAMPLES:
        raise ConfigError(f"{what} is {n:,.0f} samples; at most {MAX_SAMPLES:,} are simulated in one stream "
                          "(shorten the run or lower --rate)")
