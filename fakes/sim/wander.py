"""A slow Gauss-Markov wander, drawn by index from a seed, the same however it is chunked.

The tracker's reading wander (eq. (N1) of :mod:`station.models.tracker_noise`)
is a first-order Gauss-Markov process ``g_k = phi g_(k-1) + sqrt(1 - phi^2) e_k``
with ``phi = exp(-1 / (tau rate))``, unit variance here (the caller scales
it). A sequential process would make sample ``k`` depend on every sample
before it; the fakes measure any batch of samples in any order (a resumed
run, another chunking), so the process is drawn in overlapping blocks and
faded between them:

* block process ``G_j`` (keyed ``(seed, key, j)``) is a stationary run of
  ``2 B`` samples covering indices ``[(j - 1) B, (j + 1) B)``;
* at index ``k = j B + u`` (``0 <= u < B``) the wander is
  ``cos(pi u / 2B) G_j[u + B] + sin(pi u / 2B) G_(j+1)[u]``.

``cos^2 + sin^2 = 1`` keeps the variance 1, the fade is continuous at every
block boundary, and the covariance at lag ``m`` is ``cos(pi m / 2B) phi^m``,
within ``(pi m / 2B)^2 / 2`` of the process's ``phi^m`` (a block is 4096 or
65536 samples; a correlation time is a few hundred samples).
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict

import numpy as np
from scipy.signal import lfilter

__all__ = ["WanderDraws"]


class WanderDraws:
    """Unit-variance Gauss-Markov draws (N, 3) by integer index, for one seed and correlation (in samples)."""

    def __init__(self, seed: int, tag: int, tau_samples: float, block: int, cache: int = 8) -> None:
        self.seed = int(seed)
        self.tag = int(tag)
        self.block = int(block)
        self.phi = math.exp(-1.0 / float(tau_samples)) if tau_samples > 0 else 0.0
        self._cache: OrderedDict = OrderedDict()
        self._most = int(cache)
        self._lock = threading.Lock()

    def _process(self, key: tuple, j: int) -> np.ndarray:
        ck = (key, j)
        with self._lock:
            blk = self._cache.get(ck)
            if blk is not None:
                self._cache.move_to_end(ck)
                return blk
        rng = np.random.default_rng([self.seed, self.tag, *(int(v) + (1 << 40) for v in key), j + (1 << 40)])
        first = rng.standard_normal(3)
        e = rng.standard_normal((2 * self.block, 3))
        phi = self.phi
        blk = lfilter([math.sqrt(1.0 - phi * phi)], [1.0, -phi], e, axis=0, zi=(phi * first)[None, :])[0]
        with self._lock:
            self._cache[ck] = blk
            while len(self._cache) > self._most:
                self._cache.popitem(last=False)
        return blk

    def at(self, index, key: tuple = ()) -> np.ndarray:
        """The wander (N, 3) at integer indices ``index`` (N,) of the process named ``key``."""
        k = np.asarray(index, dtype=np.int64).reshape(-1)
        B = self.block
        j = np.floor_divide(k, B)
        u = k - j * B
        out = np.empty((k.size, 3))
        for b in np.unique(j):  # one pass per block in the batch (a few)
            sel = j == b
            uu = u[sel]
            th = (0.5 * math.pi / B) * uu
            out[sel] = (np.cos(th)[:, None] * self._process(key, int(b))[uu + B]
                        + np.sin(th)[:, None] * self._process(key, int(b) + 1)[uu])
        return out
