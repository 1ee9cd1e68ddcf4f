"""Benchmark: arm identification from 1,000 poses, ours against scipy's least_squares.

Run by hand: ``.venv/bin/python bench/bench_arm_identification.py [--poses N] [--noise-mm S]
[--blas-threads K]``.

The problem is seed 002's absolute formulation on the RB5-850 with Table 3
(as built) as the truth and Table 2 (nominal) as the start: 35 kinematic and
6 base parameters, of which the identifiable ones are free (the structural
fixes of :func:`station.analysis.arm_identification.identify`). Our solver
is Levenberg-Marquardt on the analytic Jacobian; the reference is
``scipy.optimize.least_squares`` (trust-region reflective, the default) on
the *same* residuals over the *same* free parameters with finite-difference
(2-point) Jacobians. Both start from the same point; the figures are wall
time to convergence, the final residual RMS and the largest difference of
the identified tool positions over the poses. No assertion on time.

Our time is the median (and the best) of the calls after the first, wall
and CPU (user + system: fresh memory's page faults are system time), with
the page faults per call (the identification sums the Jacobian over blocks
of poses in memory each thread keeps, so a call after the first takes none;
the first also checks the start model on 200 reference poses). Where a
call's time goes (cProfile, this problem): three evaluations of the
blockwise pass and its normal equations (the start and two accepted steps;
about half), the identifiability analysis (about 15 %), the solver's small
dense solves (a least-squares convergence test per step, five a call), the
uncertainties and warnings; the base stage and the prior's fit converge at
their start. BLAS
runs on one thread unless ``--blas-threads`` says otherwise (0: the
library's own choice), for both solvers alike: the matrices are small
(3,000 x 41), and on a shared 2-core host OpenBLAS's two threads wait for
each other (one identification took 340 ms of CPU with two threads against
20 ms with one, load 5). The setting is printed with the figures.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # this checkout's station, not an installed one


def _scipy_identify(dh0, base0, q, meas, free, **options):
    """The same absolute problem for scipy: parameters = free entries of (dh.ravel, base rotvec, base t)."""
    import numpy as np
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    from station.models import kinematics as kin

    x_full0 = np.concatenate([dh0.ravel(), Rotation.from_matrix(base0[:3, :3]).as_rotvec(), base0[:3, 3]])

    def residual(x_free):
        x = x_full0.copy()
        x[free] = x_free
        dh = x[:kin.N_PARAMS].reshape(kin.N_ROWS, 5)
        R = Rotation.from_rotvec(x[kin.N_PARAMS:kin.N_PARAMS + 3]).as_matrix()
        p = kin.tool_position(dh, q) @ R.T + x[kin.N_PARAMS + 3:]
        return (p - meas).ravel()

    t0 = time.perf_counter()
    sol = least_squares(residual, x_full0[free], jac="2-point", **options)
    dt = time.perf_counter() - t0
    x = x_full0.copy()
    x[free] = sol.x
    return dt, sol, x


def _parse() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=1000)
    ap.add_argument("--noise-mm", type=float, default=0.03)
    ap.add_argument("--repeats", type=int, default=7, help="calls of ours (the first is reported apart)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--blas-threads", type=int, default=1, help="BLAS threads of both solvers; 0: the library's")
    args = ap.parse_args()
    if args.repeats < 2 or args.blas_threads < 0:
        ap.error("--repeats must be at least 2 and --blas-threads at least 0")
    return args


def main(args: argparse.Namespace) -> None:
    import numpy as np
    from scipy.spatial.transform import Rotation

    from fakes.sim.arm_measurements import instrument_frame, measure, random_poses
    from station.analysis.arm.identification import identify, rigid_fit
    from station.models import kinematics as kin
    from station.models.robots import get_robot

    rng = np.random.default_rng(args.seed)
    nominal, truth = get_robot("rb5-850"), get_robot("rb5-850-as-built")
    q = random_poses(nominal.joint_limits_rad, args.poses, rng)
    base_true = instrument_frame(rng)
    meas = measure(truth.dh_nominal, q, base_true, args.noise_mm, rng)
    dh0 = nominal.dh_nominal

    wall, cpu, faults = [], [], []
    for _ in range(args.repeats):
        f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        t0, c0 = time.perf_counter(), time.process_time()
        res = identify(dh0, q, meas, method="absolute")
        c1 = time.process_time()
        wall.append(time.perf_counter() - t0)
        cpu.append(c1 - c0)
        faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
    free = res.identifiability.free
    p_ours = kin.tool_position(res.dh, q) @ res.base_T[:3, :3].T + res.base_T[:3, 3]
    threads = "the library's default" if args.blas_threads == 0 else str(args.blas_threads)
    print(f"RB5-850, {args.poses} poses, noise {args.noise_mm} mm, absolute method: "
          f"{kin.N_PARAMS} kinematic + 6 base parameters, {free.size} identifiable; BLAS threads: {threads}; "
          f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    med, best = float(np.median(wall[1:])), min(wall[1:])
    print(f"  ours (LM, analytic Jacobian): first call {1e3 * wall[0]:.1f} ms (checks the start model's "
          f"identifiable set on 200 reference poses once), then {1e3 * med:.1f} ms median, {1e3 * best:.1f} ms best "
          f"of {len(wall) - 1} (CPU {1e3 * float(np.median(cpu[1:])):.1f} ms median, "
          f"{int(np.median(faults[1:]))} page faults median), "
          f"{res.iterations} iterations, rms {res.residual_rms_mm:.5f} mm ({res.message})")

    # scipy from the same start (the rigid fit identify starts from)
    base0 = rigid_fit(kin.tool_position(dh0, q), meas)
    for label, options in (("defaults", {}), ("x_scale='jac'", {"x_scale": "jac"})):
        dt, sol, x = _scipy_identify(dh0, base0, q, meas, free, **options)
        dh_s = x[:kin.N_PARAMS].reshape(kin.N_ROWS, 5)
        R = Rotation.from_rotvec(x[kin.N_PARAMS:kin.N_PARAMS + 3]).as_matrix()
        p_s = kin.tool_position(dh_s, q) @ R.T + x[kin.N_PARAMS + 3:]
        rms_s = float(np.sqrt(np.mean((p_s - meas) ** 2)))
        print(f"  scipy least_squares 2-point, {label:<14}: {1e3 * dt:8.1f} ms, {sol.nfev} residual evaluations "
              f"+ {sol.njev} FD Jacobians, rms {rms_s:.5f} mm; ours (median) is {dt / med:.1f}x faster; "
              f"largest tool-point difference {np.max(np.linalg.norm(p_ours - p_s, axis=1)):.1e} mm")
    err_true = np.linalg.norm(p_ours - (kin.tool_position(truth.dh_nominal, q) @ base_true[:3, :3].T
                                        + base_true[:3, 3]), axis=1)
    print(f"  identified model against the truth over the poses: mean {err_true.mean():.4f} mm, "
          f"max {err_true.max():.4f} mm")


if __name__ == "__main__":
    _args = _parse()
    if _args.blas_threads:   # before numpy is imported: the BLAS libraries read these once
        for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[_var] = str(_args.blas_threads)
    main(_args)
