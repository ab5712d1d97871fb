"""Browser tests: headless Chromium (Debian's, through Playwright) against the server on the simulated table.

The server runs in a thread (uvicorn) on a free port with the simulator at 320×240 and few particles.
Chromium comes from ``$CHROMIUM_PATH`` or ``/usr/bin/chromium``; without it these tests FAIL (CI installs
it). A screenshot of the panel is written to ``artifacts/browser-panel.png``.
"""

from __future__ import annotations

import os
import shutil
import socket
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

pytestmark = pytest.mark.browser

ARTIFACTS = Path(__file__).resolve().parents[1] / "artifacts"
PASSWORD = "clase-de-español"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def chromium_path() -> str:
    path = os.environ.get("CHROMIUM_PATH") or "/usr/bin/chromium"
    if not Path(path).exists() and shutil.which(path) is None:
        pytest.fail(f"Chromium not found at {path!r}: install Debian's chromium or set CHROMIUM_PATH")
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def small_sim(spec: str):
    from tracker.sources.simulator import SimOptions, SimulatedTable

    scenario = spec.split(":", 1)[1] if ":" in spec else "guidance-demo"
    speed = 2.0 if scenario.startswith("learning") else 1.0  # a learning round ends within ~12 s
    options = SimOptions(width=320, height=240, focal=262.5, speed=speed)
    return SimulatedTable(scenario, seed=3, options=options, realtime=True)


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    import uvicorn

    from app.server import create_app
    from app.settings import Settings

    settings = Settings(
        host="127.0.0.1",
        port=free_port(),
        viser_port=free_port(),
        source="sim:guidance-demo",
        mode="guidance",
        database=str(tmp_path_factory.mktemp("db") / "agent.sqlite3"),
        teacher_password=PASSWORD,
        n_particles=40,
        max_fps=15,
    )
    app = create_app(settings, open_source=small_sim)
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=settings.port, log_level="warning"))
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    base = f"http://127.0.0.1:{settings.port}"
    t0 = time.time()
    while time.time() - t0 < 60:
        try:
            if httpx.get(f"{base}/api/snapshot", timeout=2).status_code == 200:
                break
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    else:
        pytest.fail("the server did not process a frame within 60 s")
    yield base
    srv.should_exit = True
    thread.join(timeout=10)


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture()
def page(browser):
    context = browser.new_context(viewport={"width": 1500, "height": 900})
    context.set_default_timeout(60_000)  # the machine may be busy: generous waits, no timing assertions
    pg = context.new_page()
    pg.dialogs = []
    pg.on("dialog", lambda d: (pg.dialogs.append(d.message), d.dismiss()))
    yield pg
    context.close()


def frame_number(page) -> int:
    text = page.locator("#frame-index").text_content() or ""
    return int(text) if text.strip().isdigit() else -1


def test_page_loads_and_updates(server, page):
    page.set_viewport_size({"width": 1280, "height": 800})  # a common laptop screen: the screenshot's size
    console: list[str] = []
    page.on("console", lambda msg: console.append(msg.text))
    page.goto(server + "/")
    page.wait_for_function("() => /^\\d+$/.test(document.getElementById('frame-index').textContent)")
    first = frame_number(page)
    page.wait_for_function(f"() => Number(document.getElementById('frame-index').textContent) > {first + 3}")
    assert frame_number(page) > first
    page.wait_for_function("() => document.getElementById('source-select').value === 'sim:guidance-demo'")
    assert page.locator("#source-select option").count() >= 8  # the simulated scenarios and a camera
    page.wait_for_function("() => document.getElementById('instruction').textContent.startsWith('Step')")
    page.wait_for_function("() => document.getElementById('color-image').naturalWidth === 320")
    # the scene comes from the other loopback name (another site: the browser draws it in its own process)
    assert page.locator("#viser-frame").get_attribute("src").startswith("http://localhost:")
    # the page's Content-Security-Policy lets the viser scene load in its frame, and blocks nothing of ours
    scene = page.frame_locator("#viser-frame")
    scene.locator("canvas").first.wait_for(state="attached")
    assert not [m for m in console if "Content Security Policy" in m], console
    # the scene's redraws are capped at the server's setting (viser ran the cap in the scene's page)
    viser = next(f for f in page.frames if f.url.startswith("http://localhost:"))
    viser.wait_for_function("() => window.__sceneRenderCap === 8")
    page.wait_for_timeout(2500)  # let the 3D scene draw before the screenshot
    ARTIFACTS.mkdir(exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / "browser-panel.png"), full_page=True)
    assert (ARTIFACTS / "browser-panel.png").stat().st_size > 10_000


