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

import secrets
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from station.config import StationConfig, config_from_dict, load_config
from station.errors import ConfigError, DataError, InsufficientDataError
from station.store import RunStore
from station.verdict import EXIT_ABORTED, Outcome

#: robots a fake station can be asked for (:meth:`Station.fake`)
CONDITIONS = ("as-drawn", "in-spec", "out-of-spec", "marginal", "rp-out", "one-pose-out")
#: the trailer section of a fake station (Station.fake's ``trailer`` merges into it)
FAKE_TRAILER = {"odometry": "odometry", "serial": "TRAILER-SIM-0001", "length_tolerance_m": 0.05}
#: the fake cell of a "marginal" robot: stops that scatter by 2 um and a tracker of MPE 1 um + 0.5 um/m, so the
#: run scatters about its prediction by 0.02-0.04 mm rms and 4 of it fit inside a 10 % guard band of a 5 mm AP
#: limit (on the realistic cell the registration alone scatters AP by 0.2-0.4 mm rms, wider than that band)
MARGINAL_CELL = {"stop_sigma_mm": 0.002, "tracker_mpe_a_um": 1.0, "tracker_mpe_b_um_per_m": 0.5}
#: an "rp-out" robot's expected RP, in units of the RP limit
RP_OUT_FACTOR = 2.0
#: RP = l_bar + 3 S_l of 3-D Gaussian stop scatter of sigma s per coordinate: l_bar = 1.596 s, S_l = 0.673 s
_RP_PER_SIGMA = 1.596 + 3 * 0.673
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
    #: the tracker's reading noise per coordinate (white and wander), mm
    tracker_sigma_mm: float
    #: the tracker's position in the base frame and its MPE a + b R (um, um/m): a systematic error of the session
    tracker_accuracy: tuple = ((0.0, 0.0, 0.0), 0.0, 0.0)


def fake_cell_truth(plan, seed: int, world_kwargs: dict | None = None) -> CellTruth:
    """The true error effects, stop scatter and tracker noise of the fake cell ``seed`` for ``plan``
    (``world_kwargs``: the fake cell's extra world parameters, e.g. ``stop_sigma_mm``)."""
    from fakes.sim.clock import ManualClock
    from fakes.sim.world import make_world

    world = make_world(robot=plan.robot.name, seed=int(seed), clock=ManualClock(), payload_kg=plan.payload_kg,
                       **dict(world_kwargs or {}))
    try:
        tr = world.tracker
        return CellTruth(int(seed), world.arm.effects, world.arm.stop_sigma_rad.copy(), tr.noise.total_um * 1e-3,
                         (tuple(float(v) for v in tr.base_T_tracker[:3, 3]), tr.mpe_a_um, tr.mpe_b_um_per_m))
    finally:
        world.close()


def _meets(condition, ap_lo, ap_hi, ad_hi, ap_margin, ad_margin, ap_lim, ad_lim, fraction) -> bool:
    """In spec: every AP and |AD| plus its margin within its limit less the guard band ``fraction`` of it
    (no limit, no bound: clear of the band, so an in-spec run is not marginal); out of spec: some pose's AP
    minus its margin at or over the AP limit; marginal: every AP and |AD| plus its margin within its limit,
    and some pose's AP minus its margin inside the guard band (at or over ``1 - fraction`` of the AP limit)."""
    if condition == "out-of-spec":
        return bool(np.any(ap_lo - ap_margin >= ap_lim))
    keep = 1.0 if condition == "marginal" else 1.0 - fraction
    in_spec = ((ap_lim is None or bool(np.all(ap_hi + ap_margin <= keep * ap_lim)))
               and (ad_lim is None or ad_hi + ad_margin <= keep * ad_lim))
    if condition == "marginal":
        return in_spec and bool(np.any(ap_lo - ap_margin >= (1.0 - fraction) * ap_lim))
    return in_spec


