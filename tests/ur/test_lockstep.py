"""The UR cell in lockstep: its programs run the world's clock, which stands still between them, and its RTDE
stream holds the clock at the package the driver has not yet kept, so the same seed gives the same tracker
samples, RTDE readings, figures and controller states at any pace and load (ur_rtde judging the stream)."""

from __future__ import annotations

import numpy as np

from app.assemble import run_procedure
from fakes.station import FakeStation
from station.config import config_from_dict
from station.store import RunStore
from tests.pace import UR_RTDE_HZ
from tests.person import person_typing_yes
from tests.ur.test_iso_procedure import UR_ISO


def _run(tmp_path, name, seed, time_scale):
    with FakeStation.start(seed=seed, time_scale=time_scale, robot="ur5e", rtde_hz=UR_RTDE_HZ) as cell:
        assert cell.controller_url.endswith("lockstep=1") and cell.controller.lockstep
        d = cell.config_dict(store_path=str(tmp_path / f"{name}.sqlite"), report_dir=str(tmp_path / name),
                             iso9283={**UR_ISO, "cycles": 3, "vap_cycles": 2})
        out = run_procedure(config_from_dict(d), "iso9283", arm=True, operator=person_typing_yes(), quiet=True,
                            run_id=name, config_dir=tmp_path)
    with RunStore(tmp_path / f"{name}.sqlite") as store:
        assert out.exit_code in (0, 1), [s.message for s in store.steps(name) if s.message]
        return (store.samples(name, "tracker"), store.samples(name, "robot"),
                {(c["pose"], c["name"]): c["value"] for c in store.characteristics(name)})


def test_a_ur_run_gives_the_same_samples_and_figures_at_any_pace_and_load(tmp_path, rng):
    """Twice, at paces 2-4 times apart (a late thread of a busy host is a slower pace here; the trailer's
    lockstep test holds the interpreter busy too)."""
    seed = int(rng.integers(2**31))
    tracker_a, robot_a, chars_a = _run(tmp_path, "fast", seed, float(rng.uniform(80.0, 120.0)))
    tracker_b, robot_b, chars_b = _run(tmp_path, "slow", seed, float(rng.uniform(25.0, 35.0)))
    assert tracker_a["t"].size > 1000 and robot_a["t"].size > 100
    # the RTDE readings too: the driver's receive process says which package it kept, and the stream sends the
    # next one (and lets the clock past it) only then; so every package of the run is stored, in both runs
    for stream_a, stream_b in ((tracker_a, tracker_b), (robot_a, robot_b)):
        assert set(stream_a) == set(stream_b)
        for col in stream_a:
            assert np.array_equal(stream_a[col], stream_b[col], equal_nan=True), col
    periods = np.round(np.diff(robot_a["t"]) * UR_RTDE_HZ)
    assert np.all(periods <= 1), "a package of the stream is missing"  # a stop's instant lies between two
    assert chars_a == chars_b
