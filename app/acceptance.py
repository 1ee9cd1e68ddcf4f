"""A small API for acceptance scripts after overhaul.

An acceptance script should read like the procedure it checks::

    def test_robot_back_in_spec(fake_station):          # or Station.from_config(...)
        run = fake_station.iso9283(cycles=30)
        run.assert_within_limits()                      # every configured limit
        assert run.value("P1", "RP_mm") <= 0.3          # a plant's own, tighter figure

:class:`Station` runs procedures through the same runner, drivers and store
as ``station run``; :class:`AcceptanceRun` reads the stored results. The
pytest plugin :mod:`app.testing` provides the ``fake_station`` fixture.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from station.config import StationConfig, config_from_dict, load_config
from station.errors import ConfigError, DataError, InsufficientDataError
from station.store import RunStore

#: robots a fake station can be asked for (:meth:`Station.fake`)
CONDITIONS = ("as-drawn", "in-spec", "out-of-spec")
#: how far, in rms lengths of the run-to-prediction scatter, a fake robot drawn in or out of spec
#: clears its limits. Over 250 poses of 50 fake cells |AP measured - predicted| was at most 1.7
#: of that rms (bench/bench_fake_truth.py); an error vector 4 rms long is a 1e-9 event.
SPEC_SIGMAS = 4.0
#: stops per pose assumed when the scatter is estimated (the fewest the procedure allows: widest)
_SPEC_CYCLES = 2
#: warm-up time of a fully warm arm, s (thermal drift: the robot must be in spec cold and warm)
_WARM_S = 1.0e6


@dataclass(frozen=True)
class CellTruth:
    """What the fake cell of one seed really is (drawn as the fake station draws it)."""

    seed: int
    effects: object  # station.models.effects.EffectSet
    stop_sigma_rad: np.ndarray
    #: tracker noise per coordinate at the farthest test pose, mm
    tracker_sigma_mm: float


def fake_cell_truth(plan, seed: int) -> CellTruth:
    """The true error effects, stop scatter and tracker noise of the fake cell ``seed`` for ``plan``."""
    from fakes.sim.clock import ManualClock
    from fakes.sim.world import make_world

    world = make_world(robot=plan.robot.name, seed=int(seed), clock=ManualClock(), payload_kg=plan.payload_kg)
    try:
        tracker_at = world.tracker.base_T_tracker[:3, 3]
        reach = np.linalg.norm(np.array(list(plan.poses_mm.values())) - tracker_at, axis=1).max()
        return CellTruth(int(seed), world.arm.effects, world.arm.stop_sigma_rad.copy(),
                         float(np.max(world.tracker.sigma_mm(reach))))
    finally:
        world.close()


def _meets(condition, ap_lo, ap_hi, ad_hi, ap_margin, ad_margin, ap_lim, ad_lim) -> bool:
    """In spec: every AP and |AD| plus its margin within its limit (no limit, no bound); out of spec:
    some pose's AP minus its margin at or over the AP limit."""
    if condition == "out-of-spec":
        return bool(np.any(ap_lo - ap_margin >= ap_lim))
    return (ap_lim is None or bool(np.all(ap_hi + ap_margin <= ap_lim))) and (
        ad_lim is None or ad_hi + ad_margin <= ad_lim)


