"""An ISO 9283 dry run interrupted anywhere and resumed ends as if it had never been interrupted.

Property over interruption points: an uninterrupted run of a seed records
every progress report the runner makes (a step starting, a target reached
inside a cycle while the tracker streams, a registration point inside the
registration's batch of programs); then runs of the same seed are aborted at
randomly drawn reports (drawn per step kind, so every kind gets cut) and
resumed through the same front door (a new fake cell, as after a crash).
Checked against the uninterrupted run:

* every step finished before the cut recorded exactly the samples of the
  uninterrupted run, bit for bit (the lockstep clock);
* the resumed run is done, every step once (plus the session steps), each
  prompt asked once in all, and the analysed stream's time never repeats
  or goes back;
* the cycle counts are those of the uninterrupted run, every characteristic
  it states is stated (a posing time across the resume's gap among them),
  and the attained poses of the cycles before the cut are the same;
* AP and RP differ by no more than the tracker noise allows: after a
  resume, a stop's attained pose may be a neighbouring sample of the same
  rest (the extraction's statistics see another stream), i.e. another draw
  of the tracker noise. The tolerance is the 99.9 % quantile of the change
  of AP and RP when the attained poses of every cycle from the cut on are
  displaced by such a draw (two samples' noise, N(0, 2 sigma^2) per
  coordinate, sigma the noise the extraction measured), by Monte Carlo
  from the test's seed.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

from fakes.cells import demo_config
from procedures.iso9283 import IsoPlan, analyse, build_procedure, registration_of
from app.assemble import RunRequest, run_procedure
from station.config import config_from_dict
from app.terminal import ProgressLine
from station.runner import CallableOperator, RunControl
from station.store import RunStore
from tests.pace import LOCKSTEP

CYCLES, VAP = 3, 2
#: time scale of these runs: the lockstep clock gives the same figures at any scale
SCALE = LOCKSTEP


class Recorder(ProgressLine):
    """Records every progress report; with ``cut_at`` (a report of the uninterrupted run: step and detail)
    asks for an abort when it comes (or, if the host's polling missed that target, when the next step starts)."""

    def __init__(self, control: RunControl, cut_at: tuple | None = None) -> None:
        super().__init__(None)
        self.control, self.cut_at, self.reports = control, cut_at, []

    def update(self, idx: int, step, detail: str = "") -> None:
        super().update(idx, step, detail)
        if self.cut_at is not None and not self.control.abort_requested:
            seen = [n for n, _ in self.reports]
            passed = self.cut_at[0] in seen and step.name != self.cut_at[0]
            if (step.name, detail) == self.cut_at or passed:
                self.control.abort()
        self.reports.append((step.name, detail))


def _run(cfg, base: Path, run_id: str, seed: int, *, cut_at=None, resume=False):
    control = RunControl()
    progress = Recorder(control, cut_at)
    operator = CallableOperator(lambda _msg: True)
    code = run_procedure(RunRequest(cfg, None if resume else "iso9283", resume=run_id if resume else None,
                                    run_id=None if resume else run_id, time_scale=SCALE, seed=seed, quiet=True,
                                    config_dir=base, operator=operator, control=control, progress=progress,
                                    stdout=io.StringIO()))
    return code, progress.reports, [m for m, _ in operator.asked]


def _step_samples(store: RunStore, run_id: str, step_idx: int) -> dict:
    return store.samples(run_id, "tracker", steps=[step_idx])


def _analysis(store: RunStore, run_id: str):
    plan = IsoPlan.from_params(store.run(run_id).params)
    idx = {s.name: i for i, s in enumerate(build_procedure(plan).steps)}
    outs = {s.name: s.output for s in store.steps(run_id) if s.status == "done"}
    reg = registration_of(outs)

    def stream(names):
        s = store.samples(run_id, "tracker", steps=[idx[n] for n in names])
        assert np.all(np.diff(s["t"]) > 0), f"{run_id}: the analysed stream's time repeats or goes back"
        return s["t"], reg.to_base(np.column_stack([s["x"], s["y"], s["z"]]))

    pose = stream([f"pose cycle {k}" for k in range(1, plan.cycles + 1)])
    vap = stream([f"vAP cycle {k}" for k in range(1, plan.vap_cycles + 1)] + ["stop stream"])
    return analyse(plan, *pose, *vap)[0]


def _figures(attained: np.ndarray, commanded: np.ndarray) -> tuple[float, float]:
    """AP and RP of one pose from its attained poses (seed 000 eq. (1)-(2))."""
    bary = attained.mean(axis=0)
    ap = float(np.linalg.norm(bary - commanded))
    d = np.linalg.norm(attained - bary, axis=1)
    return ap, float(d.mean() + 3.0 * d.std(ddof=1))


def _tolerance(attained: np.ndarray, commanded: np.ndarray, first_redone: int, sigma_mm: float,
               rng: np.random.Generator, draws: int = 4000, checks: int = 1) -> tuple[float, float]:
    """The 1 - 0.001 / ``checks`` quantile of |dAP|, |dRP| when the attained poses from ``first_redone`` on get
    another two-sample tracker noise draw (see the module docstring): 99.9 % for one check, the same family-wise
    for ``checks`` of them (``draws`` grows with it, so the quantile stays about 4 draws deep)."""
    ap0, rp0 = _figures(attained, commanded)
    m = attained.shape[0] - first_redone
    n = int(draws * max(checks, 1))
    a = np.broadcast_to(attained, (n, *attained.shape)).copy()  # Monte Carlo over noise draws, all at once
    a[:, first_redone:] += rng.normal(0.0, np.sqrt(2.0) * sigma_mm, (n, m, 3))
    bary = a.mean(axis=1)
    ap = np.linalg.norm(bary - commanded, axis=1)
    d = np.linalg.norm(a - bary[:, None], axis=2)
    rp = d.mean(axis=1) + 3.0 * d.std(axis=1, ddof=1)
    q = 1.0 - 0.001 / max(checks, 1)
    return float(np.quantile(np.abs(ap - ap0), q)), float(np.quantile(np.abs(rp - rp0), q))


def test_a_run_cut_anywhere_resumes_as_if_never_interrupted(test_seed, tmp_path):
    seed = test_seed  # the session's seed for this test (printed on failure, --seed replays)
    rng = np.random.default_rng(seed)
    print(f"seed {seed} (world and interruption points)")
    cfg = config_from_dict(demo_config(tmp_path, cycles=CYCLES, vap_cycles=VAP, rate_hz=100.0))
    code, reports, asked = _run(cfg, tmp_path, "ref", seed)
    assert code.status == "done", code.error
    ref_verdict = code.verdict
    store = RunStore(tmp_path / "station.sqlite")
    names = [s.name for s in build_procedure(IsoPlan.from_params(store.run("ref").params)).steps]
    ref = _analysis(store, "ref")

    # one interruption point per kind of moment, two of them drawn for this run
    kinds = {
        "a prompt": [i for i, (n, d) in enumerate(reports) if n in ("mount reflector", "clear the cell")],
        "connect/home": [i for i, (n, d) in enumerate(reports) if n in ("connect devices", "home")],
        "mid-batch (registration)": [i for i, (n, d) in enumerate(reports) if n == "register base frame" and d],
        "mid-stream (pose cycle)": [i for i, (n, d) in enumerate(reports) if n.startswith("pose cycle") and d],
        "mid-stream (vAP cycle)": [i for i, (n, d) in enumerate(reports) if n.startswith("vAP cycle") and d],
        "a step's start": [i for i, (n, d) in enumerate(reports) if not d and n in ("pose cycle 2", "vAP cycle 1",
                                                                                     "stop stream", "analyse")],
    }
    chosen = rng.choice(sorted(kinds), size=2, replace=False)
    for j, kind in enumerate(chosen):
        cut_at = reports[int(rng.choice(kinds[kind]))]
        run_id = f"cut{j}"
        print(f"{run_id}: cut at {kind}: {cut_at}")
        code, _, asked_first = _run(cfg, tmp_path, run_id, seed, cut_at=cut_at)
        assert code.status == "aborted" and code.exit_code == 5, f"{run_id} was not aborted at {cut_at}"
        finished_before = [s for s in store.steps(run_id) if s.status == "done"]
        code, _, asked_again = _run(cfg, tmp_path, run_id, seed, resume=True)
        assert code.status == "done" and code.verdict == ref_verdict, (code.error, code.reasons)
        assert store.run(run_id).status == "done"
        # nothing confirmed is asked again
        assert sorted(asked_first + asked_again) == sorted(asked)
        # every step once (the session steps again after the resume)
        done = [s.name for s in store.steps(run_id) if s.status == "done"]
        for name in names:
            again = name in ("check programs", "connect devices", "home")
            assert done.count(name) == 1 or (again and done.count(name) == 2), (name, done.count(name))
        # the steps finished before the cut took the uninterrupted run's samples, bit for bit
        for s in finished_before:
            a, b = _step_samples(store, run_id, s.idx), _step_samples(store, "ref", s.idx)
            assert a.keys() == b.keys(), s.name
            for col in a:
                np.testing.assert_array_equal(a[col], b[col], err_msg=f"{run_id} {s.name} {col}")
        # the resumed run states every characteristic the run left alone states (a posing time across the
        # resume's gap is measured after it, from the rest the arm was brought back to)
        stated = lambda rid: {(c["pose"], c["name"]) for c in store.characteristics(rid) if c["value"] is not None}
        assert stated(run_id) == stated("ref"), (sorted(stated("ref") - stated(run_id)), sorted(stated(run_id) - stated("ref")))
        cut = _analysis(store, run_id)
        pose_done = sum(1 for s in finished_before if s.name.startswith("pose cycle"))
        sigma = float(ref.extraction.params.noise_mm)
        for p, pr in ref.poses.items():
            pc = cut.poses[p]
            assert pc.n_cycles == pr.n_cycles == CYCLES
            # the cycles before the cut: the same attained poses (the last may straddle the resume's gap)
            np.testing.assert_allclose(pc.attained_mm[:max(pose_done - 1, 0)], pr.attained_mm[:max(pose_done - 1, 0)],
                                       atol=1e-9)
            first = max(pose_done - 1, 0)
            tol_ap, tol_rp = _tolerance(pr.attained_mm, pr.commanded_mm, first, sigma, rng)
            d_ap = abs(pc.accuracy.AP_mm - pr.accuracy.AP_mm)
            d_rp = abs(pc.repeatability.RP_mm - pr.repeatability.RP_mm)
            print(f"  {p}: dAP {d_ap:.4f} (tol {tol_ap:.4f}) dRP {d_rp:.4f} (tol {tol_rp:.4f}) mm")
            assert d_ap <= tol_ap, (p, d_ap, tol_ap)
            assert d_rp <= tol_rp, (p, d_rp, tol_rp)
    json.dumps(reports)  # the reports are plain data (printed on failure by pytest)
