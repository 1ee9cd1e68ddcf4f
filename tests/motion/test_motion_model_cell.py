"""A diagnosed motion model in the station config (``[robots.X] motion_model``) and in the fake cells' world.

The world's readings with a model carry its creep along each move's direction of arrival and its loop on
every axis; the test measures the same simulated cell (same seed) with and without the model and holds the
difference against the creep's own law, ``-A exp(-tau / tau_s)`` after the command's end.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from station.config import load_config
from station.errors import ConfigError
from station.models.motion_effects import KIND, check_motion_model

from ..station.test_config import GOOD


def _model_doc(A, tau, hz=14.0, zeta=0.8):
    return {"kind": KIND, "version": 1, "servo": {"frequency_hz": hz, "damping": zeta, "jerk_time_s": 0.0},
            "deceleration_mm_s2": 800.0, "effects": {"creep": {"amplitude_mm": A, "tau_s": tau}}}


def test_config_key_reads_the_file_relative_to_the_config(tmp_path, rng):
    (tmp_path / "models").mkdir()
    A, tau = rng.uniform(0.05, 0.3), rng.uniform(0.08, 0.3)
    (tmp_path / "models" / "r1.json").write_text(json.dumps(_model_doc(A, tau)))
    p = tmp_path / "station.toml"
    p.write_text(GOOD.replace('controller = "ctrl"\n', 'controller = "ctrl"\nmotion_model = "models/r1.json"\n'))
    cfg = load_config(p)
    assert cfg.robots["r1"].motion_model == str((tmp_path / "models" / "r1.json").resolve())
    # the run's fake cell gets the file (procedures.execute.prepare), and the cell reads and checks it
    from fakes.cells import _world_options
    from procedures.execute import prepare
    from station.store import RunStore

    with RunStore(tmp_path / "s.sqlite") as store:
        run = prepare(cfg, store, "iso9283", fake={"seed": 1, "time_scale": 1.0}, report_dir=tmp_path)
    assert run.fake["motion_model"] == cfg.robots["r1"].motion_model
    m = _world_options(run.fake)["motion_model"]
    assert m.effects["creep"]["amplitude_mm"] == pytest.approx(A) and m.servo_hz == 14.0


@pytest.mark.parametrize("content, why", [
    (None, "cannot read"),
    ("{not json", "not JSON"),
    (json.dumps(_model_doc(40.0, 0.1)), "effects.creep.amplitude_mm"),
    (json.dumps({"servo": {}}), "kind"),
])
def test_bad_model_file_refused_naming_key_and_file(tmp_path, content, why):
    f = tmp_path / "m.json"
    if content is not None:
        f.write_text(content)
    p = tmp_path / "station.toml"
    p.write_text(GOOD.replace('controller = "ctrl"\n', 'controller = "ctrl"\nmotion_model = "m.json"\n'))
    with pytest.raises(ConfigError) as exc:
        load_config(p)
    msg = str(exc.value)
    assert "robots.r1.motion_model" in msg and "m.json" in msg and why in msg, msg


def _run(model, seed, servo=None):
    """A UR5e cell (no arm errors, no stop scatter, no tracker noise): one joint move, then 2 s at rest."""
    from fakes.sim.clock import ManualClock
    from fakes.sim.world import make_world
    from station.models.tracker_noise import TrackerNoise

    w = make_world("ur5e", seed=seed, clock=ManualClock(), effects=None, stop_sigma_mm=None,
                   tracker_noise=TrackerNoise(0.0), tracker_mpe_a_um=0.0, tracker_mpe_b_um_per_m=0.0,
                   motion_model=model, servo=servo)
    q0 = np.asarray(w.robot.home_q_rad, dtype=float)
    q1 = q0 + np.radians([60.0, -10.0, 15.0, 0.0, 0.0, 0.0])
    mv = w.arm.move_joint(q1, speed_frac=0.5, profile="trapezoid")
    w.arm.dwell(2.0)
    t = np.arange(mv.t_start - 0.5, mv.t_end + 2.0, 1e-3)
    xyz, _ = w.tracker_source().measure(t)
    return w, mv, t, xyz


def test_a_cell_with_a_model_shows_its_creep(rng, test_seed):
    A, tau = rng.uniform(0.05, 0.3), rng.uniform(0.08, 0.3)
    model = check_motion_model(_model_doc(A, tau, hz=rng.uniform(10.0, 20.0), zeta=rng.uniform(0.7, 1.0)))
    from station.models.motion import ServoParams
    from station.models.motion_effects import servo_of

    w0, mv, t, x0 = _run(None, test_seed, ServoParams.uniform(*servo_of(model)))  # the same loop, no creep
    w1, mv1, _, x1 = _run(model, test_seed)
    assert (mv1.t_start, mv1.t_end) == (mv.t_start, mv.t_end)
    assert w1.arm.servo.omega_rad_s[0] == pytest.approx(model.servo_hz * 2 * math.pi)
    end = x0[-1]
    u = x0[-1] - x0[np.searchsorted(t, mv.t_end - 0.05)]
    u /= np.linalg.norm(u)
    tau_s = t - mv.t_end
    # the same loop on both: the difference is the creep alone, along the arrival, short by A while moving
    after = tau_s >= 0.0
    d = x1 - x0
    along = d[after] @ u
    assert np.max(np.abs(along - (-A * np.exp(-tau_s[after] / tau)))) < 1e-6 + 1e-3 * A
    # (u here is the measured path's; the cell's is the commanded path's, a few mrad apart through the loop's lag)
    assert np.max(np.linalg.norm(d[after] - along[:, None] * u, axis=1)) < 1e-2 * A
    moving = (tau_s < 0.0) & (t >= mv.t_start)
    assert np.allclose(np.linalg.norm(d[moving], axis=1), A, rtol=1e-6)
    assert np.allclose(d[t < mv.t_start], 0.0)
    # it ends where the cell without the model ends (the creep has died out: 2 s is 7-25 tau)
    assert np.linalg.norm(x1[-1] - end) < A * math.exp(-1.9 / tau) + 1e-9
