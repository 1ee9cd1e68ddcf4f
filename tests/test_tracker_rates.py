"""One tracker rate range for the whole station (station.tracker_rates): the config, `station simulate`, the
simulated world and its tracker accept its ends and refuse just beyond them, each naming the rate."""

import pytest

from app.cli import main
from station.config import config_from_dict
from station.errors import ConfigError
from station.tracker_rates import TRACKER_RATE_RANGE_HZ


def _config(rate):
    return {"station": {"name": "t", "store_path": "s.sqlite"}, "devices": {"c": {"url": "fake://controller"}},
            "robots": {"r1": {"model": "industrial-3100", "serial": "S", "controller": "c",
                              "workspace": {"min_mm": [-900, 800, 500], "max_mm": [900, 2600, 2300]}}},
            "iso9283": {"tracker_rate_hz": rate}}


@pytest.mark.parametrize("end", [0, 1])
def test_every_door_takes_the_same_tracker_rates(end, tmp_path, capsys):
    from fakes.sim.clock import ManualClock
    from fakes.sim.world import make_world

    edge = TRACKER_RATE_RANGE_HZ[end]
    beyond = edge * (0.99 if end == 0 else 1.01)
    assert config_from_dict(_config(edge), "edge").iso9283.tracker_rate_hz == edge
    with pytest.raises(ConfigError, match="tracker_rate_hz"):
        config_from_dict(_config(beyond), "beyond")
    make_world(seed=1, clock=ManualClock(), tracker_rate_hz=edge).close()
    with pytest.raises(ConfigError, match="tracker_rate_hz"):
        make_world(seed=1, clock=ManualClock(), tracker_rate_hz=beyond)
    assert main(["simulate", "hold", "--out", str(tmp_path / "h"), "--rate", repr(beyond)]) == 2
    assert "--rate" in capsys.readouterr().err
