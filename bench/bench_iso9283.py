"""Benchmark: ISO 9283 extraction and characteristics on one hour of 1 kHz data.

Run by hand::

    .venv/bin/python bench/bench_iso9283.py [--hours H] [--rate HZ] [--slice-frac F]

Generates one hour of tracker data at 1 kHz (3.6 M samples, ~1,150 cycles
P2..P5,P1 of a 600 mm test cube, 0.25 s dwells, servo overshoot, noise), then
prints:

* the time of the vectorised extraction and of the whole analysis (every
  characteristic, AT/RT included) — target under 1 s;
* the time of a direct per-window Python transcription of the seed's loop
  (``seed_transcription`` below: per-sample velocity, per-sample moving
  average, per-window velocity sums), measured on a slice of the stream and
  extrapolated linearly to the whole (the transcription is linear in N), and
  the speed-up — target at least 50x;
* the peak memory of the analysis (tracemalloc) against the input arrays
  (t and xyz) — target under 4x.

The transcription also serves the equivalence test in tests/iso9283: on the
same stream and parameters it must pick the same attained-pose samples.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from station.analysis.iso9283.characteristics import analyze_iso9283  # noqa: E402
from station.analysis.iso9283.poses import TABLE1_CORNERS_MM, cube_test_poses  # noqa: E402
from station.analysis.iso9283.extraction import extract_attained_poses  # noqa: E402


def seed_transcription(t, xyz, *, M, Mp, h, v_rest, min_move, min_dwell, break_s, lag=1, timings=None):
    """Direct per-sample / per-window Python transcription of the seed's method.

    Same definitions as :mod:`station.analysis.iso9283.extraction`, written as
    the plain loops the seed describes (and its Visual Basic program would
    run): eq. (3) velocity of each sample from its predecessor; the moving
    average of the velocity (vector, time-weighted) of each sample as a sum
    over the 2h steps of its window, clamped to the block between beam
    breaks; rest threshold; moves and rests; in each deceleration phase the
    horizons M_j of 2M+1 samples at j = Mp, 2Mp, ... (eq. (4)), each summing
    the velocities of its samples, the least sum wins.  Returns
    ``(phase_start, centre)`` for every deceleration phase (centre -1 where no
    horizon fits).  It has no special handling of phases with a beam break
    inside (the vectorised code flags those stops ``fallback``).  ``timings`` (a dict) receives the seconds spent in the phase split
    and in the horizons.
    """
    t0 = time.perf_counter()
    t = [float(v) for v in t]
    x = [float(v) for v in xyz[:, 0]]
    y = [float(v) for v in xyz[:, 1]]
    z = [float(v) for v in xyz[:, 2]]
    n = len(t)
    # blocks between beam breaks
    block_start = [0] * n
    block_end = [0] * n
    s0 = 0
    for i in range(1, n + 1):
        if i == n or t[i] - t[i - 1] > break_s:
            for k in range(s0, i):
                block_start[k] = s0
                block_end[k] = i - 1
            s0 = i
    # moving average of the velocity vector of every sample over its window
    u = [math.nan] * n
    for i in range(n):
        lo = max(i - h, block_start[i])
        hi = min(i + h, block_end[i])
        sx = sy = sz = st = 0.0
        for k in range(lo + 1, hi + 1):
            sx += x[k] - x[k - 1]
            sy += y[k] - y[k - 1]
            sz += z[k] - z[k - 1]
            st += t[k] - t[k - 1]
        if st > 0:
            u[i] = math.sqrt(sx * sx + sy * sy + sz * sz) / st
    # moves: runs of samples above the rest threshold
    runs = []
    i = 0
    while i < n:
        if u[i] > v_rest:
            j = i
            while j + 1 < n and u[j + 1] > v_rest:
                j += 1
            runs.append([i, j])
            i = j + 1
        else:
            i += 1
    runs = [r for r in runs if math.dist((x[r[1]], y[r[1]], z[r[1]]), (x[r[0]], y[r[0]], z[r[0]])) >= min_move]
    merged = []
    for r in runs:
        if merged:
            a0 = merged[-1][1]  # last sample of the previous move
            broken = block_start[r[0]] != block_start[a0]  # a beam break in the rest
            short = t[r[0] - 1] - t[a0 + 1] < min_dwell
        if merged and short and not (broken and r[0] - a0 - 1 >= 3):
            merged[-1][1] = r[1]
        else:
            merged.append(list(r))
    t1 = time.perf_counter()
    centers = []
    for k, (a, b) in enumerate(merged):
        best, peak = -1.0, a
        for i in range(a, b + 1):  # speed peak of the move
            if u[i] > best:
                best, peak = u[i], i
        ps = peak
        pe = merged[k + 1][0] - 1 if k + 1 < len(merged) else n - 1
        if b == n - 1:  # the stream ends in this move: no stop
            centers.append((ps, -1))
            continue
        # eq. (4): horizons M_j, j = Mp, 2Mp, ...; eq. (3) velocities; the least sum
        j = max(Mp, ((ps + M + Mp - 1) // Mp) * Mp)
        best_sum, best_j = math.inf, -1
        while j + M <= pe:
            s = 0.0
            ok = True
            for i in range(j - M, j + M + 1):
                if i - lag < block_start[i]:  # no predecessor in this block: beam break
                    ok = False
                    break
                dx = x[i] - x[i - lag]
                dy = y[i] - y[i - lag]
                dz = z[i] - z[i - lag]
                s += math.sqrt(dx * dx + dy * dy + dz * dz) / (t[i] - t[i - lag])
            if ok and s < best_sum:
                best_sum, best_j = s, j
            j += Mp
        if best_j >= 0 and u[best_j] > v_rest:  # the attained pose must be at rest
            best_j = -1
        centers.append((ps, best_j))
    if timings is not None:
        timings["phases_s"] = t1 - t0
        timings["horizons_s"] = time.perf_counter() - t1
    return centers


def differing_choices(centers, ex) -> list[tuple[int, int, int]]:
    """``(phase start, transcription's centre, vectorised code's centre)`` of every phase where they differ.

    Phases whose stop the vectorised code flagged ``fallback`` (beam break
    inside, or no horizon at rest) or refused (``failed_phases``: a beam break
    leaves no window at rest in the dwell) follow a rule the transcription
    does not have and are left out; so are phases without a stop in either.  The
    vectorised code also centres the horizon in the phase's final rest (after
    its last sample in motion), which the transcription does not: on an
    underdamped servo the two may differ there by a grid step or more.
    """
    st = ex.stops
    mine = {int(ps): int(c) for ps, c, fb in zip(st.i_phase_start, st.i_center, st.fallback) if not fb}
    skip = {int(ps) for ps, fb in zip(st.i_phase_start, st.fallback) if fb}
    skip |= {int(f.i_phase_start) for f in ex.failed_phases}
    theirs = {int(ps): int(c) for ps, c in centers if c >= 0 and ps not in skip}
    out = [(ps, theirs.get(ps, -1), mine.get(ps, -1)) for ps in sorted(set(mine) | set(theirs))]
    return [d for d in out if d[1] != d[2]]


def same_choices(centers, ex) -> bool:
    """The transcription chose the vectorised code's attained sample in every phase (see
    :func:`differing_choices`)."""
    return not differing_choices(centers, ex)


def make_hour(rng, hours=1.0, rate_hz=1000.0):
    """One hour of the 5-pose cycle on a 600 mm cube at the given rate."""
    from tests.iso9283.synth import iso_cycle_programme, random_offsets, render

    centre = np.array([0.0, 1700.0, 1400.0])
    corners = (np.array(TABLE1_CORNERS_MM) - centre) * 0.5 + centre
    tp = cube_test_poses(corners, 50.0)
    cycle_s = 2.9376  # measured for these moves and dwells: 1,225 cycles = 3.6 M samples per hour
    n_cycles = int(round(hours * 3600.0 / cycle_s))
    prog = iso_cycle_programme(rng, commanded=tp.positions_mm, n_cycles=n_cycles, dwell_s=0.25,
                               offsets_mm=random_offsets(rng), scatter_mm=0.03)
    s = render(rng, prog, start_mm=prog.target_mm[-1], rate_hz=rate_hz, speed_mm_s=2300.0, accel_mm_s2=20000.0,
               wn_hz=15.0, zeta=0.6, noise_mm=0.01, start_rest_s=1.0)
    return tp, s, n_cycles


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--slice-frac", type=float, default=0.05,
                    help="fraction of the stream the transcription runs on (extrapolated)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=12345)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    tp, s, n_cycles = make_hour(rng, args.hours, args.rate)
    t, xyz = s.t, s.xyz
    N = t.size
    in_bytes = t.nbytes + xyz.nbytes
    print(f"stream: {N:,} samples ({t[-1] / 3600:.2f} h at {args.rate:g} Hz), {n_cycles} cycles, "
          f"input arrays {in_bytes / 1e6:.1f} MB (generated in {time.perf_counter() - t0:.1f} s)")
    kw = dict(linear_paths=True, limits={"RP_mm": 0.5, "AP_mm": 5.0, "PST_s": 1.0, "MPT_s": 3.0})

    # warm up, then best of `repeat`
    analyze_iso9283(t[:50_000], xyz[:50_000], tp.positions_mm, **kw)
    t_ex, t_all = [], []
    for _ in range(args.repeat):
        a = time.perf_counter()
        ex = extract_attained_poses(t, xyz, tp.positions_mm)
        b = time.perf_counter()
        res = analyze_iso9283(t, xyz, tp.positions_mm, **kw)
        c = time.perf_counter()
        t_ex.append(b - a)
        t_all.append(c - b)
    te, ta = min(t_ex), min(t_all)
    print(f"vectorised extraction:            {te:.3f} s  ({ex.stops.n} stops, {len(ex.missing)} missing)")
    print(f"vectorised extraction + all characteristics (AP RP POS PST vAP AD RD MPT drift AT RT, verdicts): "
          f"{ta:.3f} s  [target < 1 s: {'OK' if ta < 1.0 else 'MISSED'}]")
    print(f"  poses: {', '.join(f'{n} n={p.n_cycles} RP={p.repeatability.RP_mm:.3f}' for n, p in res.poses.items())}")

    # the transcription on a slice, extrapolated
    n_slice = max(20_000, int(N * args.slice_frac))
    ts, xs = t[:n_slice], xyz[:n_slice]
    ex_s = extract_attained_poses(ts, xs, tp.positions_mm)
    p = ex_s.params
    tim = {}
    a = time.perf_counter()
    centers = seed_transcription(ts, xs, M=p.M, Mp=p.Mp, h=p.h, v_rest=p.v_rest_mm_s, min_move=p.min_move_mm,
                                 min_dwell=p.min_dwell_s, break_s=p.break_s, lag=p.lag, timings=tim)
    tt_slice = time.perf_counter() - a
    tt = tt_slice * N / n_slice
    same = same_choices(centers, ex_s)
    print(f"per-window Python transcription:   {tt_slice:.2f} s on {n_slice:,} samples "
          f"({100 * n_slice / N:.1f} %; moving average {tim['phases_s']:.2f} s, horizons "
          f"{tim['horizons_s']:.2f} s), extrapolated linearly to {N:,} samples: {tt:.1f} s "
          f"(same attained-pose samples as the vectorised code on the slice: {same})")
    print(f"speed-up: {tt / te:.0f}x (extraction vs transcription), {tt / ta:.0f}x (whole analysis vs "
          f"transcription of the extraction alone)  [target >= 50x: {'OK' if tt / ta >= 50 else 'MISSED'}]")

    # memory
    tracemalloc.start()
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    res = analyze_iso9283(t, xyz, tp.positions_mm, **kw)
    peak = tracemalloc.get_traced_memory()[1] - base
    tracemalloc.stop()
    print(f"peak memory of the analysis: {peak / 1e6:.1f} MB = {peak / in_bytes:.2f}x the input arrays "
          f"[target < 4x: {'OK' if peak < 4 * in_bytes else 'MISSED'}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