def fake_robot_seed(config: StationConfig, seed: int, condition: str, robot: str = "r1", *,
                    sigmas: float = SPEC_SIGMAS, max_tries: int = 5000, world_kwargs: dict | None = None) -> int:
    """The first fake-cell seed from ``seed`` on whose robot is in or out of spec.

    The cell's true error effects are drawn exactly as the fake station draws
    them; :func:`procedures.iso9283_truth.predict_static` gives the AP of
    every pose and the AD of P2-P4 an ideal run would measure, cold and fully
    warm, and :func:`~procedures.iso9283_truth.prediction_scatter` how far a
    run scatters about them (registration from the stop scatter of the sweep
    points, mean of two stops per pose, tracker noise). ``"in-spec"``: every
    AP and |AD| plus ``sigmas`` times its scatter within the configured
    ``ap_limit_mm`` / ``ad_limit_mm`` less their guard band
    (``station.marginal_fraction`` of each). ``"out-of-spec"``: some pose's AP
    minus ``sigmas`` times its scatter over ``ap_limit_mm``. ``"marginal"``:
    every AP and |AD| plus its margin within its limit, and some pose's AP
    minus its margin inside the guard band. RP, vAP and PST
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
    return _search(config, seed, condition, robot, sigmas, max_tries, world_kwargs)[0]


def fake_robot_prediction(config: StationConfig, seed: int, condition: str, robot: str = "r1", *,
                          sigmas: float = SPEC_SIGMAS, max_tries: int = 5000,
                          world_kwargs: dict | None = None) -> tuple[int, dict]:
    """:func:`fake_robot_seed` with what the cell predicts: ``(seed, {"AP_low_mm", "AP_high_mm",
    "AP_margin_mm"})``, per pose the predicted AP cold and warm (low, high) and ``sigmas`` times the
    run-to-prediction scatter."""
    return _search(config, seed, condition, robot, sigmas, max_tries, world_kwargs)


def _search(config, seed, condition, robot, sigmas, max_tries, world_kwargs) -> tuple[int, dict]:
    from procedures.iso9283 import plan_from_config
    from procedures.iso9283_truth import RunGeometry, predict_static, prediction_scatter

    drawn = ("in-spec", "out-of-spec", "marginal")
    if condition not in drawn:
        raise ConfigError(f"condition must be one of {', '.join(drawn)}, got {condition!r}")
    plan = plan_from_config(config, robot)
    ap_lim = plan.limits.get("AP_mm")
    ad_lim = plan.limits.get("AD_mm")
    fraction = config.station.marginal_fraction
    if condition != "in-spec" and ap_lim is None:
        raise ConfigError(f"robots.{robot}.limits.ap_limit_mm is needed to draw a robot {condition}")
    if condition == "marginal" and fraction <= 0:
        raise ConfigError("a robot 'marginal' needs a guard band: station.marginal_fraction is 0")
    names = list(plan.poses_mm)
    geo = RunGeometry.of(plan)
    for s in range(int(seed), int(seed) + max_tries):
        cell = fake_cell_truth(plan, s, world_kwargs)
        cold, warm = (predict_static(plan, cell.effects, warmup_s=w, geometry=geo) for w in (0.0, _WARM_S))
        ap = np.array([[p.AP_mm[n] for n in names] for p in (cold, warm)])
        ap_lo, ap_hi = ap.min(axis=0), ap.max(axis=0)
        ad_hi = max((abs(v) for p in (cold, warm) for v in p.AD_mm.values()), default=0.0)
        # the cheap test first: the noise-free numbers must already be on the right side
        if not _meets(condition, ap_lo, ap_hi, ad_hi, 0.0, 0.0, ap_lim, ad_lim, fraction):
            continue
        sc = prediction_scatter(plan, cell.effects, cell.stop_sigma_rad, cycles=_SPEC_CYCLES,
                                tracker_sigma_mm=cell.tracker_sigma_mm, rng=np.random.default_rng(s), geometry=geo,
                                tracker_accuracy=cell.tracker_accuracy)
        rms = np.array([sc.AP_rms_mm[n] for n in names])
        ad_sd = max(sc.AD_sd_mm.values(), default=0.0)
        if _meets(condition, ap_lo, ap_hi, ad_hi, sigmas * rms, sigmas * ad_sd, ap_lim, ad_lim, fraction):
            return s, {"AP_low_mm": dict(zip(names, ap_lo.tolist())), "AP_high_mm": dict(zip(names, ap_hi.tolist())),
                       "AP_margin_mm": dict(zip(names, (sigmas * rms).tolist()))}
    raise InsufficientDataError(f"no fake cell {condition} among seeds {seed}..{seed + max_tries - 1} "
                                f"(AP limit {ap_lim}, AD limit {ad_lim}, guard band {100 * fraction:g} %, "
                                f"{sigmas:g} sigma)")


#: the flaw of a "one pose out" robot spans at most a sixth of the way to the nearest other joint angle the
#: run visits (so its offset there is below exp(-18) of its amplitude); angles within this of another pose
#: count as visited (the vAP pre-points lie 100 mm off their poses: a few degrees at a metre's lever)
_DEFECT_GUARD_DEG = 6.0
#: ... and at least this wide (deg): a stop's scatter (thousandths of a degree) stays well inside it
_DEFECT_MIN_WIDTH_DEG = 0.02
#: ... and its joint must move the pose by at least this per radian (mm/rad), not a wrist spinning in place
_DEFECT_MIN_LEVER_MM = 300.0


def one_pose_out_defect(config: StationConfig, seed: int, prediction: dict, robot: str = "r1") -> tuple[str, dict]:
    """``(pose, joint_defect)``: a localised flaw of one joint (:mod:`fakes.sim.joint_defect`) that puts
    one pose of an in-spec cell (``prediction`` from :func:`fake_robot_prediction`) out of its AP limit by a
    clear margin and leaves every other pose and sweep point of the run untouched.

    The pose is drawn from ``seed`` (with an AD limit, not P2 or P4: the distance between them is the run's
    distance accuracy, which the flaw would put out too); the joint is the one whose angle at that pose lies
    farthest from every other angle the run visits on it (with a lever of at least 300 mm/rad); the amplitude moves the pose by
    the AP limit plus the pose's predicted AP and its margin, so its AP is over the limit whichever way its
    own error points.
    """
    from procedures.iso9283 import plan_from_config
    from procedures.iso9283_truth import RunGeometry
    from station.models import kinematics as kin

    plan = plan_from_config(config, robot)
    ap_lim = plan.limits.get("AP_mm")
    if ap_lim is None:
        raise ConfigError(f"robots.{robot}.limits.ap_limit_mm is needed to draw a robot one-pose-out")
    names = list(plan.poses_mm)
    geo = RunGeometry.of(plan)
    rng = np.random.default_rng(seed)
    ad_pair = ("P2", "P4") if plan.limits.get("AD_mm") is not None else ()  # the analysis's distance pair
    for k in rng.permutation(len(names)):
        if names[int(k)] in ad_pair:
            continue
        qp = geo.q_pose_rad[k]
        poses = np.delete(geo.q_pose_rad, k, axis=0)
        levers = np.linalg.norm(kin.joint_jacobian(plan.robot.dh_nominal, qp)[:3], axis=0)  # mm/rad per joint
        best = None
        for j in range(6):
            lever = float(levers[j])
            sep = min(float(np.degrees(np.min(np.abs(poses[:, j] - qp[j])))) - _DEFECT_GUARD_DEG,
                      float(np.degrees(np.min(np.abs(geo.q_sweep_rad[:, j] - qp[j])))))
            if lever >= _DEFECT_MIN_LEVER_MM and sep >= 6.0 * _DEFECT_MIN_WIDTH_DEG and (best is None
                                                                                      or sep > best[1]):
                best = (j, sep, lever)
        if best is None:
            continue
        j, sep, lever = best
        name = names[int(k)]
        shift_mm = 1.1 * (ap_lim + prediction["AP_high_mm"][name] + prediction["AP_margin_mm"][name])
        return name, {"joint": j + 1, "centre_deg": float(np.degrees(qp[j])), "width_deg": sep / 6.0,
                      "amplitude_deg": float(np.degrees(shift_mm / lever))}
    raise InsufficientDataError("no pose of this run has a joint angle apart from every other one it visits: "
                                "no flaw can put one pose out alone")


@dataclass
class AcceptanceRun:
    """The stored outcome of one run, with its one verdict.

    ``verdict`` is :class:`station.verdict.Outcome` (PASS, FAIL, NOT DECIDED,
    ABORTED) as :func:`procedures.decision.decide` gives it, the same as
    ``station run`` prints, ``--json`` and the report show; ``reasons`` says
    why (value, unit and limit of each failed or undecided limit, cycles
    found against asked, conformance). ``characteristics`` are the store's
    rows (keys ``pose``, ``name``, ``value``, ``unit``, ``limit``, ``passed``:
    True, False, or None when the row has no limit or was not decided).
    """

    run_id: str
    status: str
    store_path: Path
    characteristics: list[dict]
    output: str
    verdict: Outcome = Outcome.ABORTED
    reasons: list[str] = field(default_factory=list)
    #: ISO 9283 conformance of the run (None where the procedure has none)
    conformant: bool | None = None
    #: the command's exit code for this outcome (0 PASS, 1 FAIL, 3 NOT DECIDED, 4 not conformant, 5 ABORTED)
    exit_code: int = EXIT_ABORTED
    #: the fake cell's seed (None on armed devices)
    seed: int | None = None
    #: the HTML report, when the run wrote one
    report: str | None = None
    #: when the run was created and finished, s since the epoch (finished None while not finished)
    started_at: float | None = None
    finished_at: float | None = None
    procedure: str = "iso9283"
    #: the test record's who and what (operator, work order, overhaul ticket, ...), stored with the run
    record: dict = field(default_factory=dict)
    #: the plant's measurements as judged (:func:`station.measurements.evaluate` rows)
    measurements: list[dict] = field(default_factory=list)
    #: the robot and station of the run (model, serial, overhaul_state, station)
    subject: dict = field(default_factory=dict)

    #: the passing characteristics within the plant's guard band of their limit, one sentence each
    #: (:attr:`procedures.decision.RunDecision.marginal`)
    marginal_reasons: list[str] = field(default_factory=list)

    @property
    def marginal(self) -> list[str]:
        """What passed within its guard band: the characteristics within ``station.marginal_fraction`` of their
        limit (or whose U carries them over it) and the plant measurements within their own marginal band,
        as ``"P3 AP_mm"``, ``"P1 RP_plant"``."""
        return ([s.split(" = ", 1)[0] for s in self.marginal_reasons]
                + [f"{m['pose']} {m['name']}" for m in self.measurements if m.get("marginal")])

    def test_record(self) -> dict:
        """This run's test record (:func:`station.run_record.build`)."""
        from station.run_record import build

        return build(self)

    def write_record(self, out_dir: str | Path) -> tuple[Path, Path]:
        """Write the test record as ``RUN.record.json`` and ``RUN.junit.xml`` into ``out_dir``; their paths."""
        from station.run_record import write

        return write(self.test_record(), out_dir)

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
        """One sentence per failed limit, with units: ``"P1 AP_mm = 6.1 mm > limit 5 mm"``."""
        from procedures.decision import row_reason

        return [row_reason(c, Outcome.FAIL) for c in self.characteristics if c["passed"] is False]

    @property
    def passed(self) -> bool:
        """True only for a PASS: every limit decided and kept, every cycle asked measured, conformant when
        required. A FAIL, NOT DECIDED or ABORTED run is False (see :attr:`verdict` for which)."""
        return self.verdict is Outcome.PASS

    def assert_within_limits(self) -> None:
        """AssertionError unless the verdict is PASS; the message gives the verdict and every reason."""
        if self.verdict is not Outcome.PASS:
            head = f"run {self.run_id}: {self.verdict}"
            if self.verdict is Outcome.FAIL:
                head += ", outside the limits"
            raise AssertionError(head + ": " + "; ".join(self.reasons)
                                 + (f"\n{self.output}" if self.status != "done" else ""))