def test_panel_shows_image_and_state_of_one_frame(server, page):
    """Every time the panel shows a new frame, the image beside it is that frame's (the websocket brings them
    together), and each shown frame's mode, instruction and progress are the ones of that frame's snapshot."""
    page.goto(server + "/?scene=off")
    page.wait_for_function("() => document.getElementById('color-image').dataset.frame !== undefined")
    page.evaluate("""() => {
      window.__shown = []; window.__mismatch = [];
      const img = document.getElementById('color-image'), idx = document.getElementById('frame-index');
      new MutationObserver(() => {
        if (img.dataset.frame !== idx.textContent) window.__mismatch.push([img.dataset.frame, idx.textContent]);
        window.__shown.push([Number(idx.textContent), document.getElementById('instruction').textContent,
                             document.getElementById('progress-text').textContent]);
      }).observe(idx, {childList: true, characterData: true, subtree: true});
    }""")
    page.wait_for_function("() => window.__shown.length >= 15")
    assert page.evaluate("window.__mismatch") == []
    for _ in range(30):  # a frame both the server reports and the panel showed (the panel may skip some)
        snap = httpx.get(server + "/api/snapshot", timeout=10).json()
        k, n = snap["frame_index"], page.evaluate("window.__shown.length")
        # until the panel reached frame k (or, should the source have started over, 60 frames later)
        page.wait_for_function(f"() => window.__shown.some((r) => r[0] >= {k}) || window.__shown.length > {n + 60}")
        rows = [r for r in page.evaluate("window.__shown") if r[0] == k]
        if rows:
            break
    else:
        raise AssertionError("the panel never showed a frame the test looked up")
    _, instruction, progress = rows[0]
    assert instruction == snap["instruction"]
    p = snap["mode_state"].get("progress") or {}
    assert progress == f"{p['done']} of {p['total']} {p.get('unit') or 'connections'} done"
    assert page.evaluate("window.__mismatch") == []


def wait_snapshot(server: str, predicate, what: str, timeout: float = 90.0) -> dict:
    """Poll ``/api/snapshot`` until ``predicate(snapshot)`` holds (a wait on state; AssertionError naming
    ``what`` when it never does)."""
    deadline = time.monotonic() + timeout
    snap: dict = {}
    while time.monotonic() < deadline:
        r = httpx.get(server + "/api/snapshot", timeout=10)
        if r.status_code == 200:
            snap = r.json()
            if predicate(snap):
                return snap
        time.sleep(0.1)
    raise AssertionError(f"never saw {what}; last snapshot: frame {snap.get('frame_index')}")


def use_source(server: str, spec: str) -> dict:
    """Switch the server to ``spec`` (the teacher's control) and wait for a frame of it with every part placed."""
    login = httpx.post(server + "/api/auth/login", json={"password": PASSWORD})
    token = login.cookies["teacher_token"]  # a header cannot carry the non-ASCII password itself
    r = httpx.post(server + "/api/sources", json={"source": spec}, headers={"Authorization": f"Bearer {token}"})
    assert r.status_code == 200, r.text
    httpx.post(server + "/api/sessions", json={"action": "start"})
    return wait_snapshot(
        server, lambda s: s["source"].get("spec") == spec and len(s["poses"]) == 5, f"a frame of {spec}"
    )


