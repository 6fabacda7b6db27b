"""The review page in Firefox (Debian's firefox-esr, driven through Marionette on an Xvfb display): the catalogue
lists the pair, the set page draws part and grippers (software WebGL, Mesa llvmpipe) and a grasp's numbers show.
The Chromium tests (test_review_page.py) cover the rest of the page; this checks it runs on the other engine."""

from __future__ import annotations

import gc
import os
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.ui.browser import ARTIFACTS, FIREFOX, drawn_share, firefox_missing
from tests.ui.seed import seeded_serve

pytestmark = [
    pytest.mark.integration,
    pytest.mark.slow,
    pytest.mark.xdist_group("ui-browser"),
    pytest.mark.skipif(firefox_missing() is not None, reason=str(firefox_missing())),
]


@pytest.fixture(scope="module")
def served(tmp_path_factory) -> Iterator[dict]:
    with seeded_serve(tmp_path_factory.mktemp("ui-firefox")) as s:
        yield s


def _free_display() -> int:
    for n in range(90, 190):
        if not Path(f"/tmp/.X{n}-lock").exists() and not Path(f"/tmp/.X11-unix/X{n}").exists():
            return n
    raise RuntimeError("no free X display number in :90..:189")


@pytest.fixture(scope="module")
def firefox(tmp_path_factory) -> Iterator[object]:
    from marionette_driver.marionette import Marionette

    display = _free_display()
    xvfb = subprocess.Popen(
        ["Xvfb", f":{display}", "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    saved = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = f":{display}"
    client = None
    try:
        end = time.monotonic() + 20
        while not Path(f"/tmp/.X11-unix/X{display}").exists():
            assert xvfb.poll() is None and time.monotonic() < end, "Xvfb did not start"
            time.sleep(0.1)
        log = tmp_path_factory.mktemp("gecko") / "gecko.log"
        client = Marionette(bin=FIREFOX, port=0, gecko_log=str(log), prefs={"browser.shell.checkDefaultBrowser": False})
        client.start_session()
        client.set_window_rect(width=1280, height=900)
        yield client
    finally:
        if client is not None:
            client.cleanup()  # ends the session, closes Firefox, removes its profile
            client.instance = None
            del client
            gc.collect()  # the profile's finaliser runs now, not at interpreter exit (where it fails noisily)
        if saved is None:
            os.environ.pop("DISPLAY", None)
        else:
            os.environ["DISPLAY"] = saved
        xvfb.terminate()
        xvfb.wait(10)


def _wait_for(client, script: str, timeout: float = 60.0):  # type: ignore[no-untyped-def]
    end = time.monotonic() + timeout
    while True:
        value = client.execute_script(script)
        if value:
            return value
        assert time.monotonic() < end, f"timed out waiting for: {script}"
        time.sleep(0.2)


def test_the_page_works_in_firefox(served, firefox):
    from marionette_driver.by import By

    ff = firefox
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    ff.navigate(served["url"] + "/ui/")
    ff.find_element(By.CSS_SELECTOR, "#token-inline").send_keys(served["tokens"]["reader"])
    ff.find_element(By.XPATH, "//button[normalize-space()='Use token']").click()
    row = _wait_for(ff, "return document.querySelector('table.catalogue tbody tr')?.innerText")
    assert "ui-box" in row and "ui-jaw" in row
    ff.execute_script(
        "window.__errors = []; window.addEventListener('error', e => window.__errors.push(e.message))", sandbox=None
    )
    set_id = served["sets"][1]
    ff.execute_script(f"location.hash = '#/set/{set_id}'")
    _wait_for(ff, "return document.querySelector('.viewer')?.dataset.state === 'complete'")
    canvas = ff.find_element(By.CSS_SELECTOR, ".viewer canvas")
    assert drawn_share(ff.screenshot(element=canvas, format="binary")) > 0.02, "the 3D view is blank in Firefox"
    ff.find_element(By.XPATH, "//button[normalize-space()='Grasp 2']").click()
    text = _wait_for(ff, "return document.querySelector('section.selected h3')?.innerText")
    assert text.startswith("Grasp 2 of ")
    (ARTIFACTS / "20-firefox-set.png").write_bytes(ff.screenshot(format="binary"))
    assert ff.execute_script("return window.__errors", sandbox=None) == []
    assert ff.execute_script("return document.querySelectorAll('.status.error').length") == 0
