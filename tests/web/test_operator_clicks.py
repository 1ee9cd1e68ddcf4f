"""The operator's page in a real browser, pressed like a person: no click lost, the verdict in sight.

* 20 prompts of a test-only procedure (``tests/web/prompts_procedure.py``),
  each answered by pressing Yes, holding it 120-150 ms and releasing, at a
  random moment between the page's live updates (about four a second): every
  press answers its prompt. (A page that rebuilt the buttons on each update
  loses about every other such press: all 20 survive it about once in a
  million runs.)
* When a run ends, its verdict stands in a banner at the top, readable
  without scrolling on a 1280 x 800 screen and on a 10-inch tablet held
  upright (800 x 1280), and says the verdict the store holds.
"""

import os

import pytest

from procedures.registry import REGISTRY
from station.store import RunStore
from tests.pace import LOCKSTEP
from tests.web.prompts_procedure import N_PROMPTS
from tests.web.test_browser import CHROMIUM, browser  # noqa: F401  (the fixture: one headless chromium)

pytestmark = pytest.mark.skipif(not os.access(CHROMIUM, os.X_OK) and not os.environ.get("CI"),
                                reason="no /usr/bin/chromium (scripts/setup installs it as root)")


def _press(page, selector: str, hold_ms: float) -> None:
    """Press the element's centre, hold, release: a person's click, not a synthetic one."""
    box = None
    while box is None:  # the element may be redrawn between finding it and measuring it
        page.locator(selector).wait_for(state="visible")
        box = page.locator(selector).bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    page.wait_for_timeout(hold_ms)
    page.mouse.up()


def test_prompt_buttons_pressed_like_a_person_are_never_lost(served, browser, monkeypatch, rng):
    from playwright.sync_api import expect

    monkeypatch.setitem(REGISTRY, "prompts", "tests.web.prompts_procedure")
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    page.goto(served.url)
    page.select_option("select[name=procedure]", "prompts")
    page.click("#btn-start")
    page.wait_for_url("**/runs/*")
    run_id = page.url.rsplit("/", 1)[1]
    for k in range(1, N_PROMPTS + 1):
        # a press that was lost leaves the previous prompt standing: this waits in vain and fails
        expect(page.locator("#prompt-text")).to_contain_text(f"Prompt {k} of {N_PROMPTS}")
        page.wait_for_timeout(float(rng.uniform(0, 300)))  # anywhere between two live updates
        _press(page, "#btn-yes", float(rng.uniform(120, 150)))
    expect(page.locator("#status")).to_have_text("done")
    with RunStore(served.store.path) as store:
        answered = [s.output["confirmed"] for s in store.steps(run_id) if s.status == "done"]
    assert answered == [f"Prompt {k} of {N_PROMPTS}: ready?" for k in range(1, N_PROMPTS + 1)]


#: installed before the run page loads: after every change of the page, where the controls are and whether a prompt
#: stands (a press held on Pause was lost when a prompt appeared above the controls: y 166 -> 339)
CONTROLS_JS = """() => {
  const seen = window.__controls = [];
  const look = () => {
    const prompt = document.getElementById('prompt');
    const box = id => { const el = document.getElementById(id); if (!el) return null;
      const r = el.getBoundingClientRect(); return [r.x, r.y, r.width, r.height]; };
    if (!prompt) return;
    seen.push({prompt: !prompt.hidden, pause: box('btn-pause'), abort: box('btn-abort')});
  };
  new MutationObserver(look).observe(document, {subtree: true, childList: true, characterData: true,
                                                attributes: true});
}"""


@pytest.mark.parametrize("viewport", [{"width": 1280, "height": 800}, {"width": 800, "height": 1280}])
def test_the_controls_stay_put_when_a_prompt_comes_and_goes(served, client, browser, seed, viewport):
    from playwright.sync_api import expect

    page = browser.new_page(viewport=viewport)
    page.add_init_script(f"({CONTROLS_JS})()")
    run_id = client.start(seed)
    base, _, query = served.url.partition("?")
    page.goto(f"{base}runs/{run_id}" + (f"?{query}" if query else ""))
    expect(page.locator("#btn-pause")).to_be_visible()
    for _ in range(2):  # the two prompts of the ISO run: each stands on the page, then goes
        st = client.wait(run_id, lambda s: s["prompt"] is not None, 60, "a prompt")
        expect(page.locator("#prompt-text")).to_have_text(st["prompt"]["message"])
        status, _, text = client.post(f"/runs/{run_id}/answer", {"prompt_id": st["prompt"]["id"], "answer": "yes"})
        assert status == 303, text
    expect(page.locator("#prompt")).to_be_hidden()
    seen = page.evaluate("window.__controls")
    live = [s for s in seen if s["pause"] is not None]
    assert any(s["prompt"] for s in live) and any(not s["prompt"] for s in live), live[-5:]
    for key in ("pause", "abort"):
        boxes = {tuple(round(v, 1) for v in s[key]) for s in live if s[key] is not None}
        assert len(boxes) == 1, (key, boxes)
    client.post(f"/runs/{run_id}/abort")


@pytest.mark.pace(LOCKSTEP)
@pytest.mark.parametrize("viewport", [{"width": 1280, "height": 800}, {"width": 800, "height": 1280}])
def test_the_verdict_banner_is_in_sight_when_the_run_ends(served, client, browser, seed, viewport):
    from playwright.sync_api import expect

    run_id = client.start(seed)
    client.answer_prompts(run_id, 2)
    page = browser.new_page(viewport=viewport)
    base, _, query = served.url.partition("?")
    page.goto(f"{base}runs/{run_id}" + (f"?{query}" if query else ""))
    expect(page.locator("#status")).to_have_text("done", timeout=60_000)
    with RunStore(served.store.path) as store:
        stored = str(store.result(run_id, "verdict")["verdict"]).upper()
    banner = page.locator("#banner")
    expect(banner).to_be_visible()
    expect(page.locator("#banner-verdict")).to_have_text(stored)
    box = banner.bounding_box()
    assert box["y"] >= 0 and box["y"] + box["height"] <= viewport["height"], box
    assert stored in ("PASS", "FAIL", "NOT DECIDED")


def test_the_page_offers_only_what_the_config_can_run(served, client):
    from procedures.registry import runnable_procedures

    status, _, html = client.get("/")
    assert status == 200
    offered = html.split("<select name='procedure'>", 1)[1].split("</select>", 1)[0]
    can = runnable_procedures(served.hub.cfg)
    assert "iso9283" in can and "trailer" not in can  # the demo config has a cell and no [trailer] section
    for name in REGISTRY:
        assert (f"<option>{name}</option>" in offered) == (name in can)
    status, _, text = client.post("/runs", {"procedure": "trailer", "robot": "r1", "seed": 1})
    assert status in (400, 409) and "cannot run with this config" in text
