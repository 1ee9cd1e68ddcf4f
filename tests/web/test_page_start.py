"""The page answers while the procedures' modules are imported (issue 47): the import runs in a thread of its
own as the server starts, never on the event loop that answers every connection."""

from __future__ import annotations

import threading

from tests.web.conftest import Client, demo_station_config


def test_the_page_answers_while_the_procedures_are_imported(tmp_path, monkeypatch):
    """The import is held by a hook until the test lets it go. Meanwhile a robot's page and a run's state are
    answered, and so is a robot's page asked while the station page waits for the import (it waits without
    holding the loop); once the import is let go, the station page comes with its procedures."""
    import app.web.app as web_app
    from app.web.server import WebServer
    from station.config import load_config

    held, release = threading.Event(), threading.Event()
    real = web_app.load_procedures

    def held_import(cfg):
        held.set()
        assert release.wait(300), "the test never let the import go"
        return real(cfg)

    monkeypatch.setattr(web_app, "load_procedures", held_import)
    server = WebServer(load_config(demo_station_config(tmp_path)), tmp_path, host="127.0.0.1", port=0).start()
    waiting = None
    try:
        client = Client(server.url)
        assert held.wait(60)
        status, _, html = client.get("/robots/DEMO-0001")
        assert status == 200 and "Robot DEMO-0001" in html
        status, _, text = client.get("/runs/no-such-run/state")
        assert status == 404 and "no-such-run" in text
        station: dict = {}
        waiting = threading.Thread(target=lambda: station.update(page=client.get("/")))
        waiting.start()
        status, _, html = client.get("/robots/DEMO-0001")  # answered while the station page waits
        assert status == 200 and "Robot DEMO-0001" in html
        assert "page" not in station and not release.is_set()  # it cannot have been answered: the import is held
        release.set()
        waiting.join(120)
        status, _, html = station["page"]
        assert status == 200 and "<option>iso9283</option>" in html and "id='btn-start'" in html
    finally:
        release.set()
        if waiting is not None:
            waiting.join(120)
        server.close()
