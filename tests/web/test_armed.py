"""`station serve --arm`: the configured devices (here the fake station's URLs, standing in for hardware)
move only after the operator confirms the armed run on the page."""

import pytest

from fakes.station import FakeStation
from station.config import config_from_dict
from app.web.server import WebServer
from tests.web.conftest import Client


@pytest.fixture
def armed(tmp_path, test_seed):
    seed = test_seed
    with FakeStation.start(seed=seed, time_scale=40.0) as cell:
        cfg = config_from_dict(cell.config_dict(store_path=str(tmp_path / "s.sqlite"),
                                                report_dir=str(tmp_path / "reports"),
                                                iso9283={"cycles": 2, "vap_cycles": 2}))
        server = WebServer(cfg, tmp_path, port=0, arm=True).start()
        try:
            yield server, cell
        finally:
            server.close()


def test_an_armed_run_asks_first_and_a_no_moves_nothing(armed):
    server, cell = armed
    client = Client(server.url)
    status, _, page = client.get("/")
    assert "ARMED" in page and "name='seed'" not in page  # no fake-cell seed: real devices
    run_id = client.start(seed=0)
    st = client.wait(run_id, lambda s: s["prompt"] is not None, 10, "the armed confirmation")
    assert st["prompt"]["message"].startswith("ARMED: real devices will move")
    assert st["status"] == "starting" and server.store.runs() == []  # nothing stored before the answer
    status, _, _ = client.post(f"/runs/{run_id}/answer", {"prompt_id": st["prompt"]["id"], "answer": "no"})
    assert status == 303
    st = client.wait(run_id, lambda s: not s["live"], 10, "the refusal")
    assert st["status"] == "not started" and "SafetyError" in st["error"] and "nothing moved" in st["error"]
    assert server.store.runs() == []


def test_an_armed_run_confirmed_on_the_page_runs_on_the_configured_devices(armed):
    server, cell = armed
    client = Client(server.url)
    run_id = client.start(seed=0)
    asked = client.answer_prompts(run_id, 3)
    assert asked[0].startswith("ARMED") and "reflector" in asked[1].lower()
    st = client.wait(run_id, lambda s: s["n_done"] >= 7, 30, "the first pose cycle")
    assert st["status"] == "running" and st["procedure"] == "iso9283"
    rec = server.store.run(run_id)
    assert "fake" not in rec.params  # the configured devices, not a fake cell of the page's own
    _, _, page = client.get("/")  # connected by the run, and in use by it
    assert page.count(f"<td class=''>connected, in use by run {run_id}</td>") == 2
    client.post(f"/runs/{run_id}/abort")
    assert client.wait(run_id, lambda s: not s["live"], 20, "the abort")["status"] == "aborted"


def test_the_station_page_says_each_device_s_state_and_its_last_fault(tmp_path, test_seed):
    """Armed on devices that fault: the controller's FTP refuses the program upload. While the run goes, every
    device is in use (connecting until the run has connected them); after it, the controller is faulted with
    the fault and its run, the tracker idle."""
    with FakeStation.start(seed=test_seed, time_scale=40.0, faults={"controller.ftp_refuse": "stor"}) as cell:
        cfg = config_from_dict(cell.config_dict(store_path=str(tmp_path / "s.sqlite"),
                                                report_dir=str(tmp_path / "reports"),
                                                iso9283={"cycles": 2, "vap_cycles": 2}))
        server = WebServer(cfg, tmp_path, port=0, arm=True).start()
        try:
            client = Client(server.url)
            _, _, page = client.get("/")
            assert page.count("<td class=''>idle</td>") == 2 and "<td class='fault'></td>" in page
            run_id = client.start(seed=0)
            seen_in_use = False
            for _ in range(6):  # the run's prompts, until it fails uploading its program
                st = client.wait(run_id, lambda s: s["prompt"] is not None or not s["live"], 30, "a prompt or the end")
                if not st["live"]:
                    break
                _, _, page = client.get("/")
                seen_in_use = seen_in_use or page.count(f"in use by run {run_id}") == 2
                client.post(f"/runs/{run_id}/answer", {"prompt_id": st["prompt"]["id"], "answer": "yes"})
            assert seen_in_use
            assert st["status"] == "failed" and "550" in st["error"], st["error"]
            _, _, page = client.get("/")
            rows = {r.split("</td>", 1)[0]: r for r in page.split("<tr><td>")[1:]}
            assert "<td class='fail'>faulted</td>" in rows["controller"] and "550" in rows["controller"]
            assert f"run <a href='/runs/{run_id}'>{run_id}</a>" in rows["controller"]
            assert "<td class=''>idle</td>" in rows["tracker"] and "<td class='fault'></td>" in rows["tracker"]
        finally:
            server.close()
