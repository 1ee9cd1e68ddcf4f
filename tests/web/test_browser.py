"""The operator's page in a real browser: Debian's headless chromium driven by Playwright.

Two browser pages watch one run of the small demo station (fake cell drawn at
random): one starts it from the station page and answers the prompts with the
page's buttons; both see the steps advance and the verdict; the run page is
screenshotted live and done into the test's artefacts directory
(``STATION_TEST_ARTEFACTS``, else the test's tmp dir; printed), then the report
is opened from its link.
"""

import os
from pathlib import Path

import pytest

from station.store import RunStore
from tests.web.conftest import PAGE_MS

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--no-first-run", "--disable-sync"]

pytestmark = pytest.mark.skipif(not os.access(CHROMIUM, os.X_OK) and not os.environ.get("CI"),
                                reason="no /usr/bin/chromium (scripts/setup --tests installs it as root)")


#: installed in the watcher's page: records each new text of ``#current`` and ``#received`` and which plots had a
#: line, as the page's own updates draw them
RECORD_JS = """() => {
  const seen = window.__seen = {current: [], received: [], plots: []};
  const look = () => {
    for (const key of ['current', 'received']) {
      const el = document.getElementById(key);
      const list = seen[key];
      if (el && list[list.length - 1] !== el.textContent) list.push(el.textContent);
    }
    for (const id of ['plot-speed', 'plot-dist']) {
      if (!seen.plots.includes(id) && document.querySelector('#' + id + ' polyline')) {
        seen.plots.push(id);
        seen.plots.sort();
      }
    }
  };
  look();
  new MutationObserver(look).observe(document.body, {subtree: true, childList: true, characterData: true});
}"""


@pytest.fixture
def browser():
    from playwright.sync_api import sync_playwright

    from playwright.sync_api import expect

    expect.set_options(timeout=PAGE_MS)  # every expect of the browser tests (tests/web/conftest.py says why)
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            yield b
        finally:
            b.close()


def test_the_demo_run_from_the_page(served, browser, seed, tmp_path):
    from playwright.sync_api import expect

    page = browser.new_page(viewport={"width": 1200, "height": 1400})
    page.goto(served.url)
    expect(page.locator("h1")).to_contain_text("demo cell")
    page.fill("input[name=seed]", str(seed))
    page.click("#btn-start")
    page.wait_for_url("**/runs/*")
    run_id = page.url.rsplit("/", 1)[1]
    watcher = browser.new_page()  # another browser: it opens the page with the token (then holds its cookie)
    watcher.goto(f"{page.url}?token={served.guard.access_token}")
    # what the watcher's page shows, as it shows it: a busy host may finish the run before a look at the page
    # catches the stream's phase, and a navigation loses the record (the page must follow without reloading)
    watcher.evaluate(RECORD_JS)
    for expected in ("reflector", "clear the robot cell"):
        expect(page.locator("#prompt-text")).to_contain_text(expected, ignore_case=True)
        expect(watcher.locator("#prompt-text")).to_contain_text(expected, ignore_case=True)
        page.click("#btn-yes")
    watcher.wait_for_function("window.__seen.received.length >= 2", timeout=PAGE_MS)
    artefacts = Path(os.environ.get("STATION_TEST_ARTEFACTS", tmp_path))
    artefacts.mkdir(parents=True, exist_ok=True)
    watcher.screenshot(path=str(artefacts / "run_page_live.png"), full_page=True)
    expect(page.locator("#status")).to_have_text("done")
    expect(watcher.locator("#status")).to_have_text("done")
    seen = watcher.evaluate("window.__seen")
    with RunStore(served.store.path) as store:
        chars = store.characteristics(run_id)
        verdict = store.result(run_id, "verdict")["verdict"].lower()  # the run's one verdict
        n_tracker = store.sample_count(run_id, "tracker")
    # the watcher saw the steps advance without reloading (server-sent events) ...
    assert any("pose cycle" in c for c in seen["current"]) and any("vAP cycle" in c for c in seen["current"]), seen
    # ... and the plots follow the stream: the count grew, never past what the store holds
    received = [int(v) for v in seen["received"]]
    assert received == sorted(received) and 0 <= received[0] < received[-1] <= n_tracker, (received, n_tracker)
    assert seen["plots"] == ["plot-dist", "plot-speed"], seen
    expect(page.locator("#verdict")).to_have_text(verdict)
    expect(watcher.locator("#verdict")).to_have_text(verdict)
    expect(page.locator("#results-table tr")).to_have_count(len(chars) + 1)
    expect(page.locator("#steps-table tr[data-state=done]")).to_have_count(len(store_steps(served, run_id)))
    shot = artefacts / "run_page_done.png"
    page.screenshot(path=str(shot), full_page=True)
    print(f"screenshots of the run page: {artefacts}/run_page_live.png, {shot}")
    assert shot.stat().st_size > 10_000
    with page.expect_navigation():
        page.click("#report")
    assert page.url.endswith(f"/runs/{run_id}/report")
    expect(page.locator("body")).to_contain_text(run_id)
    # the station page lists the run with its verdict
    page.goto(served.url)
    expect(page.locator(f"a[href='/runs/{run_id}']")).to_be_visible()
    expect(page.locator("#runs")).to_contain_text(verdict)


def store_steps(served, run_id):
    with RunStore(served.store.path) as store:
        return {s.idx for s in store.steps(run_id) if s.status == "done"}