def make_operator(operator, arm: bool):
    """The operator of a scripted run.

    ``operator`` is an object with ``confirm(message) -> bool``,
    a callable ``message -> bool``, or the path of an answer file
    (:class:`~station.runner.AnswerFileOperator`). Without one, a dry run on
    the fakes answers yes to every prompt (logged) and an armed run asks on
    the terminal. With ``arm`` the operator must be a person: a callable, an
    answer file or any operator that is not a person (the terminal on a tty, the page) is refused
    (:class:`~station.errors.SafetyError`) before anything is recorded or
    moves, so no script answers the confirmations that guard real motion.
    """
    from app.assemble import require_person
    from app.terminal import InteractiveOperator
    from station.runner import AnswerFileOperator, CallableOperator, ScriptedOperator

    if operator is None:
        operator = InteractiveOperator() if arm else ScriptedOperator(True)
    elif isinstance(operator, (str, Path)):
        operator = AnswerFileOperator(operator)
    elif not hasattr(operator, "confirm"):
        if not callable(operator):
            raise ConfigError(f"operator must be an Operator, a callable or an answer file, got {operator!r}")
        operator = CallableOperator(operator)
    if arm:
        require_person(operator)
    return operator


class Station:
    """The station, for scripts: a config, devices (fakes unless ``arm``), a store, an operator.

    ``operator`` answers the runs' prompts (see :func:`make_operator`): on
    the fakes a script may answer them (default: yes to each); with ``arm``
    only a person may (default: the terminal; or the operator's page).
    ``store`` points the runs at another SQLite store than the config's (e.g.
    a persistent plant store, so history spans test sessions; the central
    PostgreSQL store gets the runs by forwarding, ``station.store_url``). ``record`` is the test record's who and what
    (``operator``, ``work_order``, ``overhaul_ticket``, any other text
    fields), stored with every run and written by :meth:`AcceptanceRun.write_record`.
    """

    def __init__(self, config: StationConfig, *, workdir: str | Path, arm: bool = False,
                 time_scale: float = 20.0, seed: int = 0, operator=None, store: str | Path | None = None,
                 record: dict | None = None) -> None:
        if not (isinstance(time_scale, (int, float)) and time_scale > 0):
            raise ConfigError(f"time_scale must be > 0, got {time_scale!r}")
        if store is not None:
            config = config.model_copy(update={"station": config.station.model_copy(update={"store_path": str(store)})})
        self.config = config
        self.workdir = Path(workdir)
        self.arm = arm
        self.time_scale = time_scale
        self.seed = seed
        self.operator = make_operator(operator, arm)
        self.record = dict(record or {})
        self._n = 0

    @classmethod
    def from_config(cls, path: str | Path, *, arm: bool = False, **kw) -> "Station":
        """The station of a config file (TOML or JSON); relative paths in it are taken from its folder.

        Keywords as for :class:`Station`: ``time_scale`` and ``seed`` (the fake
        cell's, without ``arm``), ``operator``, ``store``, ``record``. With
        ``arm=True`` the configured devices are used (real hardware) and only
        a person answers the confirmations (:func:`make_operator`).
        ConfigError names the file, the field and what is wrong.
        """
        return cls(load_config(path), workdir=Path(path).resolve().parent, arm=arm, **kw)

    @classmethod
    def fake(cls, workdir: str | Path, *, seed: int = 0, time_scale: float = 20.0,
             limits: dict | None = None, serial: str = "SIM-0001", model: str = "industrial-3100",
             payload_kg: float = 0.0, cycles: int = 30, vap_cycles: int = 30, condition: str = "as-drawn",
             operator=None, store: str | Path | None = None, record: dict | None = None,
             measurements: dict | None = None, trailer: dict | None = None,
             trailer_lengths_m: tuple[float, float] | None = None) -> "Station":
        """A station whose devices are the fake cell (started for each run, same seed).

        ``limits`` are merged into the fake robot's (``{"rp_limit_mm": 0.3}``
        keeps its AP, vAP and AD limits; a key set to None removes that
        limit). ``cycles``/``vap_cycles`` are the ISO plan's defaults,
        ``payload_kg`` the mass at the TCP, ``measurements`` the plant's
        own per procedure (``{"iso9283": [Measurement or table, ...]}``).
        ``trailer`` is merged into the fake station's trailer section (its
        odometry is the fake trailer's; serial ``TRAILER-SIM-0001``, length
        tolerance 0.05 m, the guarded rule: ``{"length_tolerance_m": 0.01}``),
        ``trailer_lengths_m`` the simulated trailer's true (L1, L2) in m
        (default: its design lengths).

        ``condition`` chooses the simulated robot (:data:`CONDITIONS`):
        ``"as-drawn"`` takes the cell of ``seed`` whatever its errors (an
        uncalibrated arm after overhaul: AP of about 1-6 mm); ``"in-spec"``,
        ``"out-of-spec"`` (AP over its limit at some pose) and
        ``"marginal"`` (inside, but some pose's AP inside the guard band
        ``station.marginal_fraction`` below its limit, on the fine cell of
        :data:`MARGINAL_CELL`) take the first cell from ``seed`` on that meets
        it by a clear margin (:func:`fake_robot_seed`; an in-spec cell also
        keeps clear of the guard band);
        ``"one-pose-out"`` is an in-spec cell whose arm has a flaw on one joint
        (a damaged gear tooth, :func:`one_pose_out_defect`) right at one pose:
        that pose's AP is over its limit, the others are in spec
        (``self.prediction["out_pose"]`` names it);
        ``"rp-out"`` is the cell of ``seed`` with stops that scatter so that
        the expected RP is twice ``rp_limit_mm`` (:data:`RP_OUT_FACTOR`); its
        AP is not conditioned (a scatter that wide also widens the AP's, so
        no AP margin of 4 of its rms fits the simulated arms).
        ``self.seed`` is the cell used.
        """
        from fakes.cells import demo_config

        workdir = Path(workdir)
        if condition not in CONDITIONS:
            raise ConfigError(f"condition must be one of {', '.join(CONDITIONS)}, got {condition!r}")
        cfg = demo_config(workdir.resolve(), cycles=int(cycles), vap_cycles=int(vap_cycles), rate_hz=100.0,
                          robot=model)
        r1 = cfg["robots"]["r1"]
        r1.update(serial=serial, model=model, payload_kg=float(payload_kg))
        merged = {**r1["limits"], **dict(limits or {})}
        r1["limits"] = {k: v for k, v in merged.items() if v is not None}
        cfg["devices"]["odometry"] = {"url": "fake://odometry"}
        cfg["trailer"] = {**FAKE_TRAILER, **dict(trailer or {})}
        if measurements:
            cfg["measurements"] = {proc: [m.to_dict() if hasattr(m, "to_dict") else dict(m) for m in ms]
                                   for proc, ms in measurements.items()}
        config = config_from_dict(cfg, "fake station")
        fake_options = None
        if condition == "rp-out":
            rp = config.robots["r1"].limits.rp_limit_mm
            if rp is None:
                raise ConfigError("condition 'rp-out' needs an RP limit (limits={'rp_limit_mm': ...})")
            fake_options = {"stop_sigma_mm": rp * RP_OUT_FACTOR / _RP_PER_SIGMA}
        prediction = None
        if condition == "marginal":
            fake_options = dict(MARGINAL_CELL)
        if trailer_lengths_m is not None:
            fake_options = {**(fake_options or {}), "true_lengths_m": [float(x) for x in trailer_lengths_m]}
        if condition not in ("as-drawn", "rp-out"):
            seed, prediction = fake_robot_prediction(config, seed, "in-spec" if condition == "one-pose-out"
                                                     else condition, world_kwargs=fake_options)
        if condition == "one-pose-out":
            pose, defect = one_pose_out_defect(config, seed, prediction)
            fake_options = {**(fake_options or {}), "joint_defect": defect}
            prediction = {**prediction, "out_pose": pose, "joint_defect": defect}
        station = cls(config, workdir=workdir, seed=seed, time_scale=time_scale, operator=operator, store=store,
                      record=record)
        station.condition, station.fake_options, station.prediction = condition, fake_options, prediction
        return station

    condition: str | None = None
    #: a drawn fake robot's predicted AP per pose (:func:`fake_robot_prediction`); None otherwise
    prediction: dict | None = None
    #: extra parameters of the fake cell (e.g. the stop scatter of an "rp-out" robot)
    fake_options: dict | None = None

    def run(self, procedure: str, robot: str = "r1", *, run_id: str | None = None,
            plan_overrides: dict | None = None, require_conformance: bool | None = None,
            measurements: list | None = None, record: dict | None = None) -> AcceptanceRun:
        """Run procedure ``procedure`` (``"iso9283"``, ``"arm-calibration"``, ``"trailer"``) and return
        its :class:`AcceptanceRun`; prompts go to :attr:`operator`.

        ``measurements`` (:class:`station.measurements.Measurement` or tables)
        are judged with the run, after the config's; ``record`` adds to the
        station's test-record fields for this run; an acceptance requires
        conformance to the procedure's standard (``require_conformance``;
        default: required where the procedure has one, its spec's
        ``standard``): a run that is not conformant (ISO 9283: fewer than 30
        cycles) is NOT DECIDED; False for a short check, whose PASS is then
        said to be not conformant. A procedure without a standard (the
        trailer's, the compliance test) is judged by its figures alone unless
        True is asked, which then makes it NOT DECIDED.
        """
        from app.assemble import RunRequest, run_procedure
        from station.measurements import parse

        from procedures.registry import get_procedure

        self._n += 1
        if require_conformance is None:
            require_conformance = get_procedure(procedure).standard is not None
        # the run is named after what it is made on: the robot's serial, the trailer's for a trailer run
        subject = get_procedure(procedure).subject(self.config, robot).serial or procedure
        run_id = run_id or f"{subject}-{time.strftime('%Y%m%d-%H%M%S')}-{self._n}-{secrets.token_hex(2)}"
        acceptance = {"record": {**self.record, **dict(record or {})},
                      "require_conformance": bool(require_conformance)}
        if measurements:
            acceptance["measurements"] = [m.to_dict() for m in parse(list(measurements), "measurements")]
        outcome = run_procedure(RunRequest(
            self.config, procedure, robot=robot, run_id=run_id, arm=self.arm, operator=self.operator, quiet=True,
            time_scale=self.time_scale, seed=self.seed, config_dir=self.workdir, plan_overrides=plan_overrides,
            acceptance=acceptance, fake_options=self.fake_options))
        return self._read(outcome)

    def iso9283(self, robot: str = "r1", *, cycles: int | None = None, vap_cycles: int | None = None,
                run_id: str | None = None, require_iso: bool = True, measurements: list | None = None,
                record: dict | None = None) -> AcceptanceRun:
        """Run the ISO 9283 procedure and return its results; prompts go to :attr:`operator`.

        Fewer cycles found than ``cycles`` is NOT DECIDED; so is a run that
        is not ISO 9283 conformant (fewer than 30 cycles) unless
        ``require_iso=False`` (a short check, not an acceptance).
        """
        overrides = {}
        if cycles is not None:
            overrides["cycles"] = int(cycles)
        if vap_cycles is not None:
            overrides["vap_cycles"] = int(vap_cycles)
        return self.run("iso9283", robot, run_id=run_id, plan_overrides=overrides, require_conformance=require_iso,
                        measurements=measurements, record=record)

    def resume(self, run_id: str) -> AcceptanceRun:
        """Resume stored run ``run_id`` (aborted, or stopped by a fault) from its last finished step, on the
        same fake cell (its stored seed) or the armed devices; returns its :class:`AcceptanceRun`."""
        from app.assemble import RunRequest, run_procedure

        outcome = run_procedure(RunRequest(self.config, None, resume=run_id, arm=self.arm, operator=self.operator,
                                           quiet=True, time_scale=self.time_scale, config_dir=self.workdir))
        return self._read(outcome)

    def _read(self, outcome) -> AcceptanceRun:
        store_path = self.config.station.store_file(self.workdir)
        with RunStore(store_path) as store:
            rec = store.run(outcome.run_id)
            return AcceptanceRun(
                outcome.run_id, outcome.status, store_path, store.characteristics(outcome.run_id),
                "\n".join(outcome.lines()), verdict=outcome.verdict, reasons=list(outcome.reasons),
                conformant=outcome.conformant, exit_code=outcome.exit_code,
                seed=None if outcome.fake is None else outcome.fake.get("seed"), report=outcome.report,
                started_at=rec.created_at, finished_at=rec.finished_at, procedure=outcome.procedure,
                record=(rec.params.get("acceptance") or {}).get("record", {}),
                measurements=store.results(outcome.run_id).get("measurements", []),
                marginal_reasons=list(outcome.marginal),
                subject={"model": rec.model, "serial": rec.serial, "overhaul_state": rec.overhaul_state,
                         "station": rec.station or self.config.station.name})

    def history(self, serial: str, name: str, pose: str | None = None) -> list[dict]:
        """Every stored value of characteristic (or plant measurement) ``name`` of the robot ``serial``,
        oldest first, optionally of one ``pose``.

        Each row is a dict with ``run_id``, ``created_at`` (s since the epoch),
        ``overhaul_state``, ``pose``, ``value``, ``limit`` (None without one)
        and ``passed`` (True, False, None): as
        :meth:`station.store.RunStore.history` gives them.
        """
        with RunStore(self.config.station.store_file(self.workdir)) as store:
            return store.history(serial, name, pose)
