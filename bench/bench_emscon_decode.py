"""Benchmark: decoding one emScon multi result (the driver's per-packet cost) with its truncation checks.

Run by hand: ``.venv/bin/python bench/bench_emscon_decode.py``.

A multi result of 100 and of 1,000 samples, as the fake streams them, followed
by the next packet (what the decoder sees while data flows); the figure is the
best of 5 repeats of 200 decodes, per decode. No assertion on time.
"""

from __future__ import annotations

import timeit

import numpy as np

from drivers.emscon_codec import decode
from fakes.emscon import _multi


def main() -> None:
    rng = np.random.default_rng(0)
    for n in (100, 1000):
        t_us = (np.arange(n) * 1000).astype(np.int64)
        xyz = rng.normal(500.0, 1.0, (n, 3))
        packet = _multi(t_us, xyz)
        buf = packet + _multi(t_us + n * 1000, xyz)
        used, _ = decode(buf)
        assert used == len(packet)
        dt = min(timeit.repeat(lambda: decode(buf), number=200, repeat=5)) / 200
        print(f"{n:5d}-sample packet: {dt * 1e6:7.1f} us per decode")


if __name__ == "__main__":
    main()