@pytest.fixture()
def still_table(server):
    """The simulator's 5 cubes at rest, no hand: every frame shows each part resting and in view, so what the
    box tests do does not depend on which frame of a moving scene they hit. Back to the demo afterwards."""
    use_source(server, "sim:static")
    yield server
    use_source(server, "sim:guidance-demo")


def best_seen(snap: dict) -> str:
    """The part whose colour blob is largest in the snapshot (clearly visible)."""
    seen = {n: d for n, d in snap["detections"].items() if d["bbox"] is not None and d["score"] > 0.9}
    assert seen, snap["detections"]
    return max(seen, key=lambda n: seen[n]["area"])


def drag_box(page, snap: dict, x: float, y: float, w: float, h: float) -> None:
    """Press, drag and release the mouse over the image rectangle (x, y, w, h) in image pixels."""
    iw, ih = snap["image_size"]
    box = page.locator("#overlay").bounding_box()
    sx, sy = box["width"] / iw, box["height"] / ih
    page.mouse.move(box["x"] + x * sx, box["y"] + y * sy)
    page.mouse.down()
    page.mouse.move(box["x"] + (x + w / 2) * sx, box["y"] + (y + h / 2) * sy, steps=4)
    page.mouse.move(box["x"] + (x + w) * sx, box["y"] + (y + h) * sy, steps=4)
    page.mouse.up()


def empty_spot(snap: dict, size: float = 24.0) -> tuple[float, float]:
    """The top-left corner of a size×size square of the lower image half (the table) far from every part."""
    iw, ih = snap["image_size"]
    parts = [d["bbox"] for d in snap["detections"].values() if d["bbox"] is not None]
    parts += [[b[0], b[1], b[2] - b[0], b[3] - b[1]] for b in snap["boxes"].values() if None not in b]
    for y in np.arange(ih - size - 4, ih / 2, -8.0):
        for x in np.arange(8.0, iw - size - 8, 8.0):
            if all(x + size + 8 < bx or bx + bw + 8 < x or y + size + 8 < by or by + bh + 8 < y
                   for bx, by, bw, bh in parts):
                return float(x), float(y)
    raise AssertionError(f"no empty table in view: {parts}")


def test_box_over_empty_table_is_refused(still_table, page):
    server = still_table
    page.goto(server + "/?scene=off")
    page.wait_for_function("() => document.getElementById('color-image').naturalWidth === 320")
    snap = httpx.get(server + "/api/snapshot").json()
    n_boxes = len(httpx.get(server + "/api/boxes").json()["boxes"])
    x, y = empty_spot(snap)
    drag_box(page, snap, x, y, 24, 24)
    page.wait_for_function("() => document.getElementById('box-message').textContent.startsWith('box refused')")
    message = page.locator("#box-message")
    assert "no part in the box" in message.text_content()
    assert "error" in message.get_attribute("class")
    assert len(httpx.get(server + "/api/boxes").json()["boxes"]) == n_boxes  # nothing was placed
    # a calibration learnt from bare table is refused too
    page.select_option("#box-action", "calibrate")
    page.select_option("#box-part", "red")
    page.evaluate("document.getElementById('box-message').textContent = ''")
    drag_box(page, snap, x, y, 24, 24)
    page.wait_for_function("() => document.getElementById('box-message').textContent.startsWith('box refused')")
    assert "of the image" in message.text_content()
    assert page.locator("#btn-undo-calibration").is_disabled()  # nothing to undo


def test_drawn_rectangle_creates_box_on_server(still_table, page):
    server = still_table
    page.goto(server + "/?scene=off")
    page.wait_for_function("() => document.getElementById('color-image').naturalWidth === 320")
    page.click("#btn-pause")  # hold the frame still: the box is judged on the frame the user sees
    page.wait_for_function("() => document.getElementById('worker-state').textContent === 'paused'")
    try:
        snap = httpx.get(server + "/api/snapshot").json()
        name = best_seen(snap)
        x, y, w, h = snap["detections"][name]["bbox"]
        drag_box(page, snap, x - 3, y - 3, w + 6, h + 6)
        page.wait_for_function("() => document.getElementById('box-message').textContent.startsWith('tracking')")
        assert name in page.locator("#box-message").text_content()
        boxes = httpx.get(server + "/api/boxes").json()["boxes"]
        assert boxes and boxes[-1]["part"] == name and boxes[-1]["action"] == "track"
        assert abs(boxes[-1]["rect"][0] - (x - 3)) < 3  # the rectangle arrived in image pixels
        assert boxes[-1]["pose"]["t"][2] > 0.2
        assert boxes[-1]["frame_index"] == snap["frame_index"]
        page.click("#btn-start")
        page.wait_for_function("() => document.getElementById('worker-state').textContent === 'running'")
    finally:  # resume even when an assertion failed, so the next tests see a running worker
        httpx.post(server + "/api/sessions", json={"action": "start"})