def fake_robot_seed(config: StationConfig, seed: int, condition: str, robot: str = "r1", *,
                    sigmas: float = SPEC_SIGMAS, max_tries: int = 5000) -> int:
    """The first fake-cell seed from ``seed`` on whose robot is in or out of spec.

    The cell's true error effects are drawn exactly as the fake station draws
    them; :func:`procedures.iso9283_truth.predict_static` gives the AP of
    every pose and the AD of P2-P4 an ideal run would measure, cold and fully
    warm, and :func:`~procedures.iso9283_truth.prediction_scatter` how far a
    run scatters about them (registration from the stop scatter of the sweep
    points, mean of two stops per pose, tracker noise). ``"in-spec"``: every
    AP and |AD| plus ``sigmas`` times its scatter within the configured
    ``ap_limit_mm`` / ``ad_limit_mm``. ``"out-of-spec"``: some pose's AP
    minus ``sigmas`` times its scatter over ``ap_limit_mm``. RP, vAP and PST
    of the simulated arms are bounded by their draws (over 50 cells at 5
    cycles the largest were 0.23 mm, 0.54 mm and 0.09 s) and not conditioned.

    Raises
    ------
    ConfigError
        Unknown condition, ``"out-of-spec"`` without an AP limit, or a
        best-fit registration (its frame is not predicted).
    InsufficientDataError
        No such cell among ``max_tries`` seeds (limits too tight or too loose for the simulated arms).
    """
    from procedures.iso9283 import plan_from_config
    from procedures.iso9283_truth import RunGeometry, predict_static, prediction_scatter

    if condition not in ("in-spec", "out-of-spec"):
        raise ConfigError(f"condition must be 'in-spec' or 'out-of-spec', got {condition!r}")
    plan = plan_from_config(config, robot)
    ap_lim = plan.limits.get("AP_mm")
    ad_lim = plan.limits.get("AD_mm")
    if condition == "out-of-spec" and ap_lim is None:
        raise ConfigError(f"robots.{robot}.limits.ap_limit_mm is needed to draw a robot out of spec")
    names = list(plan.poses_mm)
    geo = RunGeometry.of(plan)
    for s in range(int(seed), int(seed) + max_tries):
        cell = fake_cell_truth(plan, s)
        cold, warm = (predict_static(plan, cell.effects, warmup_s=w, geometry=geo) for w in (0.0, _WARM_S))
        ap = np.array([[p.AP_mm[n] for n in names] for p in (cold, warm)])
        ap_lo, ap_hi = ap.min(axis=0), ap.max(axis=0)
        ad_hi = max((abs(v) for p in (cold, warm) for v in p.AD_mm.values()), default=0.0)
        # the cheap test first: the noise-free numbers must already be on the right side
        if not _meets(condition, ap_lo, ap_hi, ad_hi, 0.0, 0.0, ap_lim, ad_lim):
            continue
        sc = prediction_scatter(plan, cell.effects, cell.stop_sigma_rad, cycles=_SPEC_CYCLES,
                                tracker_sigma_mm=cell.tracker_sigma_mm, rng=np.random.default_rng(s), geometry=geo)
        rms = np.array([sc.AP_rms_mm[n] for n in names])
        ad_sd = max(sc.AD_sd_mm.values(), default=0.0)
        if _meets(condition, ap_lo, ap_hi, ad_hi, sigmas * rms, sigmas * ad_sd, ap_lim, ad_lim):
            return s
    raise InsufficientDataError(f"no fake cell {condition} among seeds {seed}..{seed + max_tries - 1} "
                                f"(AP limit {ap_lim}, AD limit {ad_lim}, {sigmas:g} sigma)")


@dataclass
class AcceptanceRun:
    """The stored outcome of one run."""

    run_id: str
    status: str
    store_path: Path
    characteristics: list[dict]
    output: str

    def value(self, pose: str, name: str) -> float:
        """A characteristic's value, e.g. ``value("P1", "RP_mm")``; DataError if absent."""
        for c in self.characteristics:
            if c["pose"] == pose and c["name"] == name:
                if c["value"] is None:
                    raise DataError(f"{name} of {pose} was not computed in run {self.run_id}")
                return float(c["value"])
        have = sorted({(c["pose"], c["name"]) for c in self.characteristics})
        raise DataError(f"run {self.run_id} has no {name} for {pose} (have {have[:8]}...)")

    @property
    def poses(self) -> list[str]:
        return sorted({c["pose"] for c in self.characteristics if c["name"] == "AP_mm"})

    @property
    def failures(self) -> list[str]:
        return [f"{c['pose']} {c['name']} = {c['value']:.4g} > limit {c['limit']:g}"
                for c in self.characteristics if c["passed"] is False]

    @property
    def passed(self) -> bool | None:
        judged = [c["passed"] for c in self.characteristics if c["passed"] is not None]
        return (all(judged) if judged else None) if self.status == "done" else False

    def assert_within_limits(self) -> None:
        if self.status != "done":
            raise AssertionError(f"run {self.run_id} did not finish ({self.status}):\n{self.output}")
        if self.failures:
            raise AssertionError("outside the limits: " + "; ".join(self.failures))


def make_operator(operator, arm: bool):
    """The operator of a scripted run.

    ``operator`` is an object with ``confirm(message) -> bool`` (and ``human``),
    a callable ``message -> bool``, or the path of an answer file
    (:class:`~station.runner.AnswerFileOperator`). Without one, a dry run on
    the fakes answers yes to every prompt (logged) and an armed run asks on
    the terminal. With ``arm`` the operator must be a person: a callable, an
    answer file or any operator not marked ``human`` is refused
    (:class:`~station.errors.SafetyError`) before anything is recorded or
    moves, so no script answers the confirmations that guard real motion.
    """
    from app.assemble import require_human
    from station.runner import AnswerFileOperator, CallableOperator, InteractiveOperator, ScriptedOperator

    if operator is None:
        operator = InteractiveOperator() if arm else ScriptedOperator(True)
    elif isinstance(operator, (str, Path)):
        operator = AnswerFileOperator(operator)
    elif not hasattr(operator, "confirm"):
        if not callable(operator):
            raise ConfigError(f"operator must be an Operator, a callable or an answer file, got {operator!r}")
        operator = CallableOperator(operator)
    if arm:
        require_human(operator)
    return operator


