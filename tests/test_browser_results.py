"""Browser test of the teacher's learner-results view (headless Debian Chromium through Playwright).

The database holds results of two stations (made by :class:`app.results.ResultsRecorder` from mode states);
the server runs without a tracker source (mode none, not started) so the test costs little. A screenshot of
the view is written to ``artifacts/browser-results.png``.
"""

from __future__ import annotations

import csv
import io
import threading
import time

import httpx
import pytest
from test_browser import ARTIFACTS, CHROMIUM_ARGS, chromium_path, free_port
from test_results import guidance_state, play_guidance
from test_worker import SyntheticTable

from app.results import ResultsRecorder
from app.storage import Storage

pytestmark = pytest.mark.browser
PASSWORD = "clase-de-español"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    import uvicorn

    from app.server import create_app
    from app.settings import Settings

    db = tmp_path_factory.mktemp("db") / "agent.sqlite3"
    store = Storage(db)
    for station, slow in (("bench-1", 0.0), ("bench-2", 2.0)):
        rec = ResultsRecorder(store)
        rec.switch(store.start_session("sim:guidance-demo", "guidance", None, station=station), "guidance")
        play_guidance(rec)
        if slow:  # bench-2 starts again and is slower at step 1
            rec.observe("guidance", guidance_state(0), 2, 3000.0)
            rec.observe("guidance", guidance_state(1), 2, 3000.0 + 4.0 + slow)
        rec.switch(None, None, now=3020.0)  # the session ends (step 2 of attempt 2 unfinished)
        rec.stop()
    settings = Settings(host="127.0.0.1", port=free_port(), viser_port=0, mode="none", database=str(db),
                        teacher_password=PASSWORD, autostart=False, source="synthetic:", station="bench-1")
    app = create_app(settings, open_source=lambda _spec: SyntheticTable())
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=settings.port, log_level="warning"))
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    base = f"http://127.0.0.1:{settings.port}"
    for _ in range(300):
        try:
            if httpx.get(f"{base}/api/status", timeout=2).status_code == 200:
                break
        except httpx.HTTPError:
            time.sleep(0.2)
    yield base
    srv.should_exit = True
    thread.join(timeout=10)


@pytest.fixture()
def page(server):
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_ARGS)
        context = browser.new_context(viewport={"width": 1300, "height": 1000})
        context.set_default_timeout(60_000)
        yield context.new_page()
        browser.close()


def test_results_view_plots_filters_and_exports(server, page):
    from playwright.sync_api import expect

    page.goto(server + "/teacher")
    assert page.locator("#results-card").is_hidden()  # learners see no results
    page.locator("#btn-login:not([disabled])").wait_for()
    page.fill("#password", PASSWORD)
    page.click("#btn-login")
    page.locator("#r-chart-svg rect.bar").first.wait_for()
    bars = page.locator("#r-chart-svg rect.bar")
    assert bars.count() == 3  # steps 1..3
    times = [float(bars.nth(i).get_attribute("data-time")) for i in range(3)]
    # step 1: 4 s at bench-1, 4 s and 6 s at bench-2 (it started again)
    assert times[1:] == [6.0, 2.0] and times[0] == pytest.approx((4.0 + 4.0 + 6.0) / 3, abs=1e-3)
    heights = [float(bars.nth(i).get_attribute("height")) for i in range(3)]
    assert heights[1] > heights[0] > heights[2] > 0  # drawn to scale
    dots = page.locator("#r-chart-svg circle.error-dot")
    assert [dots.nth(i).get_attribute("data-error-rate") for i in range(3)] == ["0.667", "0", "0"]
    assert page.locator("#r-stations tbody tr").count() == 2
    assert page.locator("#r-tasks tbody tr td").first.text_content() == "guidance-5-cubes"
    ARTIFACTS.mkdir(exist_ok=True)
    page.locator("#results-card").screenshot(path=str(ARTIFACTS / "browser-results.png"))

    page.select_option("#r-station", "bench-1")
    expect(page.locator("#r-stations tbody tr")).to_have_count(1)  # (the page's CSP forbids evaluated strings)
    assert page.locator("#r-stations tbody tr td").first.text_content() == "bench-1"
    assert page.locator("#r-chart-svg circle.error-dot").first.get_attribute("data-error-rate") == "1"
    href = page.locator("#r-csv").get_attribute("href")
    assert href == "/api/results.csv?station=bench-1"
    resp = page.request.get(server + href)  # with the teacher's login cookie
    assert resp.status == 200
    rows = list(csv.DictReader(io.StringIO(resp.text())))
    assert {r["station"] for r in rows} == {"bench-1"} and [r["step"] for r in rows] == ["1", "2", "3"]

    page.click("#btn-logout")
    page.locator("#results-card").wait_for(state="hidden")
    assert page.request.get(server + href).status == 401