def test_find_parts_shows_results_and_part_list(still_table, page):
    server = still_table
    page.goto(server + "/?scene=off")
    page.wait_for_function("() => document.querySelectorAll('#part-list li[data-part]').length === 5")
    page.wait_for_function("() => document.getElementById('part-list').textContent.includes('red: tracked')")
    snap = httpx.get(server + "/api/snapshot").json()
    assert snap["carried"] == []  # no hand in this scene
    name = best_seen(snap)
    page.wait_for_selector(f"#box-part option[value='{name}']", state="attached")
    page.select_option("#box-part", name)
    page.click("#btn-auto-place")
    page.wait_for_function("() => document.getElementById('box-message').textContent.startsWith('found')")
    results = page.locator("#auto-place-results").text_content()
    assert page.locator("#box-message").text_content().startswith("found 1 of 1 part"), results
    item = page.locator(f"#auto-place-results li[data-part='{name}']")
    assert item.text_content().startswith(f"{name}: placed (fit ")
    page.select_option("#box-part", "")


def teacher_login(page, server, password=PASSWORD):
    page.goto(server + "/teacher")
    page.wait_for_function("() => document.getElementById('btn-login').textContent === 'Log in'")
    page.fill("#password", password)
    page.click("#btn-login")


def test_wrong_password_is_refused(server, page):
    teacher_login(page, server, "not-the-password")
    page.wait_for_function("() => document.getElementById('login-message').textContent.length > 0")
    assert page.locator("#login-message").text_content() == "Wrong password."
    assert page.locator("#btn-logout").is_hidden()
    assert page.locator("#btn-save").is_disabled()
    r = httpx.post(
        server + "/api/tasks",
        json={"source_sentence": "x", "words": ["a", "b"]},
        headers={"X-Teacher-Password": "not-the-password"},
    )
    assert r.status_code == 401


def create_task(page, sentence, words, distractors=""):
    page.fill("#f-source_sentence", sentence)
    page.fill("#f-words", words)
    page.fill("#f-distractors", distractors)
    page.evaluate("document.getElementById('save-message').textContent = ''")
    page.click("#btn-save")
    page.wait_for_function("() => document.getElementById('save-message').textContent.length > 0")


def choose_task(page, mode: str, task: str, source: str) -> str:
    """Pick ``mode`` and, in its task list, the entry running ``task`` on ``source``; returns the entry's text."""
    page.wait_for_selector("body[data-modes-loaded='1']", state="attached")
    page.select_option("#mode-select", mode)
    find = """([t, s]) => { const o = [...document.querySelectorAll('#task-select option')]
        .find((o) => o.dataset.task === t && o.dataset.source === s); return o ? o.value : null; }"""
    value = page.wait_for_function(find, arg=[task, source]).json_value()
    page.select_option("#task-select", value)
    return page.locator(f"#task-select option[value='{value}']").text_content()


