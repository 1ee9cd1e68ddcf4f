"""Store-and-forward: local first, idempotent push, kill -9 mid-push, server restart, several stations."""

import os
import signal
import time


from app.cli import main
from station.store import RunStore
from station.store.forward import Forwarder, forward_status, push
from tests.store.helpers import add_run, central_batches, popen, same_samples, station_config


def _wait(pred, timeout_s, what):
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if pred():
            return
        time.sleep(0.01)
    raise AssertionError(f"timed out waiting for {what}")


def test_push_sends_what_the_centre_lacks_and_nothing_twice(rng, tmp_path, pg_url):
    local, central = RunStore(tmp_path / "a.sqlite", station="cell-a"), RunStore(pg_url)
    n1, n2 = rng.integers(5, 30, size=2)
    add_run(local, "SN-1-r1", "SN-1", rng, batches=n1)
    add_run(local, "SN-2-r1", "SN-2", rng, batches=n2, status=None)  # still running
    rep = push(local, central, station="cell-a", chunk_batches=int(rng.integers(1, 8)))
    assert rep.batches_sent == n1 + n2 and rep.samples_sent == 100 * (n1 + n2)
    same_samples(local, central, "SN-1-r1")
    same_samples(local, central, "SN-2-r1")
    assert central.run("SN-1-r1").status == "done" and central.run("SN-1-r1").station == "cell-a"
    assert central.run("SN-2-r1").status == "running"
    st = forward_status(local)
    assert st["SN-1-r1"]["in_centre"] == "complete" and st["SN-2-r1"]["status_forwarded"] == "running"
    # again: the finished run is skipped, the running one sends nothing new
    rep = push(local, central, station="cell-a")
    assert rep.batches_sent == 0 and [r.run_id for r in rep.runs] == ["SN-2-r1"]
    # the running run goes on and finishes: only its new batches go
    extra = int(rng.integers(1, 10))
    for _ in range(extra):
        local.append_samples("SN-2-r1", "tracker", 0, 1, {c: rng.normal(size=100) for c in "txyz"})
    local.step_ended("SN-2-r1", 0, 1, "done")
    local.put_characteristics("SN-2-r1", [{"pose": "P1", "name": "RP_mm", "value": 0.7, "unit": "mm", "limit": 0.5}])
    local.set_run_status("SN-2-r1", "done")
    rep = push(local, central, station="cell-a")
    assert rep.batches_sent == extra
    same_samples(local, central, "SN-2-r1")
    assert central.robots_exceeding("RP_mm", latest_only=False) == local.robots_exceeding("RP_mm", latest_only=False)
    assert all(f["in_centre"] == "complete" for f in forward_status(local).values())
    local.close(), central.close()


def test_kill_9_mid_push_then_resume_loses_and_duplicates_nothing(rng, tmp_path, pg_url):
    cfg = station_config(tmp_path, "cell-k", pg_url)
    local = RunStore(tmp_path / "cell-k.sqlite", station="cell-k")
    total = int(rng.integers(250, 350))
    add_run(local, "SN-K-r1", "SN-K", rng, batches=total, per_batch=50)
    central = RunStore(pg_url)
    proc = popen("store", "push", "--config", str(cfg), "--chunk-batches", "1")
    try:
        _wait(lambda: central_batches(central, "SN-K-r1") > 20, 30, "the push to start")
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(10)
    got = central_batches(central, "SN-K-r1")
    assert 0 < got < total, f"the push was not interrupted ({got} of {total})"
    fwd = forward_status(local)["SN-K-r1"]
    assert fwd["batches_forwarded"] <= got and fwd["in_centre"] == "partial"
    assert central.run("SN-K-r1").status == "running"  # not done in the centre until everything is there
    assert central.history("SN-K", "RP_mm") == []
    rep = push(local, central, station="cell-k", chunk_batches=50)
    assert rep.batches_sent + rep.runs[0].batches_already_there == total - fwd["batches_forwarded"]
    assert central_batches(central, "SN-K-r1") == total
    same_samples(local, central, "SN-K-r1")
    assert central.run("SN-K-r1").status == "done" and len(central.history("SN-K", "RP_mm")) == 1
    local.close(), central.close()