class Station:
    """The station, for scripts: a config, devices (fakes unless ``arm``), a store, an operator.

    ``operator`` answers the runs' prompts (see :func:`make_operator`): on
    the fakes a script may answer them (default: yes to each); with ``arm``
    only a person may (default: the terminal; or the operator's page).
    """

    def __init__(self, config: StationConfig, *, workdir: str | Path, arm: bool = False,
                 time_scale: float = 20.0, seed: int = 0, operator=None) -> None:
        self.config = config
        self.workdir = Path(workdir)
        self.arm = arm
        self.time_scale = time_scale
        self.seed = seed
        self.operator = make_operator(operator, arm)
        self._n = 0

    @classmethod
    def from_config(cls, path: str | Path, *, arm: bool = False, **kw) -> "Station":
        """The station of a config file (TOML or JSON); relative paths in it are taken from its folder.
        Keywords as for :class:`Station` (``time_scale``, ``seed``, ``operator``)."""
        return cls(load_config(path), workdir=Path(path).resolve().parent, arm=arm, **kw)

    @classmethod
    def fake(cls, workdir: str | Path, *, seed: int = 0, time_scale: float = 20.0,
             limits: dict | None = None, serial: str = "SIM-0001", condition: str = "as-drawn",
             operator=None) -> "Station":
        """A station whose devices are the fake cell (started for each run, same seed).

        ``condition`` chooses the simulated robot: ``"as-drawn"`` takes the
        cell of ``seed`` whatever its errors (an uncalibrated arm after
        overhaul: AP of about 1-6 mm); ``"in-spec"`` and ``"out-of-spec"``
        take the first cell from ``seed`` on whose robot is inside, or
        outside, the configured limits by a clear margin
        (:func:`fake_robot_seed`). ``self.seed`` is the cell used.
        """
        from fakes.cells import demo_config

        workdir = Path(workdir)
        cfg = demo_config(workdir.resolve(), cycles=30, vap_cycles=30, rate_hz=100.0)
        cfg["robots"]["r1"]["serial"] = serial
        if limits is not None:
            cfg["robots"]["r1"]["limits"] = dict(limits)
        config = config_from_dict(cfg, "fake station")
        if condition not in CONDITIONS:
            raise ConfigError(f"condition must be one of {', '.join(CONDITIONS)}, got {condition!r}")
        if condition != "as-drawn":
            seed = fake_robot_seed(config, seed, condition)
        return cls(config, workdir=workdir, seed=seed, time_scale=time_scale, operator=operator)

    def iso9283(self, robot: str = "r1", *, cycles: int | None = None, vap_cycles: int | None = None,
                run_id: str | None = None) -> AcceptanceRun:
        """Run the ISO 9283 procedure and return its results; prompts go to :attr:`operator`."""
        from app.assemble import run_procedure

        overrides = {}
        if cycles is not None:
            overrides["cycles"] = int(cycles)
        if vap_cycles is not None:
            overrides["vap_cycles"] = int(vap_cycles)
        self._n += 1
        run_id = run_id or f"{self.config.robots[robot].serial}-accept-{self._n}"
        out = io.StringIO()
        run_procedure(self.config, "iso9283", robot=robot, run_id=run_id, arm=self.arm, operator=self.operator,
                      quiet=True,
                time_scale=self.time_scale, seed=self.seed, config_dir=self.workdir, plan_overrides=overrides,
                stdout=out)
        store_path = self.config.station.store_file(self.workdir)
        with RunStore(store_path) as store:
            return AcceptanceRun(run_id, store.run(run_id).status, store_path, store.characteristics(run_id),
                                 out.getvalue())

    def history(self, serial: str, name: str, pose: str | None = None) -> list[dict]:
        """Every stored value of characteristic ``name`` (e.g. ``"RP_mm"``) of the robot ``serial``, oldest
        first, optionally of one ``pose``: rows as :meth:`station.store.RunStore.history` gives them."""
        with RunStore(self.config.station.store_file(self.workdir)) as store:
            return store.history(serial, name, pose)