def test_mode_switch_brings_its_scene_and_a_learning_round_ends(server, page):
    """Choosing learning on the guidance demo offers the learning scene and switches both; when the scene's
    round ends the panel says so and asks for another sentence."""
    page.goto(server + "/?scene=off")
    page.wait_for_function("() => document.body.dataset.source === 'sim:guidance-demo'")
    try:
        # a task that does not fit the scene is refused with what to choose instead, and nothing changes
        r = httpx.post(server + "/api/modes", json={"mode": "learning", "task": "learning-4-words"})
        assert r.status_code == 422 and "sim:learning-4" in r.json()["detail"]
        label = choose_task(page, "learning", "learning-4-words", "sim:learning-4")
        assert "switches to sim:learning-4" in label
        page.click("#btn-apply-mode")
        page.wait_for_function("() => document.body.dataset.source === 'sim:learning-4'")
        page.wait_for_function("() => document.getElementById('source-select').value === 'sim:learning-4'")
        assert page.locator("#mode-select").input_value() == "learning"
        page.wait_for_function("() => document.getElementById('source-sentence').textContent.length > 0")
        first = page.locator("#source-sentence").text_content()
        words = page.locator("#cube-words li").all_text_contents()
        assert len(words) == 6  # 4 words and 2 distractors
        round0 = page.locator("#round-banner").get_attribute("data-round")
        # the scene ends, starts again: a new round, visibly, with a new sentence
        page.wait_for_function(f"() => document.getElementById('round-banner').dataset.round !== '{round0}'",
                               timeout=120_000)
        page.wait_for_function("() => !document.getElementById('round-banner').classList.contains('hidden')")
        assert page.locator("#round-banner").text_content().startswith("New round")
        page.wait_for_function(f"() => document.getElementById('source-sentence').textContent !== {first!r}")
    finally:
        r = httpx.post(server + "/api/modes", json={"mode": "guidance", "source": "sim:guidance-demo"})
        assert r.status_code == 200, r.text


def test_teacher_task_appears_in_learning_mode(server, page):
    teacher_login(page, server)
    page.wait_for_selector("#btn-logout", state="visible")
    # a bad field gets a clear message next to it
    create_task(page, "Ο σκύλος τρέχει", "Solo")
    assert "at least 2" in page.locator("#err-words").text_content()
    create_task(page, "Ο σκύλος τρέχει", "El perro corre", "gato")
    assert page.locator("#save-message").text_content().startswith("Saved task")
    assert page.locator("#task-list").get_by_text("Ο σκύλος τρέχει").count() == 1
    ref = httpx.get(server + "/api/tasks").json()["tasks"][-1]["ref"]

    page.goto(server + "/?scene=off")
    choose_task(page, "learning", ref, "sim:guidance-demo")  # 3 words: the current scene's cubes carry them
    page.click("#btn-apply-mode")
    page.wait_for_function("() => document.getElementById('mode-message').textContent.startsWith('mode learning')")
    page.wait_for_function("() => document.getElementById('source-sentence').textContent === 'Ο σκύλος τρέχει'")
    cube_words = page.locator("#cube-words").text_content()
    assert "perro" in cube_words and "gato" in cube_words
    # back to guidance for the other tests
    httpx.post(server + "/api/modes", json={"mode": "guidance"})


def test_html_looking_word_is_shown_as_text(server, page):
    word = "<script>alert(1)</script>"
    teacher_login(page, server)
    page.wait_for_selector("#btn-logout", state="visible")
    create_task(page, "<b>bold?</b>", f"{word} | hola")
    assert page.locator("#save-message").text_content().startswith("Saved task")
    item = page.locator("#task-list li").filter(has_text="<b>bold?</b>")
    item.wait_for()
    assert item.count() == 1
    assert word in item.text_content()
    assert page.locator("#task-list b").count() == 0  # the markup was not interpreted
    ref = httpx.get(server + "/api/tasks").json()["tasks"][-1]["ref"]
    r = httpx.post(server + "/api/modes", json={"mode": "learning", "task": ref})
    assert r.status_code == 200, r.text
    page.goto(server + "/?scene=off")
    page.wait_for_function("() => document.getElementById('cube-words').textContent.includes('<script>')")
    assert word in page.locator("#cube-words").text_content()
    assert page.evaluate("document.querySelectorAll('script').length") == 1  # only app.js
    assert page.dialogs == []  # alert(1) never ran
    httpx.post(server + "/api/modes", json={"mode": "guidance"})
