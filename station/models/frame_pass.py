"""One forward pass of a DH + Hayati table over many poses, laid out for the parameter Jacobian.

The same quantities as :func:`station.models.kinematics.frames` and
:func:`~station.models.kinematics.param_jacobian` (seed 002 eq. (3), (5),
(7)-(8)), computed for what an identification iterates on: one table (7, 5)
and N poses, with the poses on the last axis so that every product runs over
contiguous memory.

Each row's link transform, eq. (3), is ``T_i = Rz(theta_i + q_i) C_i`` with
``C_i = Tz(d_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)`` the same for every pose, so
the chain ``F_i = F_{i-1} T_i`` is a turn of the previous frame's x and y
axes by the joint angle (two products over the poses) and one small matrix
product with ``C_i``; the turned axes are the Jacobian's own ``x`` and ``y``
after ``Rz(theta_i)``, kept rather than computed again. The chain may start
from a rotation ``R`` (the instrument's orientation of the robot base): the
frames, the tool point and the Jacobian's columns are then in the turned
frame at no extra cost (a rotation turns axes and differences of points
alike, and a cross product of turned vectors is the turned cross product).

:func:`frame_passes` runs the same pass over blocks of poses in memory kept
from block to block (:class:`PassBuffers`): an identification that needs
only sums over the poses (normal equations) holds a block, which stays in a
core's cache, instead of 1.1 MB of frames for 1,000 poses taken afresh at
every evaluation.

Units: mm and rad.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from station.errors import DataError
from station.models import kinematics as kin

__all__ = ["FramePass", "PassBuffers", "frame_pass", "frame_passes", "turn", "tool_points", "param_jacobian",
           "param_jacobian_t"]


class FramePass(NamedTuple):
    """Frames of one table over N poses, poses last.

    ``axes[k]`` (4, 3, N): the x, y, z axes and the origin of frame k
    (k = 0 the base, as turned by the start rotation, .. 7 the TCP);
    ``turned[i]`` (2, 3, N): frame i's x and y axes after row i's
    ``Rz(theta_i + q_i)``; ``cos_alpha``, ``sin_alpha`` (7, 1, 1): the rows'
    twists, for the Hayati beta axis.
    """

    axes: np.ndarray
    turned: np.ndarray
    cos_alpha: np.ndarray
    sin_alpha: np.ndarray


def _prepare(dh, q_rad, rotation, buffers=None):
    """Validated inputs of a pass: the rows' constant parts ``C`` (7, 4, 4), ``cos``/``sin`` of
    ``theta_i + q_i`` (7, N), the start rotation (3, 3) and the rows' twists' cosines and sines (7, 1, 1).
    With ``buffers``, the joint angles' own cosines and sines are the ones they keep for these poses, turned
    by the offsets (``cos(q + theta) = cos q cos theta - sin q sin theta``)."""
    dh = kin.validate_dh(dh)
    if dh.shape != (kin.N_ROWS, 5):
        raise DataError(f"`dh` must have shape (7, 5) (one table for every pose), got {dh.shape}")
    q = np.asarray(q_rad, dtype=float)
    if q.ndim != 2 or q.shape[1] != kin.N_JOINTS:
        raise DataError(f"`q_rad` must have shape (N, {kin.N_JOINTS}), got {q.shape}")
    n = q.shape[0]
    # each row's constant part C_i: the link transform with theta 0
    flat = dh.copy()
    flat[:, 3] = 0.0
    C = kin.link_transforms(flat, np.zeros(kin.N_JOINTS))          # (7, 4, 4)
    R = np.eye(3) if rotation is None else np.asarray(rotation, dtype=float)
    al = dh[:, 1, None, None]
    if buffers is not None:
        cq, sq = buffers.joint_trig(q)
        c0, s0 = np.cos(dh[:, 3, None]), np.sin(dh[:, 3, None])
        ct, st = np.empty((kin.N_ROWS, n)), np.empty((kin.N_ROWS, n))
        j = kin.N_JOINTS
        np.multiply(cq, c0[:j], out=ct[:j])
        ct[:j] -= sq * s0[:j]
        np.multiply(sq, c0[:j], out=st[:j])
        st[:j] += cq * s0[:j]
        ct[j], st[j] = c0[j], s0[j]
        return C, ct, st, R, np.cos(al), np.sin(al)
    th = np.empty((kin.N_ROWS, n))
    th[:kin.N_JOINTS] = q.T
    th[kin.N_JOINTS] = 0.0
    th += dh[:, 3, None]
    return C, np.cos(th), np.sin(th), R, np.cos(al), np.sin(al)


def _chain(C, ct, st, R, axes, tr) -> None:
    """The chain of eq. (5) over the poses of ``ct``, ``st`` (7, n) into ``axes`` (8, 4, 3, n), ``tr`` (7, 2, 3, n)."""
    axes[0, :3] = R.T[:, :, None]       # column j of R is the base's axis j
    axes[0, 3] = 0.0
    tmp = np.empty(axes.shape[2:])
    for i in range(kin.N_ROWS):
        x, y = axes[i, 0], axes[i, 1]
        np.multiply(ct[i], x, out=tr[i, 0])
        tr[i, 0] += np.multiply(st[i], y, out=tmp)
        np.multiply(ct[i], y, out=tr[i, 1])
        tr[i, 1] -= np.multiply(st[i], x, out=tmp)
        # column j of F_i is sum_l (column l of F_{i-1} Rz) C_i[l, j]; the origin also keeps its own
        Ct = C[i].T
        nxt = axes[i + 1].reshape(4, -1)
        np.matmul(Ct[:, :2], tr[i].reshape(2, -1), out=nxt)
        nxt += Ct[:, 2:] @ axes[i, 2:].reshape(2, -1)


def frame_pass(dh, q_rad, rotation=None) -> FramePass:
    """Forward kinematics, seed 002 eq. (3) and (5), of one table ``dh`` (7, 5) over ``q_rad`` (N, 6).

    ``rotation`` (3, 3): the base frame's orientation (default the identity); every frame, and the tool
    point, is turned by it.
    """
    C, ct, st, R, ca, sa = _prepare(dh, q_rad, rotation)
    n = ct.shape[1]
    axes = np.empty((kin.N_ROWS + 1, 4, 3, n))
    tr = np.empty((kin.N_ROWS, 2, 3, n))
    _chain(C, ct, st, R, axes, tr)
    return FramePass(axes, tr, ca, sa)


class PassBuffers:
    """Memory for the passes of :func:`frame_passes` over blocks of at most ``capacity`` poses, kept from one
    pass to the next (fresh memory costs page faults). Each block's arrays are contiguous views of its start."""

    def __init__(self, capacity: int):
        if capacity < 1:
            raise DataError(f"`capacity` must be at least 1, got {capacity}")
        self.capacity = int(capacity)
        self._axes = np.empty((kin.N_ROWS + 1) * 4 * 3 * self.capacity)
        self._turned = np.empty(kin.N_ROWS * 2 * 3 * self.capacity)
        self._q = self._cq = self._sq = None

    def joint_trig(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``cos q``, ``sin q`` (6, N) of the poses ``q`` (N, 6), kept for the next pass over the same poses
        (an identification's every step)."""
        if self._q is None or self._q.shape != q.shape or not np.array_equal(self._q, q):
            self._q, self._cq, self._sq = q.copy(), np.cos(q.T), np.sin(q.T)
        return self._cq, self._sq

    def views(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``axes`` (8, 4, 3, k) and ``turned`` (7, 2, 3, k) for a block of ``k <= capacity`` poses."""
        if not 0 <= k <= self.capacity:
            raise DataError(f"a block of {k} poses does not fit buffers of {self.capacity}")
        return (self._axes[:(kin.N_ROWS + 1) * 12 * k].reshape(kin.N_ROWS + 1, 4, 3, k),
                self._turned[:kin.N_ROWS * 6 * k].reshape(kin.N_ROWS, 2, 3, k))


def frame_passes(dh, q_rad, rotation=None, *, buffers: PassBuffers, block: int | None = None):
    """The pass of :func:`frame_pass` over consecutive blocks of at most ``block`` poses (default and at most
    ``buffers.capacity``).

    Yields ``(start, FramePass)``: the block's first pose and its pass, written into ``buffers`` (so over
    the previous block's: a caller keeps what it needs of a block before asking for the next). A block
    stays in a core's cache where the whole pass of 1,000 poses (1.1 MB) would not.
    """
    block = buffers.capacity if block is None else int(block)
    if not 1 <= block <= buffers.capacity:
        raise DataError(f"`block` must be 1..{buffers.capacity} (the buffers' capacity), got {block}")
    C, ct, st, R, ca, sa = _prepare(dh, q_rad, rotation, buffers)
    n = ct.shape[1]
    for s in range(0, n, block):
        k = min(block, n - s)
        axes, tr = buffers.views(k)
        _chain(C, ct[:, s:s + k], st[:, s:s + k], R, axes, tr)
        yield s, FramePass(axes, tr, ca, sa)


def turn(fp: FramePass, rotation) -> FramePass:
    """Turn every frame of the pass by ``rotation`` (3, 3) in place (as if it had started from it); returns it.

    Frame by frame: no second pass-sized array (fresh memory costs page faults).
    """
    R = np.asarray(rotation, dtype=float)
    for block in (fp.axes, fp.turned):
        for k in range(block.shape[0]):
            block[k] = np.matmul(R, block[k])
    return fp


def tool_points(fp: FramePass) -> np.ndarray:
    """TCP positions (N, 3), mm (in the turned frame when the pass started from a rotation)."""
    return fp.axes[kin.N_ROWS, 3].T


def _cross(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """Cross product over the second axis (3) into ``out``."""
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def param_jacobian_t(fp: FramePass, out=None) -> np.ndarray:
    """Position Jacobian w.r.t. the 35 kinematic parameters, seed 002 eq. (7)-(8), poses last: shape (35, 3, N).

    ``out[5*i + k, c, n]``: row ``i``, parameter ``k`` of ``[a, alpha, d, theta, beta]``, coordinate ``c``,
    pose ``n`` (turned by the pass's start rotation); every column is written as contiguous memory, as the
    pass lays it out. ``out``: a C-contiguous (35, 3, N) array or view (e.g. the first 35 rows of a larger
    one) to write into.
    """
    n = fp.axes.shape[-1]
    if out is None:
        out = np.empty((kin.N_PARAMS, 3, n))
    elif out.shape != (kin.N_PARAMS, 3, n) or not out.flags.c_contiguous:
        raise DataError(f"`out` must be a C-contiguous ({kin.N_PARAMS}, 3, {n}) array, got {out.shape}")
    J = out.reshape(kin.N_ROWS, 5, 3, n)               # (7 rows, 5 parameters, 3 coordinates, N)
    x_m, y_m = fp.turned[:, 0], fp.turned[:, 1]         # (7, 3, N)
    z_prev = fp.axes[:kin.N_ROWS, 2]
    o = fp.axes[:, 3]                                    # (8, 3, N) frame origins
    p = o[kin.N_ROWS:]                                   # tool point
    # frame after Rz(theta): its x axis carries a, its y axis (after Rx(alpha)) is the Hayati beta axis;
    # alpha and beta rotate about o_i, theta about o_{i-1}
    y_b = fp.cos_alpha * y_m + fp.sin_alpha * z_prev
    r = p - o                                            # from every origin to the tool point
    r_prev, r_i = r[:kin.N_ROWS], r[1:]
    J[:, 0] = x_m                       # d p / d a_i
    _cross(x_m, r_i, J[:, 1])           # d p / d alpha_i
    J[:, 2] = z_prev                    # d p / d d_i
    _cross(z_prev, r_prev, J[:, 3])     # d p / d theta_i
    _cross(y_b, r_i, J[:, 4])           # d p / d beta_i
    return out


def param_jacobian(fp: FramePass, out=None) -> np.ndarray:
    """Position Jacobian w.r.t. the 35 kinematic parameters, seed 002 eq. (7)-(8), shape (N, 3, 35).

    As :func:`station.models.kinematics.param_jacobian` (column ``5*i + k``: row ``i``, parameter ``k`` of
    ``[a, alpha, d, theta, beta]``), turned by the pass's start rotation: :func:`param_jacobian_t` laid out
    poses first. ``out``: an (N, 3, 35) array or view (e.g. the first 35 columns of a larger Jacobian) to
    write into.
    """
    n = fp.axes.shape[-1]
    if out is None:
        out = np.empty((n, 3, kin.N_PARAMS))
    elif out.shape != (n, 3, kin.N_PARAMS):
        raise DataError(f"`out` must have shape ({n}, 3, {kin.N_PARAMS}), got {out.shape}")
    np.copyto(out, param_jacobian_t(fp).transpose(2, 1, 0))
    return out
