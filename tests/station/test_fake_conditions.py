"""Fake cells drawn in or out of the robot's limits (app.acceptance.fake_robot_seed)."""

import numpy as np
import pytest

from procedures.iso9283 import plan_from_config
from procedures.iso9283_truth import predict_static, prediction_scatter
from app.acceptance import SPEC_SIGMAS, Station, fake_cell_truth, fake_robot_seed
from station.errors import ConfigError, InsufficientDataError
from tests.pace import LOCKSTEP


def _prediction(station: Station):
    plan = plan_from_config(station.config, "r1")
    cell = fake_cell_truth(plan, station.seed)
    pred = predict_static(plan, cell.effects)
    sc = prediction_scatter(plan, cell.effects, cell.stop_sigma_rad, cycles=2, draws=50)
    ap = np.array(list(pred.AP_mm.values()))
    rms = np.array(list(sc.AP_rms_mm.values()))
    return plan, pred, ap, rms


def test_in_and_out_of_spec_cells_keep_their_margin(tmp_path, world_seed):
    good = Station.fake(tmp_path / "a", seed=world_seed, condition="in-spec", time_scale=LOCKSTEP)
    bad = Station.fake(tmp_path / "b", seed=world_seed, condition="out-of-spec", time_scale=LOCKSTEP)
    assert good.seed >= world_seed and bad.seed >= world_seed and good.seed != bad.seed
    # the scatter is re-estimated here with other draws: allow its Monte Carlo error (50 vs 200 draws)
    plan, pred, ap, rms = _prediction(good)
    assert np.all(ap + 0.7 * SPEC_SIGMAS * rms <= plan.limits["AP_mm"])
    assert abs(pred.AD_mm["P2-P4"]) < plan.limits["AD_mm"]
    plan, pred, ap, rms = _prediction(bad)
    assert np.any(ap - 0.7 * SPEC_SIGMAS * rms >= plan.limits["AP_mm"])
    # the first such cell: asking again from the same seed gives the same one
    assert fake_robot_seed(bad.config, world_seed, "out-of-spec") == bad.seed
    # as drawn: the seed asked for
    assert Station.fake(tmp_path / "c", seed=world_seed).seed == world_seed


def test_conditions_refused_clearly(tmp_path, world_seed):
    with pytest.raises(ConfigError, match="condition must be one of"):
        Station.fake(tmp_path, seed=world_seed, condition="nice")
    with pytest.raises(ConfigError, match="ap_limit_mm is needed"):  # limits merge: None removes one
        Station.fake(tmp_path, seed=world_seed, condition="out-of-spec", limits={"ap_limit_mm": None})
    merged = Station.fake(tmp_path, seed=world_seed, limits={"rp_limit_mm": 0.3}).config.robots["r1"].limits
    assert (merged.rp_limit_mm, merged.ap_limit_mm, merged.vap_limit_mm, merged.ad_limit_mm) == (0.3, 5.0, 2.0, 2.0)
    st = Station.fake(tmp_path, seed=world_seed, limits={"ap_limit_mm": 0.5})
    with pytest.raises(InsufficientDataError, match="no fake cell in-spec among seeds"):
        fake_robot_seed(st.config, world_seed, "in-spec", max_tries=20)
