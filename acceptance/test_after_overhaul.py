"""Example acceptance script: an industrial arm after overhaul, back into production?

Runs the ISO 9283 procedure (shortened here: 5 pose cycles, 2 multi-directional
cycles; a plant would use 30 and 10) on the station's devices and checks the
manufacturer's limits from the station config (RP 0.5 mm, AP 5 mm, vAP 2 mm)
plus a plant's own figures. With `fake_station` it runs on the fake cell;
point `Station.from_config("station.toml", arm=True)` at real devices.

`fake_station` stands for a robot that came back from overhaul inside its
maker's limits (drawn at random, with realistic errors, in spec by a margin);
`fake_station_out_of_spec` for one that did not: the same script refuses it.
"""

import pytest


def test_iso9283_after_overhaul(fake_station):
    # a short check (5 cycles, for the example's speed): an acceptance runs 30 and requires ISO 9283
    # conformance, the default; require_iso=False says this PASS is not one
    run = fake_station.iso9283(cycles=5, vap_cycles=2, require_iso=False)
    assert run.status == "done", run.output
    assert run.poses == ["P1", "P2", "P3", "P4", "P5"]
    for pose in run.poses:
        assert run.value(pose, "n_cycles") == 5
        assert run.value(pose, "RP_mm") <= 0.5, f"{pose}: repeatability out of the maker's spec"
        assert run.value(pose, "PST_s") <= 0.5, f"{pose}: settles too slowly after a stop"
    assert abs(run.value("P2-P4", "AD_mm")) <= 2.0
    run.assert_within_limits()
    assert run.passed is True and run.verdict == "PASS" and run.reasons == []


def test_a_robot_outside_the_limits_is_refused(fake_station_out_of_spec):
    run = fake_station_out_of_spec.iso9283(cycles=3, vap_cycles=2)
    assert run.status == "done", run.output
    with pytest.raises(AssertionError, match=r"FAIL, outside the limits: .*P\d AP_mm = [\d.]+ mm > limit 5 mm"):
        run.assert_within_limits()
    assert run.passed is False and run.verdict == "FAIL" and run.exit_code == 1


def test_history_shows_the_run(fake_station):
    run = fake_station.iso9283(cycles=3, vap_cycles=2)
    hist = fake_station.history("SIM-0001", "RP_mm", pose="P1")
    assert [h["run_id"] for h in hist] == [run.run_id]
    assert hist[0]["overhaul_state"] == "after"
