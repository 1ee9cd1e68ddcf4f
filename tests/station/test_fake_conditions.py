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


def test_a_marginal_robot_is_marginal_and_an_in_spec_one_is_not(tmp_path, world_seed):
    """The "marginal" fake robot's worst AP lies inside the guard band (10 % of the limit) below its limit and
    the run says so (``run.marginal``, the console, the report), still PASS; an in-spec robot has nothing
    marginal."""
    from station.verdict import Outcome

    st = Station.fake(tmp_path / "m", seed=world_seed, condition="marginal", time_scale=LOCKSTEP, cycles=3,
                      vap_cycles=3)
    lim, band = st.config.robots["r1"].limits.ap_limit_mm, st.config.station.marginal_fraction
    pred = st.prediction
    lo = {p: pred["AP_low_mm"][p] - pred["AP_margin_mm"][p] for p in pred["AP_low_mm"]}
    hi = {p: pred["AP_high_mm"][p] + pred["AP_margin_mm"][p] for p in pred["AP_low_mm"]}
    inside = {p for p in lo if lo[p] >= (1 - band) * lim}
    assert inside and all(h <= lim for h in hi.values())
    run = st.iso9283(require_iso=False)
    assert run.verdict is Outcome.PASS
    for p in lo:  # the run measures what the truth predicts, within its margin
        assert lo[p] <= run.value(p, "AP_mm") <= hi[p]
    said = {m for m in run.marginal if m.endswith("AP_mm")}
    assert {f"{p} AP_mm" for p in inside} <= said
    assert said == {f"{p} AP_mm" for p in lo if run.value(p, "AP_mm") >= (1 - band) * lim}
    for p in inside:
        assert f"{p} AP_mm = {run.value(p, 'AP_mm'):.4g} mm: marginal, within 10 % of its limit 5 mm" in run.output
        assert f"{p} AP_mm = {run.value(p, 'AP_mm'):.4g} mm: marginal" in open(run.report).read()
    good = Station.fake(tmp_path / "g", seed=world_seed, condition="in-spec", time_scale=LOCKSTEP, cycles=3,
                        vap_cycles=3).iso9283(require_iso=False)
    assert good.verdict is Outcome.PASS
    assert good.marginal == [] and ": marginal" not in good.output
    assert max(good.value(p, "AP_mm") for p in good.poses) < (1 - band) * lim


def test_the_guard_band_is_the_configs_and_checked(tmp_path, world_seed):
    from fakes.cells import demo_config
    from station.config import config_from_dict

    cfg = demo_config(tmp_path, cycles=3, vap_cycles=3, rate_hz=100.0)
    assert config_from_dict(cfg).station.marginal_fraction == 0.1
    for bad in (1.0, -0.1, float("nan")):
        cfg["station"]["marginal_fraction"] = bad
        with pytest.raises(ConfigError, match="station.marginal_fraction"):
            config_from_dict(cfg)
    cfg["station"]["marginal_fraction"] = 0.0
    with pytest.raises(ConfigError, match="needs a guard band"):
        fake_robot_seed(config_from_dict(cfg), world_seed, "marginal")
