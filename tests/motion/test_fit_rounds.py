"""A motion fit whose rounds do not converge keeps its best round and stops when a round does not improve on it
(station/analysis/motion/fit.py ``fit``). The rounds' minimiser is replaced by one that cycles between two
parameter sets, as the hour's bench saw a mode's rounds do; the RSS that judges them is the real one, on a test
stream with its loop drawn at random."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from station.analysis.motion import fit as F
from station.analysis.motion.windows import cut_windows

from .motion_stream import draw, make_stream


def test_cycling_rounds_keep_the_best_and_stop(rng, monkeypatch):
    s = make_stream(draw(rng, cycles=3))
    w = cut_windows(s.t_s, s.xyz_mm, s.poses_mm, s.names)
    good = F.Params({"servo": np.array([s.truth.servo_hz, s.truth.servo_zeta, 0.0])})
    bad = F.Params({"servo": np.array([1.3 * s.truth.servo_hz, s.truth.servo_zeta, 0.0])})
    calls = []

    def cycling(f, x0, **kw):  # a round that ends on the other point, not converged
        x = (good if len(calls) % 2 == 0 else bad).vector()
        calls.append(x)
        return SimpleNamespace(x=x, cost=0.5 * float(np.sum(f(x) ** 2)), status=0, nfev=15, success=False,
                               message="the rounds' limit")

    monkeypatch.setattr(F, "least_squares", cycling)
    q, ok, msg = F.fit(w, bad)
    assert F.rss(w, good) < F.rss(w, bad)
    np.testing.assert_allclose(q.vector(), good.vector())  # the best round, not the last one
    assert not ok and "did not lower" in msg
    assert len(calls) == 2  # good, then bad (no better: stop); not all of FIT_ROUNDS
    # a round that ends on the worse point first: kept only until the better one comes
    calls.clear()
    calls.append(None)  # the first round now ends on `bad`
    q, _, _ = F.fit(w, good)
    np.testing.assert_allclose(q.vector(), good.vector())
    assert len(calls) == 1 + 3  # bad, good (better: on), bad (no better: stop)
