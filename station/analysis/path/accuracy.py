"""Path accuracy AT and path repeatability RT (ISO 9283 clause 8.2; clause 8.3 on a reorientation).

For each normal plane i of the commanded path, the n cycles' crossings
x_ij have their barycentre x_bar_i; AT_i is its distance from the commanded
point (the path analogue of seed eq. (1)), RT_i = l_bar_i + 3 S_l,i with l_ij
the distance of x_ij from x_bar_i (seed eq. (2)). AT = max_i AT_i,
RT = max_i RT_i.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.analysis.path.mc import DEFAULT_TRIALS, from_draws
from station.analysis.path.noise import PathNoise
from station.errors import DataError


@dataclass(frozen=True)
class PathAccuracy:
    AT_mm: float
    RT_mm: float | None
    AT_i_mm: np.ndarray
    RT_i_mm: np.ndarray | None
    plane_AT: int
    plane_RT: int | None


def at_rt(crossings_mm, commanded_mm) -> PathAccuracy:
    """``crossings_mm`` (n, m, 3): n cycles' crossings of m planes; ``commanded_mm`` (m, 3). RT needs n >= 2."""
    c = np.asarray(crossings_mm, dtype=float)
    bary = c.mean(axis=0)
    at_i = np.linalg.norm(bary - commanded_mm, axis=1)
    i_at = int(np.argmax(at_i))
    if c.shape[0] < 2:
        return PathAccuracy(float(at_i[i_at]), None, at_i, None, i_at, None)
    l = np.linalg.norm(c - bary[None], axis=2)
    rt_i = l.mean(axis=0) + 3.0 * l.std(axis=0, ddof=1)
    i_rt = int(np.argmax(rt_i))
    return PathAccuracy(float(at_i[i_at]), float(rt_i[i_rt]), at_i, rt_i, i_at, i_rt)


def _batched(c, commanded):
    """AT and RT of a batch of crossings (T, n, m, 3)."""
    bary = c.mean(axis=1)
    at = np.linalg.norm(bary - commanded[None], axis=2).max(axis=1)
    l = np.linalg.norm(c - bary[:, None], axis=3)
    rt = (l.mean(axis=1) + 3.0 * l.std(axis=1, ddof=1)).max(axis=1) if c.shape[1] >= 2 else None
    return at, rt


def at_rt_uncertainty(crossings_mm, commanded_mm, normals, noise_sd_mm, acc: PathAccuracy, subject: str, *,
                      sampling_mm: float = 0.0, t_s=None, trials: int = DEFAULT_TRIALS, seed: int = 0,
                      k: float = 2.0) -> dict:
    """u and U of AT and RT: the crossings re-measured with the instrument's noise in their planes; both are
    taken back to no noise (:func:`~station.analysis.path.mc.from_draws` with ``draws2``).

    ``normals`` (m, 3) unit normals of the planes (None: noise in all three axes, e.g. a held point);
    ``noise_sd_mm`` per-coordinate sd (scalar or (n, m)), or a :class:`~station.analysis.path.noise.PathNoise`
    (white and wander); ``t_s`` (n, m) the crossings' times, along which a wander is drawn (the crossings of
    one cycle's neighbouring planes share most of it); ``sampling_mm``: the standard uncertainty a crossing
    takes from the interpolation between samples.
    """
    c = np.asarray(crossings_mm, dtype=float)
    rng = np.random.default_rng([seed, 44, 82])
    pn = noise_sd_mm if isinstance(noise_sd_mm, PathNoise) else None  # else a white sd, scalar or (n, m)
    wander = pn is not None and pn.has_wander
    if wander and t_s is None:
        raise DataError("a noise with a wander needs the crossings' times (t_s)")
    sd = np.broadcast_to(np.asarray(pn.white_mm if pn else noise_sd_mm, float), c.shape[:2])[None, :, :, None]
    nn = None if normals is None else np.asarray(normals, dtype=float)
    if wander:
        tt = np.asarray(t_s, dtype=float).reshape(-1)
        order = np.argsort(tt, kind="stable")

    def noise():
        if wander:  # one timeline: every crossing at its time
            d = np.empty((trials, tt.size, c.shape[2]))
            d[:, order] = pn.draw(rng, (trials,), tt[order], c.shape[2])
            e = d.reshape(trials, *c.shape)
        else:
            e = rng.standard_normal((trials, *c.shape)) * sd
        if nn is not None:
            e -= np.einsum("tnmk,mk->tnm", e, nn)[..., None] * nn[None, None]
        return e

    e1 = noise()
    cmd = np.asarray(commanded_mm, float)
    at, rt = _batched(c[None] + e1, cmd)
    at2, rt2 = _batched(c[None] + e1 + noise(), cmd)
    n = c.shape[0]
    extra = {"sampling (interpolation between samples)": sampling_mm / np.sqrt(n)} if sampling_mm else None
    out = {"AT_mm": from_draws("AT_mm", subject, acc.AT_mm, at, k=k, extra=extra, n=n, seed=seed, draws2=at2)}
    if rt is not None and acc.RT_mm is not None:
        extra = {"sampling (interpolation between samples)": sampling_mm} if sampling_mm else None
        out["RT_mm"] = from_draws("RT_mm", subject, acc.RT_mm, rt, k=k, extra=extra, n=n, seed=seed, draws2=rt2)
    return out