def test_server_stopped_mid_push_and_restarted_while_the_station_goes_on(rng, tmp_path, pg_server):
    url = pg_server.create_db()
    local = RunStore(tmp_path / "s.sqlite", station="cell-s")
    total = int(rng.integers(300, 400))
    add_run(local, "SN-S-r1", "SN-S", rng, batches=total, per_batch=50)
    central = RunStore(url)
    errors = []
    fwd = Forwarder(tmp_path / "s.sqlite", url, station="cell-s", interval_s=0.2, max_pause_s=0.5, chunk_batches=1,
                    connect_timeout_s=1, on_pass=lambda rep, err: errors.append(err) if err else None)
    with fwd:
        _wait(lambda: central_batches(central, "SN-S-r1") > 10, 30, "forwarding to start")
        central.close()
        pg_server.stop("fast")
        try:
            _wait(lambda: errors, 15, "the forwarder to notice the server is gone")
            # the station goes on locally meanwhile
            add_run(local, "SN-S-r2", "SN-S", rng, batches=7, state="in-service")
        finally:
            pg_server.start()
        _wait(lambda: all(f["in_centre"] == "complete" for f in forward_status(local).values()), 30,
              "forwarding to finish after the restart")
    assert "connection lost" in str(errors[0]) or "cannot connect" in str(errors[0])
    central = RunStore(url)
    assert central_batches(central, "SN-S-r1") == total
    same_samples(local, central, "SN-S-r1")
    same_samples(local, central, "SN-S-r2")
    assert [h["run_id"] for h in central.history("SN-S", "RP_mm")] == ["SN-S-r1", "SN-S-r2"]
    local.close(), central.close()


def test_several_stations_pushing_at_once(rng, tmp_path, pg_url):
    expected = {}
    cfgs = []
    for s, name in enumerate(("cell-a", "cell-b", "cell-c")):
        cfgs.append(station_config(tmp_path, name, pg_url))
        with RunStore(tmp_path / f"{name}.sqlite", station=name) as local:
            for k in range(3):
                serial = "SN-SHARED" if k == 0 else f"SN-{s}-{k}"  # one robot visits every station
                run_id = f"{serial}-{name}-{k}"
                n = int(rng.integers(20, 60))
                add_run(local, run_id, serial, rng, batches=n, per_batch=20, state="after" if s == 0 else "in-service")
                expected[run_id] = (name, n)
    # every station at once, and station a twice at once (the same runs from two processes)
    procs = [popen("store", "push", "--config", str(c), "--chunk-batches", "3") for c in cfgs + cfgs[:1]]
    outs = [p.communicate(timeout=60) for p in procs]
    assert [p.returncode for p in procs] == [0, 0, 0, 0], outs
    central = RunStore(pg_url)
    got = {r.run_id: (r.station, central_batches(central, r.run_id)) for r in central.runs()}
    assert got == expected
    shared = central.backend.query("SELECT COUNT(*) FROM robots WHERE serial='SN-SHARED'")[0][0]
    assert shared == 1
    from station.fleet.questions import robot_history

    assert {h["station"] for h in robot_history(central, "SN-SHARED", "RP_mm")} == {"cell-a", "cell-b", "cell-c"}
    for name in ("cell-a", "cell-b", "cell-c"):
        with RunStore(tmp_path / f"{name}.sqlite") as local:
            for run_id in (r.run_id for r in local.runs()):
                same_samples(local, central, run_id)
    central.close()


def test_a_run_id_of_another_station_is_refused_not_merged(rng, tmp_path, pg_url, capsys):
    for name in ("cell-a", "cell-b"):
        with RunStore(tmp_path / f"{name}.sqlite", station=name) as local:
            add_run(local, "SN-X-1", "SN-X", rng, batches=3)
    assert main(["store", "push", "--config", str(station_config(tmp_path, "cell-a", pg_url))]) == 0
    assert main(["store", "push", "--config", str(station_config(tmp_path, "cell-b", pg_url))]) == 1
    assert "already holds a run of this id from station 'cell-a'" in capsys.readouterr().out
    with RunStore(pg_url) as central, RunStore(tmp_path / "cell-a.sqlite") as a:
        assert central.run("SN-X-1").station == "cell-a"
        same_samples(a, central, "SN-X-1")


def test_unreachable_centre_keeps_everything_local_and_no_secret_is_written(rng, tmp_path, pg_server, capsys):
    with RunStore(tmp_path / "cell-u.sqlite", station="cell-u") as local:
        add_run(local, "SN-U-1", "SN-U", rng, batches=4)
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    dead = station_config(tmp_path, "cell-u", f"postgresql://station@127.0.0.1:{port}/plant?connect_timeout=2")
    assert main(["store", "push", "--config", str(dead)]) == 1
    err = capsys.readouterr().err
    assert "cannot connect" in err and "Nothing was lost" in err
    with RunStore(tmp_path / "cell-u.sqlite") as local:
        assert forward_status(local)["SN-U-1"]["in_centre"] == "no" and local.sample_count("SN-U-1") == 400
    url = pg_server.create_db()
    assert main(["store", "push", "--config", str(station_config(tmp_path, "cell-u", url))]) == 0
    out = capsys.readouterr()
    secret = pg_server.password
    assert secret not in out.out + out.err
    with RunStore(url) as central:
        for table, cols in (("runs", "config_json || params_json"), ("results", "value_json"), ("steps", "name")):
            rows = central.backend.query(f"SELECT {cols} FROM {table}")
            assert rows and not any(secret in (r[0] or "") for r in rows)
    assert secret.encode() not in (tmp_path / "cell-u.sqlite").read_bytes()
